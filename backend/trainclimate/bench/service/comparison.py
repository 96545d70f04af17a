"""Part 2 of the service benchmark: with ``pairs`` × ``days`` of fleet data stored, the latency
(ms) of the fleet summary over 6 h, 24 h, 7 d and 30 d — refreshed as the dashboard refreshes
it, over a new range each time, and over the latest range as a new window completes — and of
the pair comparison over 24 h and 7 d; the baseline in the same run, the rollup floor: the least
any summary reads, every coach's totals over the window summed from the window rollups in one
statement. Also the COPY load rate and the rollups' size and build time."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from trainclimate.bench.common import latency_ms
from trainclimate.bench.service.database import copy_block, copy_telemetry, sql, table_size
from trainclimate.bench.service.fleet import client as fleet_client
from trainclimate.bench.service.fleet import pair_ids, register, synthetic, tokens

#: The summary's windows. [h]
SUMMARY_H = {"6h": 6, "24h": 24, "7d": 168, "30d": 720}
#: The pair comparison's windows. [h]
COMPARISON_H = {"24h": 24, "7d": 168}
#: Every summary window's p95, refreshed and over a new range. [ms]
SUMMARY_TARGET_P95_MS = 300.0
#: The pair comparison's p95 over 7 days. [ms]
COMPARISON_TARGET_P95_MS = 150.0
#: The first stored minute of the synthetic data.
DATA_START = pd.Timestamp("2024-11-01T00:00Z")
#: The rollup floor: every coach's energy, HVAC energy and windows over a range of windows.
FLOOR = (
    "SELECT coach_id, sum(energy_kwh), sum(hvac_kwh), count(*) FROM window_rollups "
    'WHERE "window" >= %s AND "window" < %s GROUP BY coach_id'
)


def run(url: str, model: Path, pairs: int, days: int, samples: int, progress) -> dict:
    """Load ``pairs`` × ``days`` of 1-minute rows with binary COPY and build their window rollups,
    pair days (:mod:`~trainclimate.service.store.pair_days`) and fleet days
    (:mod:`~trainclimate.service.store.fleet_days`), then time ``samples`` requests per
    point: the fleet summary over each of :data:`SUMMARY_H` refreshed (the data's end, each window
    in turn, after one untimed round that fills the read cache), over new ranges (random ends)
    and over the latest ranges (ending in each of the data's last windows, :func:`_latest_end`),
    the pair comparison over each of :data:`COMPARISON_H` (random trains and ends), and the rollup
    floor over each summary window. ``progress(1)`` after the load and after the requests."""
    from trainclimate.service.store import fleet_days, pair_days, rollups, setpoint_rollups
    from trainclimate.service.store.db import Database

    ids = pair_ids("C", pairs)[0]
    end = DATA_START + pd.Timedelta(days=days)
    register(url, ids, "archive")  # not the live fleet: the tick later leaves them alone
    n_rows = len(ids) * days * 1440
    sent, copy_s = copy_telemetry(url, _rows(pairs, days, seed=2))
    n_setpoints = copy_setpoints(url, ids, days)
    db = Database(url)
    t0 = time.perf_counter()
    with db.transaction() as session:
        n_rollups = rollups.rebuild(session)
        setpoint_rollups.rebuild(session)
    rollup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    with db.transaction() as session:  # as the scheduler keeps them, all at once
        n_days = pair_days.build(session, pair_days.fleet_pairs(session, end.to_pydatetime()))
    days_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    with db.transaction() as session:
        n_fleet_days = fleet_days.build(session)
    fleet_days_s = time.perf_counter() - t0
    db.dispose()
    t0 = time.perf_counter()
    sql(url, "VACUUM ANALYZE", autocommit=True)
    vacuum_s = time.perf_counter() - t0
    if progress:
        progress(1)
    rng = np.random.default_rng(4)
    latest_rng = np.random.default_rng(5)  # its own: the other requests' draws stay as they were
    summary: dict[str, dict] = {name: {} for name in SUMMARY_H}
    comparison: dict[str, dict] = {}
    with fleet_client(url, model) as client:
        viewer = tokens(url, "viewer")[0]

        def timed(path: str, params: dict) -> tuple[float, dict]:
            t0 = time.perf_counter()
            reply = client.get(path, params=params, headers=viewer)
            elapsed = time.perf_counter() - t0
            if reply.status_code != 200:
                raise RuntimeError(f"{path} failed: {reply.status_code} {reply.text[:200]}")
            return elapsed, reply.json()

        def summary_at(hours: int, stop: pd.Timestamp) -> tuple[float, dict]:
            return timed("/api/v1/fleet/summary", {"hours": hours, "end": stop.isoformat()})

        for hours in SUMMARY_H.values():  # untimed: the cache filled as a dashboard's first look
            summary_at(hours, end)
        refresh: dict[str, list[float]] = {name: [] for name in SUMMARY_H}
        for _ in range(samples):  # a control room's views, refreshed in turn
            for name, hours in SUMMARY_H.items():
                refresh[name].append(summary_at(hours, end)[0])
        trains_per_reply = len(summary_at(24, end)[1]["trains"])
        for name, hours in SUMMARY_H.items():
            fresh = [summary_at(hours, _random_end(rng, days))[0] for _ in range(samples)]
            latest = [
                summary_at(hours, _latest_end(latest_rng, days, k))[0] for k in range(samples)
            ]
            summary[name] = {
                "refresh": latency_ms(refresh[name]),
                "new": latency_ms(fresh),
                "latest": latency_ms(latest),
            }
        width = len(ids[0].rsplit("-", 1)[0]) - 1
        for name, hours in COMPARISON_H.items():
            spent = []
            for _ in range(samples):
                train = f"C{int(rng.integers(pairs)):0{width}d}"
                stop = _random_end(rng, days)
                start = stop - pd.Timedelta(hours=hours)
                params = {"start": start.isoformat(), "end": stop.isoformat()}
                spent.append(timed(f"/api/v1/trains/{train}/comparison", params)[0])
            comparison[name] = latency_ms(spent)
    floor = _floor(url, days, samples)
    if progress:
        progress(1)
    rollup_mb = sql(url, "SELECT pg_total_relation_size('window_rollups')")[0][0] / 2**20
    days_mb = sql(url, "SELECT pg_total_relation_size('pair_days')")[0][0] / 2**20
    return {
        "pairs": pairs,
        "days": days,
        "rows": n_rows,
        "setpoints": n_setpoints,
        "trains_per_reply": trains_per_reply,
        "samples": samples,
        "summary": summary,
        "comparison": comparison,
        "floor": floor,
        "new_vs_floor_p95": {
            name: summary[name]["new"]["p95_ms"] / floor[name]["p95_ms"] for name in SUMMARY_H
        },
        "table": table_size(url),
        "rollups": {"rows": n_rollups, "build_s": rollup_s, "total_mb": rollup_mb},
        "pair_days": {"rows": n_days, "build_s": days_s, "total_mb": days_mb},
        "fleet_days": {"rows": n_fleet_days, "build_s": fleet_days_s},
        "copy": {
            "rows": n_rows,
            "seconds": copy_s,
            "rows_per_s": n_rows / copy_s,
            "mb_sent": sent / 2**20,
            "vacuum_analyze_s": vacuum_s,
        },
        "target_p95_ms": {
            "summary": SUMMARY_TARGET_P95_MS,
            "comparison_7d": COMPARISON_TARGET_P95_MS,
        },
    }


def met(part: dict) -> bool:
    """Whether :func:`run`'s figures meet the targets: every summary window's p95 refreshed,
    new and latest, and the 7-day comparison's p95."""
    summary = all(
        v[kind]["p95_ms"] <= SUMMARY_TARGET_P95_MS
        for v in part["summary"].values()
        for kind in ("refresh", "new", "latest")
    )
    return summary and part["comparison"]["7d"]["p95_ms"] <= COMPARISON_TARGET_P95_MS


def copy_setpoints(url: str, ids: list[str], days: int) -> int:
    """A setpoint per coach and 5-minute tick over the data's days, as the layer's trial
    issues them: on each service day (switch hour 3 local) one coach of each train under the
    layer (``ddpc``), the other on T_rule with the layer off (``rule``/``inactive``), the roles
    swapped day by day (a crossover); loaded with COPY, ``last_tick`` set to the last tick.
    Returns how many."""
    import psycopg

    from trainclimate.analysis import trial_plan

    ticks = pd.date_range(
        DATA_START, DATA_START + pd.Timedelta(days=days), freq="5min", inclusive="left"
    )
    even = trial_plan.service_days(ticks) % 2 == 0
    stamps = [t.isoformat() for t in ticks]
    on = "\t22.0\t21.4\tddpc\toptimal\t\t{t}\n"
    off = "\t22.0\t22.0\trule\tinactive\t\t{t}\n"
    statement = (
        "COPY setpoints (coach_id, tick, t_rule_c, t_ref_c, source, reason, detail, created_at)"
        " FROM STDIN"
    )
    with psycopg.connect(url) as conn, conn.cursor() as cur:
        with cur.copy(statement) as copy:
            for cid in ids:
                a = cid.endswith("-A")
                copy.write(
                    "".join(
                        f"{cid}\t{t}" + (on if day == a else off).format(t=t)
                        for t, day in zip(stamps, even, strict=True)
                    )
                )
        cur.execute(
            "UPDATE coaches SET last_tick = %s WHERE id = ANY(%s)", (ticks[-1].to_pydatetime(), ids)
        )
    return len(ids) * len(ticks)


def _random_end(rng, days: int) -> pd.Timestamp:
    """A random minute in the data's second hour to its end."""
    return DATA_START + pd.Timedelta(minutes=int(rng.integers(60, days * 1440 + 1)))


def _latest_end(rng, days: int, k: int) -> pd.Timestamp:
    """A random minute inside the data's (k + 1)-th last 30-minute window but its first: a range
    ending there ends on that window's start, in the day still running (no pair day yet), as
    every range ending now does when a new window is complete. The data end at midnight UTC and
    the service days switch at 02:00 UTC, so for k < 43 that day is the data's last."""
    window_start = DATA_START + pd.Timedelta(days=days) - pd.Timedelta(minutes=30 * (k + 1))
    return window_start + pd.Timedelta(minutes=int(rng.integers(1, 30)))


def _floor(url: str, days: int, samples: int) -> dict:
    """The rollup floor's latency (ms) over each summary window ending at random whole windows,
    ``samples`` times each, on one connection."""
    import psycopg

    rng = np.random.default_rng(6)
    first = round(DATA_START.timestamp()) // 1800
    out = {}
    with psycopg.connect(url) as conn:
        for name, hours in SUMMARY_H.items():
            spent = []
            for _ in range(samples + 2):
                hi = first + int(rng.integers(2, days * 48 + 1))
                t0 = time.perf_counter()
                conn.execute(FLOOR, (hi - 2 * hours, hi)).fetchall()
                spent.append(time.perf_counter() - t0)
            out[name] = latency_ms(spent[2:])
    return out


def _rows(pairs: int, days: int, seed: int):
    """Blocks for :func:`~.database.copy_telemetry`: ``pairs`` × ``days`` of 1-minute rows, one
    block per day, in the order a live feed stores them (hour by hour, coach after coach)."""
    ids, train, active = pair_ids("C", pairs)
    start_s = DATA_START.timestamp()
    rng = np.random.default_rng(seed)
    hour, coach, minute = np.meshgrid(
        np.arange(24), np.arange(len(ids)), np.arange(1, 61), indexing="ij"
    )
    coach, day_minute = coach.ravel(), (hour * 60 + minute).ravel()
    id_array = np.asarray(ids, dtype="S")[coach]
    for day in range(days):
        m = day * 1440 + day_minute
        v = synthetic(rng, train[coach], active[coach], m)
        yield copy_block(id_array, start_s + 60.0 * m, v)
