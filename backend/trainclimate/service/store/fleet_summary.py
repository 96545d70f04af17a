"""The fleet at a glance: every train's activated-vs-deactivated savings and comfort over the last
hours, pooled into the fleet's, the coaches by status, and the coaches that need attention.

A train's numbers are those of its pair comparison (:mod:`.comparison`) over the same range:
the same 30-minute windows (aligned to the clock, the first one after the pair's data or the range
starts), labelled and excluded the same way (:mod:`.pair_labels`: the coach that ran the layer,
a minute missing, a link lost, an override, a tick that was not DDPC on the activated coach),
violation and discomfort over the same minutes (both coaches in regular mode, nothing affected).
Here each train's whole service days come from its pair days (:mod:`.pair_days`, kept by the
scheduler once a day is over), the rest from the telemetry's sums per pair and window in the
window rollups kept at ingest (:mod:`.rollups`; the raw minutes only for the windows they cannot
give exactly) and the setpoints' counts per coach and window in the setpoint rollups
(:mod:`.setpoint_rollups`); the fleet's naive figures pool its trains' energies, its savings
estimate their trial estimates (:func:`trainclimate.analysis.trial_pool.pool`). Each train's figures
are kept in the read cache while its rows and setpoints in the counted range and its overrides
are unchanged (:func:`.pair_windows.pair_states`).
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timedelta

import numpy as np
import pandas as pd
from sqlalchemy import select, text
from sqlalchemy.orm import Session

from trainclimate.analysis import trial, trial_pool
from trainclimate.analysis.savings import PairTotals
from trainclimate.coach.meters import HEADLINE_METER, METERS
from trainclimate.service.store import (
    fleet_days,
    pair_days,
    pair_days_read,
    pair_windows,
    plans,
    queries,
)
from trainclimate.service.store.attention import (
    VIOLATION_LOOKBACK_MIN,
    attention,
    coaches_by_status,
)
from trainclimate.service.store.cache import ReadCache
from trainclimate.service.store.models import (
    Coach,
    CoachFeed,
    FleetClock,
    PairGuard,
    Train,
)
from trainclimate.service.store.records import CoachView


def coach_feeds(session: Session) -> dict[str, tuple]:
    """Every coach's feed row (:class:`~.models.CoachFeed`: one row per coach, whatever the
    history kept) and last tick, read once for a summary: coach id → (first, newest, last_ok,
    late_rows, last_tick); a coach without a feed row has None for its times and 0 late rows."""
    rows = session.execute(
        select(
            Coach.id,
            CoachFeed.first,
            CoachFeed.newest,
            CoachFeed.last_ok,
            CoachFeed.late_rows,
            Coach.last_tick,
        ).outerjoin(CoachFeed, CoachFeed.coach_id == Coach.id)
    )
    return {
        cid: (first, newest, last_ok, late or 0, tick)
        for cid, first, newest, last_ok, late, tick in rows
    }


#: Pair days analysed together at most (bounds the arrays: 8 192 pair days of windows ≈ 95 MB,
#: where no pair day holds them): 256 trains over 30 days, up to 910 over a week. Each chunk
#: costs its own reads and set-up: a new summary of 450 trains took 3-8 % less in one chunk than
#: in two of 256 on a slower host, 0-4 % on a quicker one (measured).
_CHUNK_PAIR_DAYS = 8192
#: The summary's window: the rollups' and the pair days'. [min]
WINDOW_MIN = float(pair_days.WINDOW_MIN)


def pair_results(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    switch_hours: list[int],
    cache: ReadCache | None = None,
    feeds: dict[str, tuple] | None = None,
) -> dict[str, dict]:
    """Each pair's figures over its range (lo, hi] with its train's switch hour
    (:func:`.pair_days_read.pair_results`), those whose state (:func:`.pair_windows.pair_states`)
    is unchanged since they were computed taken from ``cache`` (a dashboard's refresh
    recomputes nothing; ``feeds``: the coaches' :func:`coach_feeds`, else read for it). Coach
    0's id → result (shared with the cache: not to be changed)."""
    overrides = pair_windows.overrides_over(session, pairs)
    # what the states are made of, read once for the request (a read per chunk cost 5 ms each,
    # measured); the states of ranges read later in it are as old or older: never too new
    marks: dict[str, tuple] | None = None
    states: Sequence[tuple | None] = [None] * len(pairs)
    if cache is not None:
        if feeds is None:
            marks = pair_windows.coach_marks(session, pairs)
        else:
            marks = {c: (f[1], f[3], f[4]) for c, f in feeds.items()}
        states = pair_windows.pair_states(session, pairs, overrides, marks)
    out, missing = {}, []
    for pair, hour, state in zip(pairs, switch_hours, states, strict=True):
        key = ("pair-result", *pair, WINDOW_MIN, hour)
        kept = cache.lookup(key, state) if cache is not None else None
        if kept is None:
            missing.append((pair, hour, state, key))
        else:
            out[pair[0]] = kept
    if missing and session.get_bind().dialect.name == "postgresql":
        # the range's reads run often enough for psycopg to prepare them, and PostgreSQL then
        # plans them once for any bounds: reading 14 400 pair days took 160-228 ms so, against
        # 60-68 ms planned for its values (measured, before they were read packed); the
        # partial days' windows and the rollups are read alike
        session.execute(text("SET LOCAL plan_cache_mode = force_custom_plan"))
    # each chunk's bootstraps run on their own threads while the next chunk is read (the
    # reads leave much of the second core idle); the figures are kept, not the sums they came
    # from: one answer per train and range
    fleet: dict = {}  # the fleet days read, once for all chunks
    with ThreadPoolExecutor(trial.BOOTSTRAP_THREADS, thread_name_prefix="bootstrap") as executor:
        read = [
            (
                chunk,
                pair_days_read.pair_results_later(
                    session,
                    [m[0] for m in chunk],
                    [m[1] for m in chunk],
                    overrides,
                    executor,
                    cache,
                    marks,
                    fleet=fleet,
                ),
            )
            for chunk in _chunks(missing)
        ]
        for chunk, results in read:
            for (pair, _, state, key), result in zip(chunk, results(), strict=True):
                out[pair[0]] = result
                if cache is not None:
                    cache.put(key, state, result)
    return out


def _chunks(missing: list) -> list[list]:
    """``missing`` (per pair its (pair, …), the pair (coach 0, coach 1, lo, hi)) in chunks of at
    most :data:`_CHUNK_PAIR_DAYS` pair days, counting each pair's range as the service days it
    can touch (its whole days, and a partial day at either end)."""
    span = max((p[3] - p[2] for p, *_ in missing), default=timedelta(0))
    size = max(1, _CHUNK_PAIR_DAYS // (span // timedelta(days=1) + 2))
    return [missing[i : i + size] for i in range(0, len(missing), size)]


#: Reads of the trains' figures at most, when a pair day they read is rebuilt meanwhile.
_ATTEMPTS = 3


def summary(
    session: Session,
    views: list[CoachView],
    hours: float,
    end: datetime | None = None,
    cache: ReadCache | None = None,
) -> dict:
    """The fleet at a glance: savings and comfort of every train over the ``hours`` up to
    ``end`` (default: each train's fleet clock — the demo's simulated time, the live fleet's
    newest telemetry) and the fleet's, pooled; the coaches by status and those that need
    attention now, from their ``views`` (as the fleet list shows them,
    :func:`.queries.coach_view`). Trains without a pair of coaches are left out. Each train's
    figures are its pair comparison's (:func:`pair_result`); the fleet's savings pool the
    trains' estimates that have an interval (:func:`trial_pool.pool`), and its naive figure the
    trains' energies. With ``cache``, each pair's window sums and setpoint counts are kept
    there while its rows and setpoints in the range and its overrides are unchanged: the range
    ends at the last whole window, so data arriving in the current one leaves it unchanged, and
    the dashboard's refreshes read a few index-only counts instead of every row.

    Returns
    -------
    dict
        ``hours``, ``window_min``, the fleet's ``meter`` (the HVAC units' when every train
        counts them, else the whole coach's), ``savings_pct`` [%] (the pooled estimate, else
        the naive figure) with ``savings_ci95_pct``, ``savings_ci95_reason``, ``estimator``
        (``random_effects`` or ``naive``), ``trains_pooled``, ``trains_confounded``,
        ``naive_savings_pct`` and ``savings_by_meter_pct`` (energy over energy),
        ``energy_activated_kwh`` and ``energy_deactivated_kwh`` [kWh],
        ``avg_hourly_violation_activated_k`` and ``avg_hourly_violation_deactivated_k`` [K],
        ``excluded_minutes`` [min], ``counted_windows``, ``counted_hours`` [h]; ``trains``: per
        train ``id``, ``name``, ``plan`` (in force at its end), ``coaches``, ``activated``,
        ``deactivated`` (now), ``start``, ``end`` and its :func:`figures`; ``windows``: per
        window (oldest first) its ``start``, the energies of the trains that count it
        (``energy_activated_kwh``, ``energy_deactivated_kwh``, kWh: they add up to the fleet's)
        and how many ``trains`` do; ``coaches_by_status`` (:func:`coaches_by_status`) and
        ``attention`` (:func:`attention`).
    """
    # trains and coaches as plain rows (an ORM object per train and coach costs more than the
    # rest of a refresh at 450 trains)
    by_train: dict[str, list] = {}
    for c in session.execute(
        select(Coach.id, Coach.train_id, Coach.fleet, Coach.ddpc_active).order_by(Coach.id)
    ):
        by_train.setdefault(c.train_id, []).append(c)
    paired = []
    for t in session.execute(select(Train.id, Train.name).order_by(Train.id)):
        pair = queries.pick_pair(by_train.get(t.id, []))
        if pair is not None:
            paired.append((t, pair))
    feeds = coach_feeds(session)
    times = {cid: f[:2] for cid, f in feeds.items()}
    clocks = {c.name: c.time for c in session.scalars(select(FleetClock))}
    ranges, pairs = [], []
    # the trains mostly share a range: its bounds as datetimes made once (pandas' arithmetic
    # costs ≈ 20 µs a train)
    bounds: dict[tuple, tuple[datetime, datetime]] = {}
    for t, (c0, c1) in paired:
        stop = end or clocks.get(c0.fleet) or times.get(c0.id, (None, None))[1]
        if stop is None:
            continue  # no data and no clock: nothing to count
        firsts = [times.get(c.id, (None, None))[0] for c in (c0, c1)]
        earliest = min((f for f in firsts if f is not None), default=None)
        start = stop - timedelta(hours=hours)
        first, n = queries.counted_range(start, stop, earliest, WINDOW_MIN)
        if (first, n) not in bounds:
            hi = first + pd.Timedelta(minutes=WINDOW_MIN * n)
            bounds[(first, n)] = (first.to_pydatetime(), hi.to_pydatetime())
        lo_dt, hi_dt = bounds[(first, n)]
        ranges.append((t, c0, c1, lo_dt, n, stop))
        pairs.append((c0.id, c1.id, lo_dt, hi_dt))
    by_stop: dict[datetime, list[str]] = {}
    for t, _, _, _, _, stop in ranges:
        by_stop.setdefault(stop, []).append(t.id)
    in_force = {}
    for stop, ids in by_stop.items():
        in_force |= {tid: rows[0] for tid, rows in plans.plans_at(session, ids, stop).items()}
    terms = [plans.terms(in_force.get(t.id)) for t, *_ in ranges]
    hours_of = [h for _, h, _ in terms]
    for attempt in range(_ATTEMPTS):
        # the charts of the days read whole from their pair days, already pooled per day (the
        # fleet days); a pair day rebuilt meanwhile (its chart gone): read again, uncached
        found = pair_results(session, pairs, hours_of, cache if attempt == 0 else None, feeds)
        try:
            day_w, day_n, day_e = fleet_days.charts(
                session,
                [
                    (c0, c1, h, *found[c0]["chart_days"])
                    for (c0, c1, *_), h in zip(pairs, hours_of, strict=True)
                ],
            )
            break
        except pair_days.PairDaysChangedError:
            if attempt == _ATTEMPTS - 1:
                raise
    results = [
        (t, c0, c1, first, stop, {**found[c0.id], "plan": plan})
        for (t, c0, c1, first, _, stop), (plan, _, _) in zip(ranges, terms, strict=True)
    ]
    # the fleet's headline is the HVAC units' meter when every train has it
    fleet_meters = [m for m in METERS if all(m in r[-1]["totals"] for r in results)]
    fleet_meter = HEADLINE_METER if HEADLINE_METER in fleet_meters else "hvac_and_floor"
    fleet = {
        m: PairTotals.pooled([r[-1]["totals"][m] for r in results], WINDOW_MIN)
        for m in fleet_meters
    }
    out_trains, counted_w, counted_e = [], [], []
    chart_columns = [2 * list(METERS).index(fleet_meter) + k for k in (0, 1)]
    for t, c0, c1, first, stop, r in results:
        chart_w, chart_e = r["chart"]
        counted_w.append(chart_w)
        counted_e.append(chart_e)
        on = c0 if c0.ddpc_active else c1 if c1.ddpc_active else None
        off = c0 if not c0.ddpc_active else c1 if not c1.ddpc_active else None
        out_trains.append(
            {
                "id": t.id,
                "name": t.name,
                "plan": r["plan"],
                "coaches": [c0.id, c1.id],
                "activated": on.id if on is not None else None,
                "deactivated": off.id if off is not None else None,
                "start": first,
                "end": stop,
                **r["figures"],
            }
        )
    # the counted windows' energies, pooled per window over the trains that count it
    all_w = np.concatenate([*counted_w, day_w])
    all_n = np.concatenate([np.ones(len(all_w) - len(day_w)), day_n])
    all_e = np.concatenate([*counted_e, day_e])[:, chart_columns].T
    # the windows are integers: binned by their offset from the first (a sort costs more)
    first_w = int(all_w.min()) if len(all_w) else 0
    offset = all_w - first_w
    per_window = np.bincount(offset, all_n)
    present = np.flatnonzero(per_window)
    starts, n_trains = present + first_w, per_window[present]
    pooled_e = np.stack([np.bincount(offset, e, minlength=len(per_window))[present] for e in all_e])
    totals = fleet[fleet_meter]
    pooled = trial_pool.pool([r[-1]["estimate"] for r in results])
    naive = totals.savings_pct
    clocks_now = {v["id"]: v["clock"] for v in views if v["clock"] is not None}
    return {
        "hours": hours,
        "window_min": WINDOW_MIN,
        "meter": fleet_meter,
        "savings_pct": pooled["savings_pct"] if pooled["savings_pct"] is not None else naive,
        "savings_ci95_pct": pooled["savings_ci95_pct"],
        "savings_ci95_reason": pooled["savings_ci95_reason"],
        "estimator": "random_effects" if pooled["savings_pct"] is not None else "naive",
        "standard_error_pct": pooled["standard_error_pct"],
        "trains_pooled": pooled["trains_pooled"],
        "trains_confounded": pooled["trains_confounded"],
        "naive_savings_pct": naive,
        "savings_by_meter_pct": {m: fleet[m].savings_pct if m in fleet else None for m in METERS},
        "energy_activated_kwh": totals.energy_activated_kwh,
        "energy_deactivated_kwh": totals.energy_deactivated_kwh,
        "avg_hourly_violation_activated_k": totals.avg_hourly_violation_k,
        "avg_hourly_violation_deactivated_k": totals.baseline_violation_k,
        "excluded_minutes": totals.excluded_minutes,
        "counted_windows": sum(r[-1]["counted_windows"] for r in results),
        "counted_hours": totals.counted_hours,
        "trains": out_trains,
        "windows": [
            {
                "start": start,
                "energy_activated_kwh": e_act,
                "energy_deactivated_kwh": e_deact,
                "trains": n,
            }
            for start, e_act, e_deact, n in zip(
                pd.to_datetime(starts * pair_days.WINDOW_S, unit="s", utc=True).to_pydatetime(),
                *pooled_e.tolist(),
                n_trains.astype(np.int64).tolist(),
                strict=True,
            )
        ],
        "coaches_by_status": coaches_by_status(views),
        "attention": attention(
            views, comfort_violations(session, clocks_now, feeds), handed_back(session)
        ),
    }


def handed_back(session: Session) -> dict[str, dict]:
    """The trains whose guard handed the layer back to T_rule (:mod:`.guard`): train →
    ``coach_id`` (the coach the layer was on) and ``figures`` (what it tripped on)."""
    rows = session.execute(
        select(PairGuard.train_id, PairGuard.coach_id, PairGuard.figures).where(
            PairGuard.tripped_at.is_not(None)
        )
    )
    return {t: {"coach_id": c, "figures": f} for t, c, f in rows}


def comfort_violations(
    session: Session, ends: dict[str, datetime], feeds: dict[str, tuple] | None = None
) -> dict[str, float]:
    """How long each coach's decks have been outside the comfort band without a break, up to
    its newest row, over the :data:`.attention.VIOLATION_LOOKBACK_MIN` before ``ends[coach]``,
    from each coach's comfort state kept at ingest (:class:`~.models.CoachFeed`: two times
    per coach, whatever the history kept).

    A row is within comfort when every deck is within T_rule ± T_max or the coach is not in
    regular mode (the band applies in regular mode only).

    Parameters
    ----------
    ends : dict
        Coach id → the end of its lookback (its fleet clock).
    feeds : dict, optional
        The coaches' :func:`coach_feeds`, if read already.

    Returns
    -------
    dict
        Coach id → minutes from its last row within comfort to its newest row (the whole
        lookback when no row within it was); coaches whose newest row is within comfort, or
        without rows in the lookback, are left out. [min]
    """
    if not ends:
        return {}
    lookback = timedelta(minutes=VIOLATION_LOOKBACK_MIN)
    if feeds is None:
        feeds = coach_feeds(session)
    out = {}
    for cid, (_, newest, last_ok, _, _) in feeds.items():
        if cid not in ends or newest is None:
            continue
        lo = ends[cid] - lookback
        if newest <= lo:
            continue  # no row in the lookback
        since = last_ok if last_ok is not None and last_ok > lo else lo
        if since != newest:
            out[cid] = (newest - since).total_seconds() / 60.0
    return out
