"""The fleet at a glance: every train's activated-vs-deactivated savings and comfort over the last
hours, pooled into the fleet's, the coaches by status, and the coaches that need attention.

A train's numbers are those of its pair comparison (:mod:`.comparison`) over the same range:
the same 30-minute windows (aligned to the clock, the first one after the pair's data or the range
starts), labelled and excluded the same way (:mod:`.pair_trial`: the coach that ran the layer,
a minute missing, a link lost, an override, a tick that was not DDPC on the activated coach),
violation and discomfort over the same minutes (both coaches in regular mode, nothing affected).
Here the telemetry's sums per pair and window come from the window rollups kept at ingest
(:mod:`.rollups`; the raw minutes only for the windows they cannot give exactly, summed in the
database in one statement over every train), and the setpoints' counts per coach and window from
the setpoint rollups kept by the scheduler (:mod:`.setpoint_rollups`); the fleet's naive figures
pool its trains' energies, its savings estimate their trial estimates
(:func:`trainclimate.analysis.trial.pool`). Each train's figures are kept in the read cache while
its rows and setpoints in the counted range and its overrides are unchanged (:func:`pair_states`).
"""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pandas as pd
from sqlalchemy import (
    and_,
    case,
    false,
    func,
    literal,
    not_,
    or_,
    select,
    text,
    true,
    union_all,
)
from sqlalchemy.orm import Session
from sqlalchemy.sql.expression import ColumnElement

from trainclimate.analysis import trial
from trainclimate.analysis.savings import PairTotals
from trainclimate.service.store import pair_trial, plans, queries, rollups, setpoint_rollups
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
    Override,
    PairGuard,
    Telemetry,
    Train,
    UTCDateTime,
)
from trainclimate.service.store.pair_trial import COUNTS, SUMS, energy_columns
from trainclimate.service.store.sqltime import EpochSeconds, OnMinute
from trainclimate.sim.power import HEADLINE_METER, METERS
from trainclimate.sim.setpoint import COMFORT_BAND_K

DECKS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
ID, TIME = Telemetry.coach_id.type, UTCDateTime()


def _violation(row, t_max_k: float) -> list[ColumnElement]:
    """Per deck, max(0, |T_room − T_rule| − T_max) of telemetry row ``row`` (paper, Eq. (4)). [K]"""
    out = []
    for deck in DECKS:
        excess = func.abs(row.c[deck] - row.c.t_rule_c) - t_max_k
        out.append(case((excess > 0, excess), else_=0.0))
    return out


def _literal_table(name: str, columns: dict, rows: list[tuple]):
    """A small table ``name`` of literal ``rows`` with ``columns`` (name → SQL type), as a CTE
    of a UNION ALL of SELECTs (both databases take it)."""
    return union_all(
        *(
            select(
                *(literal(v, t).label(n) for v, (n, t) in zip(row, columns.items(), strict=True))
            )
            for row in rows
        )
    ).cte(name)


def overrides_over(session: Session, pairs: list[tuple[str, str, datetime, datetime]]) -> list:
    """The overrides of the pairs' coaches that overlap the union of their ranges: rows of
    (id, coach_id, starts_at, ends_at, cancelled_at), by id."""
    if not pairs:
        return []
    coaches = {c for pair in pairs for c in pair[:2]}
    rows = session.execute(
        select(
            Override.id,
            Override.coach_id,
            Override.starts_at,
            Override.ends_at,
            Override.cancelled_at,
        )
        .where(queries.among(Override.coach_id, coaches))
        .where(
            Override.starts_at < max(x[3] for x in pairs),
            Override.ends_at > min(x[2] for x in pairs),
        )
        .order_by(Override.id)
    ).all()
    return [r for r in rows if r.coach_id in coaches]


