"""Part 3 of the service benchmark: the live fleet's tick with its database work (s), against the
same decisions in memory (the controller steps alone)."""

from __future__ import annotations

import time
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from trainclimate.bench.service.database import copy_block, copy_telemetry, sql, sql_all
from trainclimate.bench.service.fleet import pair_ids, register

#: The tick time the fleet tick is measured against, in s.
TARGET_S = 2.0


def run(url: str, model: Path, coaches: int, lead_ticks: int, repeats: int) -> dict:
    """The live fleet's tick for ``coaches`` coaches (half activated) with its database work,
    against the same decisions in memory (:meth:`Scheduler.decide`: the controller steps alone).

    The coaches are simulated minute by minute for ``lead_ticks`` + ``repeats`` ticks; after a
    warm-up tick, ``repeats`` ticks are timed. Times in s (medians, and every run's); the tick's
    parts each timed on their own: its telemetry reads, the samples' extraction, the decisions
    and a tick with no telemetry in its window (every coach stale: the claim and the writes).
    """
    from sqlalchemy import select

    from trainclimate.predict.artifact import load_predictor
    from trainclimate.service.scheduler import Scheduler
    from trainclimate.service.settings import Settings
    from trainclimate.service.store.db import Database
    from trainclimate.service.store.models import Coach
    from trainclimate.service.store.telemetry import controller_samples, load_rows

    settings = Settings(database_url=url, predictor_path=model)
    period = timedelta(minutes=settings.sampling_min)
    ids, start = live_fleet(url, model, coaches, lead_ticks + repeats, period)
    db = Database(url)
    warm = start + lead_ticks * period
    ticks = [warm + j * period for j in range(1, repeats + 1)]

    scheduler = Scheduler(db, settings)
    if scheduler.tick_fleet("live", warm) != len(ids):  # warm-up: controllers, caches, pool
        raise RuntimeError("the warm-up tick did not reach every coach")
    tick_s, written = [], []
    for tick in ticks:
        t0 = time.perf_counter()
        written.append(scheduler.tick_fleet("live", tick))
        tick_s.append(time.perf_counter() - t0)
    reasons = dict(
        sql_all(
            url,
            "SELECT reason, count(*) FROM setpoints WHERE tick = %s GROUP BY reason ORDER BY 1",
            (ticks[0],),
        )
    )

    # the same work without the database: the decisions alone, on the same samples
    rho = load_predictor(model).rho
    window = (rho + 2) * period + timedelta(minutes=1)
    with db.sessions() as session:
        fleet = session.scalars(select(Coach).where(Coach.fleet == "live").order_by(Coach.id)).all()
    read_s, samples_s, steps_s = [], [], []
    baseline = Scheduler(db, settings)
    with db.transaction() as session:
        baseline.refresh_model(session)
    baseline_reasons: dict[str, int] = {}
    for j, tick in enumerate([warm, *ticks]):
        t0 = time.perf_counter()
        telemetry = {}
        for b in range(0, len(ids), 250):  # the tick's reads, batch by batch
            with db.transaction() as session:
                telemetry |= load_rows(session, ids[b : b + 250], tick - window, tick)
        t1 = time.perf_counter()
        at = tick.timestamp()
        samples = {c: controller_samples(telemetry[c], at, scheduler.period_s) for c in ids}
        t2 = time.perf_counter()
        decisions = [baseline.decide(c, samples[c.id], None, tick) for c in fleet]
        t3 = time.perf_counter()
        if j:  # the first is the baseline's own warm-up tick
            read_s.append(t1 - t0)
            samples_s.append(t2 - t1)
            steps_s.append(t3 - t2)
        if j == 1:
            for d in decisions:
                baseline_reasons[d.reason] = baseline_reasons.get(d.reason, 0) + 1
    rows_stored = sql_all(
        url, "SELECT count(*) FROM telemetry WHERE coach_id = ANY(%s)", (list(ids),)
    )[0][0]

    # the tick's claim and writes: a tick with no telemetry in its window (every coach stale, so
    # no samples and no controller step) is the claim, the reads (empty, still one DataFrame per
    # coach), the overrides, the insert of every setpoint, the last_tick updates and the commits
    empty = ticks[-1] + timedelta(days=1)
    t0 = time.perf_counter()
    stale_written = scheduler.tick_fleet("live", empty)
    claim_write_s = time.perf_counter() - t0
    # the live fleet's setpoints only: the fleet-scale part's trial may have one at that tick
    stale = dict(
        sql_all(
            url,
            "SELECT reason, count(*) FROM setpoints WHERE tick = %s AND coach_id = ANY(%s) "
            "GROUP BY 1",
            (empty, list(ids)),
        )
    )
    if stale_written != len(ids) or stale != {"stale": len(ids)}:
        raise RuntimeError(f"the tick without telemetry gave {stale}")
    db.dispose()
    tick_med, steps_med = float(np.median(tick_s)), float(np.median(steps_s))
    read_med, samples_med = float(np.median(read_s)), float(np.median(samples_s))
    return {
        "coaches": len(ids),
        "activated": len(ids) // 2,
        "lead_in_ticks": lead_ticks,
        "tick_s": tick_med,
        "tick_runs_s": tick_s,
        "setpoints_written": written,
        "reasons": reasons,
        "controller_steps_s": steps_med,
        "controller_steps_runs_s": steps_s,
        "baseline_reasons": baseline_reasons,
        "tick_vs_steps": tick_med / steps_med,
        "parts_s": {  # each measured on its own (their sum is the tick's, up to the noise)
            "telemetry_read": read_med,
            "controller_samples": samples_med,
            "decisions": steps_med,
            "tick_without_telemetry": claim_write_s,
        },
        "target_s": TARGET_S,
        "telemetry_rows_stored": rows_stored,
    }


