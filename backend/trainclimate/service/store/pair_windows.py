"""Each pair's 30-minute windows as the pair comparison, the fleet summary and the guard read
them: per window the telemetry's sums (:data:`~.pair_labels.SUMS`) from the window rollups
(:mod:`.rollups`; the raw minutes, summed in the database in one statement over every pair, only
for the windows the rollups cannot give exactly) and both coaches' setpoint counts
(:data:`~.pair_labels.COUNTS`) from the setpoint rollups (:mod:`.setpoint_rollups`), as arrays over
each pair's range; and what they are computed from (:func:`pair_states`), for the read cache.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np
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

from trainclimate.coach.setpoint import COMFORT_BAND_K
from trainclimate.service.store import pair_labels, queries, rollups, setpoint_rollups
from trainclimate.service.store.cache import ReadCache
from trainclimate.service.store.models import (
    Coach,
    CoachFeed,
    Override,
    Telemetry,
    UTCDateTime,
)
from trainclimate.service.store.pair_labels import COUNTS, SUMS
from trainclimate.service.store.sqltime import EpochSeconds, OnMinute

DECKS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
ID, TIME = Telemetry.coach_id.type, UTCDateTime()


def _violation(row, t_max_k: float) -> list[ColumnElement]:
    """Per deck, max(0, |T_room − T_rule| − T_max) of telemetry row ``row`` (paper, Eq. (4)). [K]"""
    out: list[ColumnElement] = []
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
    postgresql = session.get_bind().dialect.name == "postgresql"
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


def range_windows(lo: datetime, hi: datetime, window_min: float) -> tuple[int, int]:
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
        n = {p[0]: range_windows(p[2], p[3], window_min)[1] for p in pairs}
        grids = {c0: np.zeros((k, len(SUMS))) for c0, k in n.items()}
        raw = pairs
    else:
        grids, raw = rollups.pair_grids(session, pairs, overrides)
    los = {p[0]: range_windows(p[2], p[3], window_min)[0] for p in pairs}
    for c0, by_window in window_sums(session, raw, window_min, overrides=overrides).items():
        _grid(by_window, los[c0], len(grids[c0]), grids[c0])
    return grids


def pair_counts(
    session: Session, pairs: list[tuple[str, str, datetime, datetime]], window_min: float
) -> dict[str, np.ndarray]:
    """Both coaches' setpoint counts (:func:`.pair_labels.setpoint_counts`) of each pair per
    window of its range, (W, 2, len(COUNTS)): from the setpoint rollups
    (:mod:`.setpoint_rollups`) for their 30-minute windows, else counted over the setpoints."""
    if not pairs:
        return {}
    coaches = sorted({c for pair in pairs for c in pair[:2]})
    ranges = [range_windows(lo, hi, window_min) for _, _, lo, hi in pairs]
    if window_min != setpoint_rollups.WINDOW_MIN:
        counts = pair_labels.setpoint_counts(
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


def coach_marks(session: Session, pairs: list) -> dict[str, tuple]:
    """What :func:`pair_states` reads of each coach of ``pairs`` (coach 0, coach 1, …), in two
    look-ups of one row per coach: coach id → (its newest telemetry time and its late rows, as
    its feed keeps them (:class:`~.models.CoachFeed`), its last tick); a coach not found is left
    out. Read once, it serves every :func:`pair_states` of a request (a fleet summary takes
    them from its one read of every coach, :func:`.fleet_summary.coach_feeds`)."""
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
    return {c: (*feeds.get(c, (None, 0)), ticks.get(c)) for c in coaches if c in ticks}


def pair_states(
    session: Session, pairs: list, overrides: list, marks: dict[str, tuple] | None = None
) -> list[tuple]:
    """What each pair's sums and setpoint counts over its range (lo, hi] are computed from, from
    its coaches' :func:`coach_marks` (``marks``, else read here): per coach its newest telemetry
    row up to ``hi`` and its late rows, and its last tick up to ``hi``; and the overrides of
    either coach overlapping the range, as they are (a cancellation changes them).

    Telemetry is only ever inserted: a row arriving in order lands after the coach's newest,
    which moves while it is before ``hi``; one arriving late counts in its late rows. Setpoints
    are inserted at ticks after the coach's last tick, which the same transaction advances.
    So a range whose state is unchanged has the same rows and setpoints (a late row elsewhere
    in the coach's history changes the state too: a recomputation, never a stale answer)."""
    if not pairs:
        return []
    if marks is None:
        marks = coach_marks(session, pairs)
    by_coach: dict[str, list] = {}  # each pair looks at its coaches' overrides only
    for o in overrides:
        by_coach.setdefault(o[1], []).append(o)
    states = []
    for c0, c1, lo, hi in pairs:
        per_coach = []
        for c in (c0, c1):
            newest, late, tick = marks.get(c, (None, 0, None))
            per_coach.append(
                (
                    None if newest is None else min(newest, hi),
                    late,
                    None if tick is None else min(tick, hi),
                )
            )
        theirs = by_coach.get(c0, []) + (by_coach.get(c1, []) if c1 != c0 else [])
        theirs.sort(key=lambda o: o[0])  # by id, as ``overrides``
        mine = tuple(tuple(o) for o in theirs if o[2] < hi and o[3] > lo)
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
        states = (
            pair_states(session, pairs, overrides) if cache is not None else [None] * len(pairs)
        )
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


def pair_data_extended(
    session: Session,
    pairs: list,
    window_min: float,
    cache: ReadCache | None,
    overrides: list,
    marks: dict[str, tuple] | None = None,
    keep: list[bool] | None = None,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """:func:`pair_data` of ranges read again and again from one start to a later and later end,
    as a range ending now reads its service day so far, a window longer every 30 minutes: each
    pair's windows are kept in ``cache`` from its range's start to the furthest end read, with
    the state at that end (:func:`pair_states`). A range starting there whose kept windows are
    still in that state takes them, and reads only the windows after them (none if they reach
    its end); every other one is read whole. A state unchanged at the kept end means the rows
    and setpoints up to it are unchanged, and each window's sums are its own: kept and new
    windows put end to end are the range's. ``overrides``: :func:`overrides_over` the pairs;
    ``marks``: their coaches' :func:`coach_marks` (else read here); ``keep``: per range whether
    to keep it (default all; a range whose start moves each time would only crowd the cache).
    """
    if cache is None:
        return pair_data(session, pairs, window_min, None, overrides)
    keys = [
        ("pair-data-from", c0, c1, lo, window_min) if k else None
        for (c0, c1, lo, _), k in zip(pairs, keep or [True] * len(pairs), strict=True)
    ]
    kept = [cache.peek(key) if key is not None else None for key in keys]
    held = [(p[0], p[1], p[2], k[1][0]) for p, k in zip(pairs, kept, strict=True) if k]
    if marks is None:
        marks = coach_marks(session, pairs)
    # ``overrides`` cover each range: a kept end past it can miss an override after the range,
    # which changes nothing kept up to the range's end — or the state, and the range is read
    now = iter(pair_states(session, held, overrides, marks))
    out, todo = {}, []
    for pair, key, k in zip(pairs, keys, kept, strict=True):
        c0, _, lo, hi = pair
        prefix = k[1] if k is not None and next(now) == k[0] else None
        if prefix is not None and prefix[0] >= hi:
            n = range_windows(lo, hi, window_min)[1]
            out[c0] = (prefix[1][:n], prefix[2][:n])
        else:
            todo.append((pair, key, prefix))
    if not todo:
        return out
    # the states before the reads: a row arriving meanwhile leaves an older state kept (a
    # recomputation next time), never newer data's state with older data
    states = pair_states(session, [t[0] for t in todo], overrides, marks)
    rest = [(c0, c1, p[0] if p else lo, hi) for (c0, c1, lo, hi), _, p in todo]
    read = pair_data(session, rest, window_min, None, overrides)
    for (pair, key, prefix), state in zip(todo, states, strict=True):
        grid, counts = read[pair[0]]
        if prefix is not None:
            grid, counts = np.concatenate([prefix[1], grid]), np.concatenate([prefix[2], counts])
        out[pair[0]] = (grid, counts)
        if key is not None:
            cache.put(key, state, (pair[3], grid, counts))
    return out
