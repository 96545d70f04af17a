"""The fleet at a glance: every train's activated-vs-deactivated savings and comfort over the last
hours, pooled into the fleet's, the coaches by status, and the coaches that need attention.

A train's numbers are those of its pair comparison (:func:`.queries.comparison`, i.e.
:func:`trainclimate.analysis.savings.compare` on the stored 1-minute telemetry) over the same
range: the same 30-minute windows (aligned to the clock, the first one after the pair's data or
the range starts), the same windows excluded (a minute missing for either coach, a coach not
connected, without its power or overridden), violation and discomfort over the same minutes (both
coaches in regular mode, nothing affected). Here they are summed in the database, per train and
window, in one statement over every train — the 24-h fleet view reads a few sums per window
instead of 2 880 rows per train — and combined by the same
:class:`~trainclimate.analysis.savings.PairTotals`; the fleet's figures pool its trains' (energy
over energy, discomfort over hours counted). Each train's sums are kept in the read cache while
its rows in the counted range and its overrides are unchanged (:func:`_pair_states`).
"""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pandas as pd
from sqlalchemy import (
    Integer,
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
from sqlalchemy.ext.compiler import compiles
from sqlalchemy.orm import Session, selectinload
from sqlalchemy.sql.expression import ColumnElement, FunctionElement

from trainclimate.analysis.savings import PairTotals
from trainclimate.service.store import queries
from trainclimate.service.store.attention import (
    VIOLATION_LOOKBACK_MIN,
    attention,
    coaches_by_status,
)
from trainclimate.service.store.cache import ReadCache
from trainclimate.service.store.models import (
    Coach,
    FleetClock,
    Override,
    Telemetry,
    Train,
    UTCDateTime,
)
from trainclimate.sim.power import HEADLINE_METER, METERS

DECKS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
ID, TIME = Telemetry.coach_id.type, UTCDateTime()


class EpochSeconds(FunctionElement):
    """A timestamp column as whole seconds since 1970-01-01 UTC (an integer, so that dividing it
    by an integer floors on either database)."""

    type = Integer()
    inherit_cache = True


@compiles(EpochSeconds)  # PostgreSQL, and any other SQL standard database
def _epoch_pg(element, compiler, **kw):
    # date_part gives a double precision (EXTRACT a numeric: slower to compute)
    return f"CAST(FLOOR(date_part('epoch', {compiler.process(element.clauses, **kw)})) AS BIGINT)"


@compiles(EpochSeconds, "sqlite")
def _epoch_sqlite(element, compiler, **kw):
    return f"CAST(strftime('%s', {compiler.process(element.clauses, **kw)}) AS INTEGER)"


class OnMinute(FunctionElement):
    """Whether a timestamp column falls on a whole minute (the comparison's 1-minute grid)."""

    inherit_cache = True


@compiles(OnMinute)  # PostgreSQL, and any other SQL standard database
def _on_minute_pg(element, compiler, **kw):
    col = compiler.process(element.clauses, **kw)
    return f"(date_trunc('minute', {col}) = {col})"


@compiles(OnMinute, "sqlite")
def _on_minute_sqlite(element, compiler, **kw):
    return f"(strftime('%f', {compiler.process(element.clauses, **kw)}) = '00.000')"


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
    return session.execute(
        select(
            Override.id,
            Override.coach_id,
            Override.starts_at,
            Override.ends_at,
            Override.cancelled_at,
        )
        .where(Override.coach_id.in_({c for pair in pairs for c in pair[:2]}))
        .where(
            Override.starts_at < max(x[3] for x in pairs),
            Override.ends_at > min(x[2] for x in pairs),
        )
        .order_by(Override.id)
    ).all()


def window_sums(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    window_min: float = 30.0,
    t_max_k: float = queries.COMFORT_BAND_K,
    overrides: list | None = None,
) -> dict[str, dict[int, np.ndarray]]:
    """Per pair and window, the sums a pair comparison is made of, read in one statement.

    Parameters
    ----------
    pairs : list of (activated id, deactivated id, lo, hi)
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
        Activated coach id → window index (the window's start in window lengths since 1970) →
        an array of :data:`SUMS`: the minutes both coaches have a row on the minute grid, those
        affected (either coach not connected, without power, or overridden), the energy of
        each coach [kWh], the minutes counted for comfort (nothing affected, both in regular
        mode), the discomfort per deck of the activated and the deactivated coach over
        those [K·h], each coach's energy on the HVAC units' meter (without the floor and wall
        heating) [kWh] and the minutes where a coach's row does not split the floor heating off.
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


#: What :func:`window_sums` returns per window, in order.
SUMS = (
    "minutes",
    "affected_minutes",
    "energy_activated_kwh",
    "energy_deactivated_kwh",
    "counted_minutes",
    *(f"discomfort_{d}_kh" for d in ("up", "mid", "low")),
    *(f"baseline_discomfort_{d}_kh" for d in ("up", "mid", "low")),
    "energy_activated_hvac_kwh",
    "energy_deactivated_hvac_kwh",
    "unsplit_minutes",
)


def pair_windows(
    sums: dict[int, np.ndarray], first: pd.Timestamp, n_windows: int, window_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A pair's ``n_windows`` windows from ``first``, from its :func:`window_sums`: a window is
    included when both coaches have every minute of it and none is affected.

    Parameters
    ----------
    sums : dict
        Window index → sums (:data:`SUMS`), as :func:`window_sums` gives them for the pair.
    first : pandas.Timestamp
        The first window's start.
    n_windows : int
        How many windows are counted.
    window_min : float
        Window length. [min]

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        The windows' indices (n,) (starts in window lengths since 1970), their sums
        (n, len(SUMS)) — zeros where the pair has no row — and whether each is included (n,).
    """
    w0 = int(first.timestamp() // (window_min * 60))
    index = np.arange(w0, w0 + n_windows)
    grid = np.array([sums.get(w, np.zeros(len(SUMS))) for w in index]).reshape(-1, len(SUMS))
    minutes, affected = grid[:, 0], grid[:, 1]
    return index, grid, (minutes == round(window_min)) & (affected == 0)


def pair_totals(
    grid: np.ndarray, included: np.ndarray, window_min: float, meter: str = "hvac_and_floor"
) -> PairTotals:
    """A pair's totals on ``meter`` from its :func:`pair_windows`' sums and included windows."""
    e_act, e_deact = grid[:, _energy_columns(meter)].T
    counted = grid[:, 4]
    return PairTotals(
        energy_activated_kwh=float(e_act[included].sum()),
        energy_deactivated_kwh=float(e_deact[included].sum()),
        windows=len(grid),
        excluded_windows=int(len(grid) - included.sum()),
        window_min=window_min,
        counted_hours=float(counted.sum() / 60.0),
        discomfort_kh=grid[:, 5:8].sum(axis=0),
        baseline_discomfort_kh=grid[:, 8:11].sum(axis=0),
    )


def split_everywhere(grid: np.ndarray, included: np.ndarray) -> bool:
    """Whether every minute of the included windows splits the floor heating off (the HVAC
    units' meter counts then)."""
    return not np.any(grid[included, SUMS.index("unsplit_minutes")] > 0)


def _energy_columns(meter: str) -> list[int]:
    """The columns of :data:`SUMS` with the activated and the deactivated coach's energy on
    ``meter``."""
    suffix = "_kwh" if meter == "hvac_and_floor" else "_hvac_kwh"
    return [SUMS.index(f"energy_{coach}{suffix}") for coach in ("activated", "deactivated")]


def _totals_dict(by_meter: dict[str, PairTotals], meter: str) -> dict:
    """The figures of ``meter``'s totals, and the savings on every meter (None for one that
    does not count)."""
    t = by_meter[meter]
    return {
        "meter": meter,
        "savings_by_meter_pct": {
            m: by_meter[m].savings_pct if m in by_meter else None for m in METERS
        },
        "savings_pct": t.savings_pct,
        "energy_activated_kwh": t.energy_activated_kwh,
        "energy_deactivated_kwh": t.energy_deactivated_kwh,
        "avg_hourly_violation_activated_k": t.avg_hourly_violation_k,
        "avg_hourly_violation_deactivated_k": t.baseline_violation_k,
        "excluded_minutes": t.excluded_minutes,
        "counted_hours": t.counted_hours,
    }


def _coach_times(session: Session, coaches: list[Coach]) -> dict[str, tuple]:
    """Each coach's first and newest telemetry time: two index probes per coach, in one
    statement (one plan for all coaches)."""
    if not coaches:
        return {}
    of_coach = Telemetry.coach_id == Coach.id
    first = select(func.min(Telemetry.time)).where(of_coach).scalar_subquery()
    newest = select(func.max(Telemetry.time)).where(of_coach).scalar_subquery()
    rows = session.execute(
        select(Coach.id, first, newest).where(Coach.id.in_([c.id for c in coaches]))
    )
    return {cid: (t0, t1) for cid, t0, t1 in rows}


def _pair_states(session: Session, pairs: list, overrides: list) -> list[tuple]:
    """What each pair's :func:`window_sums` over its range (lo, hi] are computed from: each
    coach's number of rows in the range (telemetry is only ever inserted: a new row in the range
    changes its count; rows after it, the current window's, do not) and the overrides of either
    coach overlapping it, as they are (a cancellation changes them). One statement of index-only
    counts."""
    if not pairs:
        return []
    p = _literal_table("pairs", {"act": ID, "deact": ID, "lo": TIME, "hi": TIME}, pairs)

    def rows_of(coach):
        return (
            select(func.count())
            .select_from(Telemetry)
            .where(Telemetry.coach_id == coach, Telemetry.time > p.c.lo, Telemetry.time <= p.c.hi)
            .scalar_subquery()
        )

    counts = dict(
        ((a, d), (n_a, n_d))
        for a, d, n_a, n_d in session.execute(
            select(p.c.act, p.c.deact, rows_of(p.c.act), rows_of(p.c.deact))
        )
    )
    states = []
    for act, deact, lo, hi in pairs:
        mine = tuple(
            tuple(o) for o in overrides if o[1] in (act, deact) and o[2] < hi and o[3] > lo
        )
        states.append((*counts[act, deact], mine))
    return states


def _cached_window_sums(
    session: Session, pairs: list, window_min: float, cache: ReadCache | None
) -> dict[str, dict[int, np.ndarray]]:
    """:func:`window_sums` of ``pairs``, those whose state (:func:`_pair_states`) is unchanged
    since they were computed taken from ``cache``, the others computed together and kept."""
    overrides = overrides_over(session, pairs)
    if cache is None:
        return window_sums(session, pairs, window_min, overrides=overrides)
    keys = [("fleet-summary", *pair, window_min) for pair in pairs]
    states = _pair_states(session, pairs, overrides)
    sums, missing = {}, []
    for pair, key, state in zip(pairs, keys, states, strict=True):
        kept = cache.lookup(key, state)
        if kept is None:
            missing.append((pair, key, state))
        else:
            sums[pair[0]] = kept
    computed = window_sums(session, [m[0] for m in missing], window_min, overrides=overrides)
    for pair, key, state in missing:
        sums[pair[0]] = computed.get(pair[0], {})
        cache.put(key, state, sums[pair[0]])
    return sums


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
    :func:`.queries.coach_view`). Trains without both an activated and a deactivated coach are
    left out. With ``cache``, each pair's window sums are kept there while its rows in the range
    and its overrides are unchanged: the range ends at the last whole window, so rows arriving
    in the current one leave it unchanged, and the dashboard's refreshes read a few index-only
    counts instead of every row.

    Returns
    -------
    dict
        ``hours``, ``window_min``, the fleet's ``meter`` (the HVAC units' when every train
        splits the floor heating off, else the whole coach's), ``savings_pct`` [%] on it and
        ``savings_by_meter_pct``, ``energy_activated_kwh`` and
        ``energy_deactivated_kwh`` [kWh], ``avg_hourly_violation_activated_k`` and
        ``avg_hourly_violation_deactivated_k`` [K], ``excluded_minutes`` [min],
        ``counted_hours`` [h]; ``trains``: per train ``id``, ``name``, ``activated``,
        ``deactivated``, ``start``, ``end`` and the same figures; ``windows``: per window
        (oldest first) its ``start``, the energies of the trains that count it
        (``energy_activated_kwh``, ``energy_deactivated_kwh``, kWh: they add up to the fleet's)
        and how many ``trains`` do; ``coaches_by_status`` (:func:`coaches_by_status`) and
        ``attention`` (:func:`attention`).
    """
    trains = session.scalars(select(Train).options(selectinload(Train.coaches)).order_by(Train.id))
    paired = []
    for t in trains:
        on = [c for c in t.coaches if c.ddpc_active]
        off = [c for c in t.coaches if not c.ddpc_active]
        if on and off:
            paired.append((t, on[0], off[0]))
    times = _coach_times(session, [c for _, act, deact in paired for c in (act, deact)])
    clocks = {c.name: c.time for c in session.scalars(select(FleetClock))}
    ranges, pairs = [], []
    for t, act, deact in paired:
        stop = end or clocks.get(act.fleet) or times[act.id][1]
        if stop is None:
            continue  # no data and no clock: nothing to count
        firsts = [times[c.id][0] for c in (act, deact)]
        earliest = min((f for f in firsts if f is not None), default=None)
        start = stop - timedelta(hours=hours)
        first, n = queries.counted_range(start, stop, earliest, window_min)
        ranges.append((t, act, deact, first, n, stop))
        hi = first + pd.Timedelta(minutes=window_min * n)
        pairs.append((act.id, deact.id, first.to_pydatetime(), hi.to_pydatetime()))
    sums = _cached_window_sums(session, pairs, window_min, cache)
    per_train = []
    for t, act, deact, first, n, stop in ranges:
        index, grid, included = pair_windows(sums.get(act.id, {}), first, n, window_min)
        meters = METERS if split_everywhere(grid, included) else ("hvac_and_floor",)
        totals = {m: pair_totals(grid, included, window_min, m) for m in meters}
        per_train.append((t, act, deact, first, stop, index, grid, included, totals))
    # the fleet's headline is the HVAC units' meter when every train has it
    fleet_meters = [m for m in METERS if all(m in x[-1] for x in per_train)]
    fleet_meter = HEADLINE_METER if HEADLINE_METER in fleet_meters else "hvac_and_floor"
    energy = _energy_columns(fleet_meter)
    fleet = {m: PairTotals.empty(window_min) for m in fleet_meters}
    out_trains, windows = [], {}
    for t, act, deact, first, stop, index, grid, included, totals in per_train:
        fleet = {m: fleet[m] + totals[m] for m in fleet}
        for w, e_act, e_deact in zip(index[included], *grid[included][:, energy].T, strict=True):
            pooled = windows.setdefault(int(w), [0.0, 0.0, 0])
            pooled[0], pooled[1], pooled[2] = pooled[0] + e_act, pooled[1] + e_deact, pooled[2] + 1
        out_trains.append(
            {
                "id": t.id,
                "name": t.name,
                "activated": act.id,
                "deactivated": deact.id,
                "start": first.to_pydatetime(),
                "end": stop,
                **_totals_dict(
                    totals, HEADLINE_METER if HEADLINE_METER in totals else "hvac_and_floor"
                ),
            }
        )
    clocks_now = {v["id"]: v["clock"] for v in views if v["clock"] is not None}
    return {
        "hours": hours,
        "window_min": window_min,
        **_totals_dict(fleet, fleet_meter),
        "trains": out_trains,
        "windows": [
            {
                "start": pd.Timestamp(w * window_min * 60, unit="s", tz="UTC").to_pydatetime(),
                "energy_activated_kwh": e_act,
                "energy_deactivated_kwh": e_deact,
                "trains": n,
            }
            for w, (e_act, e_deact, n) in sorted(windows.items())
        ],
        "coaches_by_status": coaches_by_status(views),
        "attention": attention(views, comfort_violations(session, clocks_now)),
    }


def comfort_violations(
    session: Session, ends: dict[str, datetime], t_max_k: float = queries.COMFORT_BAND_K
) -> dict[str, float]:
    """How long each coach's decks have been outside the comfort band without a break, up to
    its newest row, over the :data:`.attention.VIOLATION_LOOKBACK_MIN` before ``ends[coach]``.

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
    c = _literal_table(
        "lookback", {"id": ID, "lo": TIME}, [(cid, t - lookback) for cid, t in ends.items()]
    )
    row = Telemetry.__table__.alias("r")
    outside = or_(*(v > 0 for v in _violation(row, t_max_k)))
    ok = or_(row.c.mode != "regular", not_(outside))
    found = session.execute(
        select(row.c.coach_id, func.max(row.c.time), func.max(case((ok, row.c.time))), c.c.lo)
        .select_from(c)
        .join(row, and_(row.c.coach_id == c.c.id, row.c.time > c.c.lo))
        .group_by(row.c.coach_id, c.c.lo)
    ).all()
    out = {}
    for cid, newest, last_ok, lo in found:
        if last_ok != newest:
            out[cid] = ((newest - (last_ok or lo)).total_seconds()) / 60.0
    return out