def live_fleet(
    url: str, model: Path, coaches: int, ticks: int, period: timedelta
) -> tuple[list[str], datetime]:
    """``coaches`` live coaches (half activated) registered in the database at ``url``, their
    1-minute telemetry over ``ticks`` sampling periods of ``period`` loaded with COPY (then
    ``VACUUM ANALYZE``), and the model file ``model`` registered as the active model: (the coach
    ids, the time the telemetry starts — a tick; its first row is stamped a minute later)."""
    from trainclimate.service.app import register_model_file
    from trainclimate.service.settings import Settings
    from trainclimate.service.store.db import Database

    ids, start, block = _fleet_block(coaches, round(ticks * period / timedelta(minutes=1)))
    register(url, ids, "live")
    copy_telemetry(url, [block])
    sql(url, "VACUUM ANALYZE telemetry", autocommit=True)
    db = Database(url)
    with db.transaction() as session:
        register_model_file(session, Settings(database_url=url, predictor_path=model))
    db.dispose()
    return ids, start.to_pydatetime()


def _fleet_block(coaches: int, minutes: int):
    """``coaches`` coaches of ``parked-heating-nov`` (HVAC in regular mode) simulated for
    ``minutes``, as 1-minute telemetry rows minute by minute (every coach's row of a minute
    together, as a live feed stores them): (ids, the first row's minute start, COPY block)."""
    from trainclimate.coach.rule import MODE_REGULAR
    from trainclimate.sim import scenarios
    from trainclimate.sim.simulator import FleetSimulator

    ids = pair_ids("L", coaches // 2)[0]
    env, params = scenarios.build(
        scenarios.get("parked-heating-nov"), n_coaches=len(ids), hours=minutes / 60.0
    )
    sim = FleetSimulator(params, env)
    sim.run()
    r = sim.result()
    per_min = round(60.0 / env.dt_s)
    steps = minutes * per_min
    if not np.all(np.asarray(env.mode[:steps]) == MODE_REGULAR):
        raise RuntimeError("the fleet tick's scenario left regular mode")

    def means(a) -> np.ndarray:
        """Per-minute means of a per-step series (leading axis the simulator's steps)."""
        a = np.asarray(a)[:steps]
        return a.reshape(minutes, per_min, *a.shape[1:]).mean(axis=1)

    room = means(r.t_room_meas_c)
    values = {
        "t_room_up_c": room[..., 0],
        "t_room_mid_c": room[..., 1],
        "t_room_low_c": room[..., 2],
        "t_ref_c": means(r.t_ref_c),
        "t_rule_c": means(r.t_rule_c),
        "t_amb_c": means(env.t_amb_c),
        "ghi_w_m2": means(env.ghi_w_m2),
        "q_gt_w_m2": means(env.q_roof_w_m2),
        "q_gs_w_m2": means(env.q_side_w_m2),
        "occupancy_pct": means(env.occupancy_pct),
        "speed_kmh": means(env.speed_kmh),
        "power_kw": means(r.total_power_w) / 1e3,
        "floor_power_kw": means(r.power_w["floor_wall"]) / 1e3,
    }
    start = env.time[0]
    time_s = start.timestamp() + 60.0 * np.repeat(np.arange(1, minutes + 1), len(ids))
    id_array = np.tile(np.asarray(ids, dtype="S"), minutes)
    block = copy_block(id_array, time_s, {c: v.ravel() for c, v in values.items()})
    return ids, start, block