def window_sums(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    window_min: float = 30.0,
    t_max_k: float = COMFORT_BAND_K,
    overrides: list | None = None,
) -> dict[str, dict[int, np.ndarray]]:
    """Per pair and window, the sums a pair comparison is made of, read in one statement.

    Parameters
    ----------
    pairs : list of (coach 0 id, coach 1 id, lo, hi)
        The pairs, each counted over the telemetry rows stamped in (lo, hi].
    window_min : float, default 30.0
        Window length. [min]
    t_max_k : float
        Comfort half-band T_max. [K]
    overrides : list, optional
        :func:`overrides_over` the pairs (read here if not given).

    Returns
    -------
    dict
        Coach 0's id → window index (the window's start in window lengths since 1970) →
        an array of :data:`SUMS`: the minutes both coaches have a row on the minute grid, those
        affected (either coach not connected, without power, or overridden), the energy of
        each coach [kWh], the minutes counted for comfort (nothing affected, both in regular
        mode), the discomfort per deck of coach 0 and coach 1 over those [K·h], each coach's
        energy on the HVAC units' meter (without the floor and wall heating) [kWh], the minutes
        where a coach's row does not split the floor heating off, those where a coach's link
        was lost and those overridden.
    """
    if not pairs:
        return {}
    p = _literal_table("pairs", {"act": ID, "deact": ID, "lo": TIME, "hi": TIME}, pairs)
    if overrides is None:
        overrides = overrides_over(session, pairs)
    a, b = Telemetry.__table__.alias("a"), Telemetry.__table__.alias("b")
    overridden = or_(
        false(),
        *(
            and_(
                or_(p.c.act == cid, p.c.deact == cid),
                a.c.time > starts,
                a.c.time <= (cancelled or ends),
            )
            for _, cid, starts, ends, cancelled in overrides
        ),
    )
    affected = or_(
        not_(a.c.connected),
        not_(b.c.connected),
        a.c.power_kw.is_(None),
        b.c.power_kw.is_(None),
        overridden,
    )
    # a row stamped t is the minute starting t − 1 min: its window is ⌊(t − 60 s) / window⌋
    window = ((EpochSeconds(a.c.time) - 60) // round(window_min * 60)).label("w")
    pair_rows = a.join(
        b,
        and_(
            b.c.coach_id == p.c.deact,
            b.c.time == a.c.time,
            b.c.time > p.c.lo,  # b's range too: each side is one range scan of the index
            b.c.time <= p.c.hi,
        ),
    )
    in_range = and_(a.c.coach_id == p.c.act, a.c.time > p.c.lo, a.c.time <= p.c.hi)
    # the pair's minutes, each value computed once (OFFSET 0 keeps PostgreSQL from inlining the
    # subquery into the sums, which would compute them again in every one)
    minutes = (
        select(
            p.c.act,
            window,
            # rows off the minute grid do not count (the comparison reads the grid's minutes)
            OnMinute(a.c.time).label("grid"),
            affected.label("bad"),
            or_(not_(a.c.connected), not_(b.c.connected)).label("lost"),
            overridden.label("overridden"),
            and_(a.c.mode == "regular", b.c.mode == "regular").label("band"),
            func.coalesce(a.c.power_kw, 0.0).label("pa"),
            func.coalesce(b.c.power_kw, 0.0).label("pb"),
            func.coalesce(a.c.floor_power_kw, 0.0).label("fa"),
            func.coalesce(b.c.floor_power_kw, 0.0).label("fb"),
            or_(a.c.floor_power_kw.is_(None), b.c.floor_power_kw.is_(None)).label("unsplit"),
            *(v.label(f"va{i}") for i, v in enumerate(_violation(a, t_max_k))),
            *(v.label(f"vb{i}") for i, v in enumerate(_violation(b, t_max_k))),
        )
        .select_from(pair_rows)
        .where(in_range)
        .offset(0)
    )
    postgresql = session.bind.dialect.name == "postgresql"
    if postgresql:
        # pair by pair (LATERAL): PostgreSQL hashes one coach's rows and probes the other's,
        # where over all pairs at once it probes the index once per row (3× slower, measured)
        minutes = minutes.correlate(p)
    m = minutes.subquery("m")
    counted = and_(m.c.grid, not_(m.c.bad), m.c.band)
    kwh = 1.0 / 60.0  # a 1-minute row's mean power in kW → kWh
    sums = [
        func.sum(case((m.c.grid, 1), else_=0)),
        func.sum(case((and_(m.c.grid, m.c.bad), 1), else_=0)),
        func.sum(case((m.c.grid, m.c.pa), else_=0.0)) * kwh,
        func.sum(case((m.c.grid, m.c.pb), else_=0.0)) * kwh,
        func.sum(case((counted, 1), else_=0)),
        *(func.sum(case((counted, m.c[f"va{i}"]), else_=0.0)) / 60.0 for i in range(3)),
        *(func.sum(case((counted, m.c[f"vb{i}"]), else_=0.0)) / 60.0 for i in range(3)),
        func.sum(case((m.c.grid, m.c.pa - m.c.fa), else_=0.0)) * kwh,
        func.sum(case((m.c.grid, m.c.pb - m.c.fb), else_=0.0)) * kwh,
        func.sum(case((and_(m.c.grid, m.c.unsplit), 1), else_=0)),
        func.sum(case((and_(m.c.grid, m.c.lost), 1), else_=0)),
        func.sum(case((and_(m.c.grid, m.c.overridden), 1), else_=0)),
    ]
    if postgresql:
        # without JIT compilation, which the plan's cost asks for and which took longer than
        # the query itself (300 ms against 100 ms, measured)
        session.execute(text("SET LOCAL jit = off"))
        per_pair = select(m.c.w, *sums).group_by(m.c.w).lateral("per_pair")
        query = select(p.c.act, *per_pair.c).select_from(p).join(per_pair, true())
    else:
        query = select(m.c.act, m.c.w, *sums).group_by(m.c.act, m.c.w)
    rows = session.execute(query).all()
    out: dict[str, dict[int, np.ndarray]] = {}
    for act, w, *values in rows:
        out.setdefault(act, {})[int(w)] = np.array([v or 0.0 for v in values], float)
    return out


def _grid(by_window: dict[int, np.ndarray], w_lo: int, n: int, into: np.ndarray) -> np.ndarray:
    """``into`` (n, …) with the windows of ``by_window`` (index → values) in [w_lo, w_lo + n)
    set."""
    for w, values in by_window.items():
        if w_lo <= w < w_lo + n:
            into[w - w_lo] = values
    return into


def _range_windows(lo: datetime, hi: datetime, window_min: float) -> tuple[int, int]:
    """(first window index, number of windows) of (lo, hi] on window boundaries."""
    step = round(window_min * 60)
    w_lo = round(lo.timestamp()) // step
    return w_lo, round(hi.timestamp()) // step - w_lo


def pair_grids(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    window_min: float,
    overrides: list,
) -> dict[str, np.ndarray]:
    """:func:`window_sums` of each pair as an array over its range's windows, (W, len(SUMS)),
    zeros where it has no row: from the window rollups (:mod:`.rollups`) where they give them
    exactly, from the raw minutes for the other windows (and for any window length but the
    rollups')."""
    if window_min != rollups.WINDOW_MIN:
        n = {p[0]: _range_windows(p[2], p[3], window_min)[1] for p in pairs}
        grids = {c0: np.zeros((k, len(SUMS))) for c0, k in n.items()}
        raw = pairs
    else:
        grids, raw = rollups.pair_grids(session, pairs, overrides)
    los = {p[0]: _range_windows(p[2], p[3], window_min)[0] for p in pairs}
    for c0, by_window in window_sums(session, raw, window_min, overrides=overrides).items():
        _grid(by_window, los[c0], len(grids[c0]), grids[c0])
    return grids


def pair_counts(
    session: Session, pairs: list[tuple[str, str, datetime, datetime]], window_min: float
) -> dict[str, np.ndarray]:
    """Both coaches' setpoint counts (:func:`.pair_trial.setpoint_counts`) of each pair per
    window of its range, (W, 2, len(COUNTS)): from the setpoint rollups
    (:mod:`.setpoint_rollups`) for their 30-minute windows, else counted over the setpoints."""
    if not pairs:
        return {}
    coaches = sorted({c for pair in pairs for c in pair[:2]})
    ranges = [_range_windows(lo, hi, window_min) for _, _, lo, hi in pairs]
    if window_min != setpoint_rollups.WINDOW_MIN:
        counts = pair_trial.setpoint_counts(
            session, coaches, min(p[2] for p in pairs), max(p[3] for p in pairs), window_min
        )
        out = {}
        for (c0, c1, _, _), (w_lo, n) in zip(pairs, ranges, strict=True):
            dense = np.zeros((n, 2, len(COUNTS)))
            for side, c in enumerate((c0, c1)):
                _grid(counts.get(c, {}), w_lo, n, dense[:, side])
            out[c0] = dense
        return out
    rows = setpoint_rollups.read_rows(
        session, coaches, min(r[0] for r in ranges), max(r[0] + r[1] for r in ranges)
    )
    values = np.stack([rows[c] for c in COUNTS], axis=-1).reshape(len(rows), len(COUNTS))
    position = {c: i for i, c in enumerate(coaches)}
    # each coach's windows in order, so that a pair's side is two slices
    order = np.lexsort((rows["window"], rows["coach"]))
    coach, window, values = rows["coach"][order], rows["window"][order], values[order]
    edges = np.searchsorted(coach, np.arange(len(coaches) + 1))
    out = {}
    for (c0, c1, _, _), (w_lo, n) in zip(pairs, ranges, strict=True):
        dense = np.zeros((n, 2, len(COUNTS)))
        for side, c in enumerate((c0, c1)):
            a, b = edges[position[c]], edges[position[c] + 1]
            lo, hi = a + np.searchsorted(window[a:b], [w_lo, w_lo + n])
            dense[window[lo:hi] - w_lo, side] = values[lo:hi]
        out[c0] = dense
    return out


def _coach_times(session: Session, coaches: list) -> dict[str, tuple]:
    """Each coach's first and newest telemetry time: two index probes per coach, in one
    statement (one plan for all coaches)."""
    if not coaches:
        return {}
    of_coach = Telemetry.coach_id == Coach.id
    first = select(func.min(Telemetry.time)).where(of_coach).scalar_subquery()
    newest = select(func.max(Telemetry.time)).where(of_coach).scalar_subquery()
    ids = {c.id for c in coaches}
    rows = session.execute(select(Coach.id, first, newest).where(queries.among(Coach.id, ids)))
    return {cid: (t0, t1) for cid, t0, t1 in rows if cid in ids}


def pair_states(session: Session, pairs: list, overrides: list) -> list[tuple]:
    """What each pair's sums and setpoint counts over its range (lo, hi] are computed from, in
    two look-ups of one row per coach: per coach its newest telemetry row up to ``hi`` and its
    late rows (:class:`~.models.CoachFeed`), and its last tick up to ``hi``; and the overrides
    of either coach overlapping the range, as they are (a cancellation changes them).

    Telemetry is only ever inserted: a row arriving in order lands after the coach's newest,
    which moves while it is before ``hi``; one arriving late counts in its late rows. Setpoints
    are inserted at ticks after the coach's last tick, which the same transaction advances.
    So a range whose state is unchanged has the same rows and setpoints (a late row elsewhere
    in the coach's history changes the state too: a recomputation, never a stale answer)."""
    if not pairs:
        return []
    coaches = sorted({c for pair in pairs for c in pair[:2]})
    feeds = {
        cid: (newest, late)
        for cid, newest, late in session.execute(
            select(CoachFeed.coach_id, CoachFeed.newest, CoachFeed.late_rows).where(
                queries.among(CoachFeed.coach_id, coaches)
            )
        )
    }
    ticks = {
        cid: tick
        for cid, tick in session.execute(
            select(Coach.id, Coach.last_tick).where(queries.among(Coach.id, coaches))
        )
    }
    states = []
    for c0, c1, lo, hi in pairs:
        per_coach = []
        for c in (c0, c1):
            newest, late = feeds.get(c, (None, 0))
            tick = ticks.get(c)
            per_coach.append(
                (
                    None if newest is None else min(newest, hi),
                    late,
                    None if tick is None else min(tick, hi),
                )
            )
        mine = tuple(tuple(o) for o in overrides if o[1] in (c0, c1) and o[2] < hi and o[3] > lo)
        states.append((*per_coach, mine))
    return states


def pair_data(
    session: Session,
    pairs: list,
    window_min: float,
    cache: ReadCache | None = None,
    overrides: list | None = None,
    states: list | None = None,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each pair's :func:`pair_grids` and :func:`pair_counts` over its range, those whose state
    (:func:`pair_states`, or ``states`` if given) is unchanged since they were computed taken
    from ``cache``, the others computed together (and kept).

    Returns
    -------
    dict
        Coach 0's id → (window sums (W, len(SUMS)), both coaches' setpoint counts
        (W, 2, len(COUNTS))).
    """
    if overrides is None:
        overrides = overrides_over(session, pairs)
    keys = [("pair-data", *pair, window_min) for pair in pairs]
    if states is None:
        states = pair_states(session, pairs, overrides) if cache else [None] * len(pairs)
    out, missing = {}, []
    for pair, key, state in zip(pairs, keys, states, strict=True):
        kept = cache.lookup(key, state) if cache is not None else None
        if kept is None:
            missing.append((pair, key, state))
        else:
            out[pair[0]] = kept
    if not missing:
        return out
    todo = [m[0] for m in missing]
    grids = pair_grids(session, todo, window_min, overrides)
    counts = pair_counts(session, todo, window_min)
    for pair, key, state in missing:
        out[pair[0]] = (grids[pair[0]], counts[pair[0]])
        if cache is not None:
            cache.put(key, state, out[pair[0]])
    return out


#: Pairs analysed together (bounds the arrays: 128 pairs × 30 days ≈ 45 MB).
_CHUNK = 128


def pair_results(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    switch_hours: list[int],
    window_min: float,
    cache: ReadCache | None = None,
) -> dict[str, dict]:
    """Each pair's :func:`.pair_trial.pair_result` over its range (lo, hi] with its train's
    switch hour, those whose state (:func:`pair_states`) is unchanged since they were computed
    taken from ``cache`` (a dashboard's refresh recomputes nothing), the others from their
    :func:`pair_data`. Coach 0's id → result (shared with the cache: not to be changed)."""
    overrides = overrides_over(session, pairs)
    states = pair_states(session, pairs, overrides) if cache else [None] * len(pairs)
    out, missing = {}, []
    for pair, hour, state in zip(pairs, switch_hours, states, strict=True):
        key = ("pair-result", *pair, window_min, hour)
        kept = cache.lookup(key, state) if cache is not None else None
        if kept is None:
            missing.append((pair, hour, state, key))
        else:
            out[pair[0]] = kept
    todo = [m[0] for m in missing]
    # the figures are kept, not the sums they came from: one answer per train and range
    data = pair_data(session, todo, window_min, None, overrides)
    by_range: dict[tuple, list] = {}
    for m in missing:
        by_range.setdefault(m[0][2:], []).append(m)
    chunks = [
        (lo_hi, group[i : i + _CHUNK])
        for lo_hi, group in by_range.items()
        for i in range(0, len(group), _CHUNK)
    ]
    for (lo, hi), group in chunks:
        w_lo, n = _range_windows(lo, hi, window_min)
        found = pair_trial.pair_results(
            np.arange(w_lo, w_lo + n),
            np.stack([data[pair[0]][0] for pair, *_ in group]).reshape(len(group), n, len(SUMS)),
            np.stack([data[pair[0]][1] for pair, *_ in group]).reshape(
                len(group), n, 2, len(COUNTS)
            ),
            window_min,
            [hour for _, hour, _, _ in group],
        )
        for (pair, _, state, key), result in zip(group, found, strict=True):
            out[pair[0]] = result
            if cache is not None:
                cache.put(key, state, result)
    return out


def summary(
    session: Session,
    views: list[dict],
    hours: float,
    end: datetime | None = None,
    window_min: float = 30.0,
    cache: ReadCache | None = None,
) -> dict:
    """The fleet at a glance: savings and comfort of every train over the ``hours`` up to
    ``end`` (default: each train's fleet clock — the demo's simulated time, the live fleet's
    newest telemetry) and the fleet's, pooled; the coaches by status and those that need
    attention now, from their ``views`` (as the fleet list shows them,
    :func:`.queries.coach_view`). Trains without a pair of coaches are left out. Each train's
    figures are its pair comparison's (:func:`pair_result`); the fleet's savings pool the
    trains' estimates that have an interval (:func:`trial.pool`), and its naive figure the
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
    times = _coach_times(session, [c for _, pair in paired for c in pair])
    clocks = {c.name: c.time for c in session.scalars(select(FleetClock))}
    ranges, pairs = [], []
    for t, (c0, c1) in paired:
        stop = end or clocks.get(c0.fleet) or times[c0.id][1]
        if stop is None:
            continue  # no data and no clock: nothing to count
        firsts = [times[c.id][0] for c in (c0, c1)]
        earliest = min((f for f in firsts if f is not None), default=None)
        start = stop - timedelta(hours=hours)
        first, n = queries.counted_range(start, stop, earliest, window_min)
        ranges.append((t, c0, c1, first, n, stop))
        hi = first + pd.Timedelta(minutes=window_min * n)
        pairs.append((c0.id, c1.id, first.to_pydatetime(), hi.to_pydatetime()))
    by_stop: dict[datetime, list[str]] = {}
    for t, _, _, _, _, stop in ranges:
        by_stop.setdefault(stop, []).append(t.id)
    in_force = {}
    for stop, ids in by_stop.items():
        in_force |= {tid: rows[0] for tid, rows in plans.plans_at(session, ids, stop).items()}
    terms = [plans.terms(in_force.get(t.id)) for t, *_ in ranges]
    found = pair_results(session, pairs, [h for _, h, _ in terms], window_min, cache)
    results = [
        (t, c0, c1, first, stop, {**found[c0.id], "plan": plan})
        for (t, c0, c1, first, _, stop), (plan, _, _) in zip(ranges, terms, strict=True)
    ]
    # the fleet's headline is the HVAC units' meter when every train has it
    fleet_meters = [m for m in METERS if all(m in r[-1]["totals"] for r in results)]
    fleet_meter = HEADLINE_METER if HEADLINE_METER in fleet_meters else "hvac_and_floor"
    fleet = {m: PairTotals.empty(window_min) for m in fleet_meters}
    out_trains, counted_w, counted_e = [], [], []
    for t, c0, c1, first, stop, r in results:
        fleet = {m: fleet[m] + r["totals"][m] for m in fleet}
        e0, e1 = r["grid"][:, list(energy_columns(fleet_meter))].T
        one = r["label"] == 1
        counted_w.append(r["index"][r["counted"]])
        counted_e.append(np.stack([np.where(one, e1, e0), np.where(one, e0, e1)])[:, r["counted"]])
        out_trains.append(
            {
                "id": t.id,
                "name": t.name,
                "plan": r["plan"],
                "coaches": [c0.id, c1.id],
                "activated": next((c.id for c in (c0, c1) if c.ddpc_active), None),
                "deactivated": next((c.id for c in (c0, c1) if not c.ddpc_active), None),
                "start": first.to_pydatetime(),
                "end": stop,
                **r["figures"],
            }
        )
    # the counted windows' energies, pooled per window over the trains that count it
    all_w = np.concatenate(counted_w) if counted_w else np.zeros(0, np.int64)
    all_e = np.concatenate(counted_e, axis=1) if counted_e else np.zeros((2, 0))
    starts, which, n_trains = np.unique(all_w, return_inverse=True, return_counts=True)
    pooled_e = np.stack([np.bincount(which, e, minlength=len(starts)) for e in all_e])
    totals = fleet[fleet_meter]
    pooled = trial.pool([r[-1]["estimate"] for r in results])
    naive = totals.savings_pct
    clocks_now = {v["id"]: v["clock"] for v in views if v["clock"] is not None}
    return {
        "hours": hours,
        "window_min": window_min,
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
        "counted_windows": sum(int(r[-1]["counted"].sum()) for r in results),
        "counted_hours": totals.counted_hours,
        "trains": out_trains,
        "windows": [
            {
                "start": pd.Timestamp(int(w) * window_min * 60, unit="s", tz="UTC").to_pydatetime(),
                "energy_activated_kwh": float(e_act),
                "energy_deactivated_kwh": float(e_deact),
                "trains": int(n),
            }
            for w, e_act, e_deact, n in zip(starts, *pooled_e, n_trains, strict=True)
        ],
        "coaches_by_status": coaches_by_status(views),
        "attention": attention(
            views, comfort_violations(session, clocks_now), handed_back(session)
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


def comfort_violations(session: Session, ends: dict[str, datetime]) -> dict[str, float]:
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
    found = session.execute(
        select(CoachFeed.coach_id, CoachFeed.newest, CoachFeed.last_ok).where(
            queries.among(CoachFeed.coach_id, ends)
        )
    )
    out = {}
    for cid, newest, last_ok in found:
        if cid not in ends:
            continue
        lo = ends[cid] - lookback
        if newest <= lo:
            continue  # no row in the lookback
        since = last_ok if last_ok is not None and last_ok > lo else lo
        if since != newest:
            out[cid] = (newest - since).total_seconds() / 60.0
    return out
