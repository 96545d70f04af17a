"""Pair days: each pair's figures over each whole service day, kept once the day is over, so that
a fleet summary over a new range of days reads one row per pair and day instead of every window.

A pair day (:class:`~.models.PairDay`) holds what the day's windows add up to
(:data:`~.pair_trial.FIELDS`: energies, discomfort, windows counted and excluded by reason, the
trial estimate's daily sums), the counted windows' energies (the fleet's chart), and the
windows themselves (each one's sums, label and own reason to be excluded), computed from the
rollups exactly as the pair comparison computes them (:func:`.pair_trial.pair_results`). Only the
lead-in after a change of the activated coach reaches across windows: a day's figures depend on
the last labelled window before it and on a change just before it, the *state* it was entered
in (:func:`.pair_labels.lead_state`). Each pair day records the state it was computed from and
the state it leaves; a range reads a day from its row only when it enters the day in the state
the day was computed from (:mod:`.pair_days_read`).

A pair day is made once both coaches' newest telemetry and last tick are past the day's end
(:func:`build`: the scheduler keeps them, a few a minute; ``trainclimate bench`` builds them
for data loaded around the service). What can still change a past day drops its pair days
(:func:`forget`): a row arriving late for it, an override over it, raw minutes dropped by
retention (:func:`forget_all`). Every pair day written or dropped drops its day's fleet chart
(:mod:`.fleet_days`), which is made again from the pair days then stored.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import datetime
from typing import cast

import numpy as np
import pandas as pd
from psycopg import sql as psql
from sqlalchemy import Table, and_, delete, func, or_, select
from sqlalchemy.orm import Session

from trainclimate.analysis import trial_plan
from trainclimate.analysis.arrays import pieces
from trainclimate.service.store import (
    binary_rows,
    pair_labels,
    pair_trial,
    pair_windows,
    plans,
    queries,
    rollups,
)
from trainclimate.service.store.models import Coach, CoachFeed, FleetDay, PairDay, Telemetry
from trainclimate.service.store.pair_labels import NO_STATE, SUMS
from trainclimate.service.store.pair_trial import CHART_FIELDS
from trainclimate.service.store.upsert import insert_new

#: The pair days' window. [min]
WINDOW_MIN = rollups.WINDOW_MIN
#: The same in seconds. [s]
WINDOW_S = WINDOW_MIN * 60
#: The windows a change of the activated coach marks as lead-in: states whose last change is
#: this many windows back or more are the same.
_LEAD = int(np.ceil(pair_labels.LEAD_IN_MIN / WINDOW_MIN))
#: Days of a pair built together (bounds the arrays).
_CHUNK_DAYS = 31


class PairDaysChangedError(RuntimeError):
    """A pair day or fleet day read by a summary changed before the summary had read all it
    needed of it (a concurrent rebuild): the trains' figures are read again."""


def table() -> Table:
    return cast(Table, PairDay.__table__)


def digest(c0: str, c1: str, hour: int, day: int, chart: bytes) -> int:
    """A 63-bit hash of a pair day's key and chart (BLAKE2b): a fleet day's members add up to
    its digest (modulo 2⁶³), so that a summary can tell whether it pools the pair days read."""
    key = f"{c0}\x00{c1}\x00{hour}\x00{day}\x00".encode()
    return int.from_bytes(hashlib.blake2b(key + chart, digest_size=8).digest(), "little") >> 1


def stored_state(prev, age) -> tuple[int, int]:
    """A lead-in state as stored: ages of :data:`_LEAD` windows or more are one."""
    return int(prev), int(min(int(age), _LEAD))


@dataclass
class Day:
    """One pair's service day as a range takes it: its ``fields`` (len(FIELDS),), the counted
    windows' indices and chart energies (k,), (k, 4), and the state it leaves."""

    day: int
    fields: np.ndarray
    chart_windows: np.ndarray
    chart: np.ndarray
    exiting: tuple[int, int]


def day_windows(day: int, switch_hour: int) -> tuple[int, int]:
    """The windows [first, end) of service day ``day`` (an ordinal) at ``switch_hour``."""
    start = trial_plan.day_start(pd.Timestamp.fromordinal(day).date(), switch_hour)
    end = trial_plan.day_start(pd.Timestamp.fromordinal(day + 1).date(), switch_hour)
    return round(start.timestamp()) // WINDOW_S, round(end.timestamp()) // WINDOW_S


def days_from_windows(
    day: list[int],
    index: np.ndarray,
    grid: np.ndarray,
    label: np.ndarray,
    code0: np.ndarray,
    entering: tuple[np.ndarray, np.ndarray],
) -> list[Day]:
    """Days (or the parts of them in a range) of several pairs from their windows, as many of
    each: their ``index`` (B, W), sums ``grid`` (B, W, len(SUMS)), labels and own codes
    (:func:`.pair_labels.base_windows`, (B, W)), each taken from its ``entering`` lead-in state
    (labels and ages, (B,))."""
    code = pair_labels.with_lead_in(label, code0, WINDOW_MIN, entering=entering)
    per_window = pair_trial.window_fields(grid, label, code)
    counted = (code == 0) & (label >= 0)
    if not len(day):
        return []
    prev, age = pair_labels.lead_state(label, entering)
    # every day's sums and counted windows at once, then split per day (the 8 550 days of twelve
    # summaries took 180 ms so, against 196 ms with a reduction and two selections per day)
    fields = per_window.sum(axis=1)
    bounds = np.cumsum(counted.sum(axis=1))[:-1]
    chart_windows = pieces(index[counted], bounds)
    chart = pieces(per_window[counted][:, CHART_FIELDS], bounds)
    lead = np.minimum(age, _LEAD).astype(np.int64)  # as stored_state, for the batch
    exiting = zip(prev.astype(np.int64).tolist(), lead.tolist(), strict=True)
    return [
        Day(day=d, fields=f, chart_windows=w, chart=c, exiting=e)
        for d, f, w, c, e in zip(day, fields, chart_windows, chart, exiting, strict=True)
    ]


# --- reading a pair day's windows ---------------------------------------------------------


def _placed(t) -> tuple:
    """A pair day's columns that say whose it is and which windows it holds: coach 0, coach 1,
    switch hour, day, first window, windows."""
    return t.c.coach_0, t.c.coach_1, t.c.switch_hour, t.c.day, t.c.first_window, t.c.windows


def unpack_windows(n: int, packed: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` windows of a pair day as its ``minutes`` hold them: sums (n, len(SUMS)), labels and
    own codes (n,), these two as stored (int8)."""
    size = n * len(SUMS) * 8
    grid = np.frombuffer(packed, np.float64, n * len(SUMS)).reshape(n, len(SUMS))
    label = np.frombuffer(packed, np.int8, n, size)
    code0 = np.frombuffer(packed, np.int8, n, size + n)
    return grid, label, code0


def stored_windows(session: Session, wanted: dict[tuple, tuple[int, int]]) -> dict[tuple, tuple]:
    """The windows of the pair days ``wanted``, (coach 0, coach 1, hour, day) → the windows
    [a, b) asked for: key → (the first of them it holds, their sums, labels and own codes).
    On PostgreSQL each pair day through its key, and only those windows sent: the server cuts
    them out of its ``minutes`` (a range's partial first and last days need about half a day
    each; 900 of them took 40 ms to read whole, measured)."""
    if not wanted:
        return {}
    keys = list(wanted)
    if session.get_bind().dialect.name != "postgresql":
        t = table()
        found = {}
        for r in session.execute(
            select(*_placed(t), t.c.minutes).where(
                t.c.day.in_(sorted({k[3] for k in keys})),
                queries.among(t.c.coach_0, {k[0] for k in keys}),
            )
        ):
            key = (r[0], r[1], r[2], r[3])
            if key not in wanted:
                continue
            a, b = wanted[key]
            first, n = r.first_window, r.windows
            j0 = max(a - first, 0)
            j1 = max(min(b - first, n), j0)
            grid, label, code0 = unpack_windows(n, r.minutes)
            found[key] = (first + j0, grid[j0:j1], label[j0:j1], code0[j0:j1])
        return found
    # p.m: the value read once for the three cuts (OFFSET 0 keeps the subquery, and so its one
    # read, per row; stored uncompressed since migration 0020, an older row decompressed once);
    # the sums of windows [j0, j1), then their labels and own codes
    query = psql.SQL(
        "SELECT k.i - 1, p.f + p.j0, p.j1 - p.j0, "
        "substring(p.m from p.j0 * {row} + 1 for (p.j1 - p.j0) * {row}), "
        "substring(p.m from p.n * {row} + p.j0 + 1 for p.j1 - p.j0) "
        "|| substring(p.m from p.n * {row} + p.n + p.j0 + 1 for p.j1 - p.j0) "
        "FROM unnest({c0}, {c1}, {hour}, {day}, {a}, {b}) WITH ORDINALITY "
        "AS k(c0, c1, h, d, a, b, i) "
        "CROSS JOIN LATERAL (SELECT q.*, greatest(least(k.b - q.f, q.n), q.j0)::int AS j1 FROM "
        "(SELECT first_window AS f, windows::int AS n, greatest(k.a - first_window, 0)::int AS j0, "
        "minutes || ''::bytea AS m FROM pair_days WHERE coach_0 = k.c0 AND coach_1 = k.c1 "
        "AND switch_hour = k.h AND day = k.d OFFSET 0) AS q) AS p"
    ).format(
        row=psql.Literal(len(SUMS) * 8),
        c0=binary_rows.array_of((k[0] for k in keys), "text"),
        c1=binary_rows.array_of((k[1] for k in keys), "text"),
        hour=binary_rows.array_of((int(k[2]) for k in keys), "int4"),
        day=binary_rows.array_of((int(k[3]) for k in keys), "int4"),
        a=binary_rows.array_of((int(wanted[k][0]) for k in keys), "int8"),
        b=binary_rows.array_of((int(wanted[k][1]) for k in keys), "int8"),
    )
    read = binary_rows.rows(session, query)
    if not read:
        return {}
    # every row's windows unpacked at once: the sums one after the other, each row's labels
    # followed by its own codes
    at, first, n, sums, marks = zip(*read, strict=True)
    lengths = np.array(n, np.int64)
    end = np.cumsum(lengths)
    start = end - lengths
    grid = np.frombuffer(b"".join(sums), np.float64).reshape(-1, len(SUMS))
    both = np.frombuffer(b"".join(marks), np.int8)
    # row r's labels start at 2·start[r] of ``both``, its codes n[r] later
    place = np.arange(int(end[-1])) + np.repeat(start, lengths)
    label, code0 = both[place], both[place + np.repeat(lengths, lengths)]
    return {
        keys[i]: (f, grid[a:b], label[a:b], code0[a:b])
        for i, f, a, b in zip(at, first, start.tolist(), end.tolist(), strict=True)
    }


# --- building -----------------------------------------------------------------------------


def _row(c0: str, c1: str, hour: int, d: Day, entering, first: int, grid, label, code0) -> dict:
    """A :class:`~.models.PairDay` row of day ``d`` over windows [first, first + len(grid))."""
    chart = np.column_stack([d.chart_windows - first, d.chart]).astype(np.float64).tobytes()
    return {
        "coach_0": c0,
        "coach_1": c1,
        "switch_hour": hour,
        "day": d.day,
        "first_window": first,
        "windows": len(grid),
        "entering_label": entering[0],
        "entering_age": entering[1],
        "exiting_label": d.exiting[0],
        "exiting_age": d.exiting[1],
        "fields": d.fields.astype(np.float64).tobytes(),
        "chart": chart,
        "chart_digest": digest(c0, c1, hour, d.day, chart),
        "minutes": grid.astype(np.float64).tobytes()
        + label.astype(np.int8).tobytes()
        + code0.astype(np.int8).tobytes(),
    }


def horizons(session: Session, pairs: list[tuple[str, str]]) -> dict[tuple[str, str], datetime]:
    """Up to when each pair's data is complete: the earliest of both coaches' newest telemetry
    and last ticks (pairs where any is unknown are left out)."""
    coaches = sorted({c for p in pairs for c in p})
    newest = dict(
        session.execute(
            select(CoachFeed.coach_id, CoachFeed.newest).where(
                queries.among(CoachFeed.coach_id, coaches)
            )
        ).all()
    )
    ticks = dict(
        session.execute(
            select(Coach.id, Coach.last_tick).where(queries.among(Coach.id, coaches))
        ).all()
    )
    out = {}
    for p in pairs:
        times = [t.get(c) for c in p for t in (newest, ticks)]
        known = [t for t in times if t is not None]
        if len(known) == len(times):
            out[p] = min(known)
    return out


def _first_rows(session: Session, coaches: list[str]) -> dict[str, datetime]:
    """Each coach's first telemetry time (one index probe each)."""
    of_coach = Telemetry.coach_id == Coach.id
    first = select(func.min(Telemetry.time)).where(of_coach).scalar_subquery()
    rows = session.execute(select(Coach.id, first).where(queries.among(Coach.id, coaches)))
    return {cid: t for cid, t in rows if t is not None and cid in coaches}


def build(
    session: Session,
    pairs: list[tuple[str, str, int]],
    max_days: int | None = None,
) -> int:
    """Make the pair days missing for ``pairs`` (coach 0, coach 1, switch hour [h]) from the
    rollups, from each pair's first service day with data up to the last one over for both
    coaches (:func:`horizons`), oldest first, each from the state its day before left — and
    make again those stored that were entered from another state than the one their day before
    now leaves; at most ``max_days`` of them. Concurrent builders insert each day once.
    Returns how many were made.

    A pair whose stored days run without a gap from its first day is taken up after its last
    one (one row read); only a pair with a gap (a day dropped by :func:`forget`) has all its
    days' states read."""
    if not pairs:
        return 0
    ends = horizons(session, [(c0, c1) for c0, c1, _ in pairs])
    firsts = _first_rows(session, sorted({c for p in pairs for c in p[:2]}))
    spans = _spans(session, pairs)
    budget = max_days if max_days is not None else 1 << 62
    made = 0
    for pair in pairs:
        c0, c1, hour = pair
        end, first = ends.get((c0, c1)), [firsts.get(c) for c in (c0, c1)]
        if end is None or first[0] is None or first[1] is None:
            continue
        day = trial_plan.service_day(pd.Timestamp(min(first[0], first[1])), hour).toordinal()
        last = trial_plan.service_day(pd.Timestamp(end), hour).toordinal()
        if day_windows(last, hour)[1] * WINDOW_S > end.timestamp():
            last -= 1  # the day the data reaches into is not over
        state = stored_state(*NO_STATE)
        have: dict[int, tuple] = {}
        span = spans.get(pair)
        if span is not None:
            low, high, n = span
            if low == day and n == high - low + 1:  # no gap: on from the last one
                have = _states(session, pair, high)
                day, state = high, have[high][0]
            else:
                have = _states(session, pair)
        while day <= last and budget > 0:
            kept = have.get(day)
            if kept is not None and kept[0] == state:
                state, day = kept[1], day + 1
                continue
            run = [day]  # this day and the next ones not stored, a chunk at most
            while len(run) < min(_CHUNK_DAYS, budget) and run[-1] < last:
                if run[-1] + 1 in have:
                    break
                run.append(run[-1] + 1)
            state = _build_run(session, pair, run, state, [d for d in run if d in have])
            made += len(run)
            budget -= len(run)
            day = run[-1] + 1
        if budget <= 0:
            break
    return made


def _spans(session: Session, pairs) -> dict[tuple, tuple[int, int, int]]:
    """Each pair's stored days: (first, last, how many)."""
    t = table()
    wanted = set(pairs)
    rows = session.execute(
        select(
            t.c.coach_0,
            t.c.coach_1,
            t.c.switch_hour,
            func.min(t.c.day),
            func.max(t.c.day),
            func.count(),
        )
        .where(queries.among(t.c.coach_0, {p[0] for p in pairs}))
        .group_by(t.c.coach_0, t.c.coach_1, t.c.switch_hour)
    )
    return {(c0, c1, h): (lo, hi, n) for c0, c1, h, lo, hi, n in rows if (c0, c1, h) in wanted}


def _states(session: Session, pair: tuple, day: int | None = None) -> dict[int, tuple]:
    """The stored days of ``pair`` (only ``day`` if given): day → (entering state, exiting
    state)."""
    t = table()
    c0, c1, hour = pair
    query = select(
        t.c.day, t.c.entering_label, t.c.entering_age, t.c.exiting_label, t.c.exiting_age
    ).where(t.c.coach_0 == c0, t.c.coach_1 == c1, t.c.switch_hour == hour)
    if day is not None:
        query = query.where(t.c.day == day)
    return {d: ((el, ea), (xl, xa)) for d, el, ea, xl, xa in session.execute(query)}


def _build_run(
    session: Session, pair: tuple, days: list[int], entering: tuple, replaced: list[int]
) -> tuple[int, int]:
    """Compute and store consecutive ``days`` of ``pair`` from the ``entering`` state, in
    place of its stored days ``replaced``; the state the last one leaves."""
    c0, c1, hour = pair
    lo_w, hi_w = day_windows(days[0], hour)[0], day_windows(days[-1], hour)[1]
    lo, hi = (pd.Timestamp(w * WINDOW_S, unit="s", tz="UTC").to_pydatetime() for w in (lo_w, hi_w))
    grid, counts = pair_windows.pair_data(session, [(c0, c1, lo, hi)], WINDOW_MIN)[c0]
    label, code0 = pair_labels.base_windows(grid, counts, WINDOW_MIN)
    index = np.arange(lo_w, hi_w)
    rows = []
    state = entering
    for day in days:
        a, b = (w - lo_w for w in day_windows(day, hour))
        entering = (np.array([state[0]]), np.array([state[1]]))
        d = days_from_windows(
            [day], index[None, a:b], grid[None, a:b], label[None, a:b], code0[None, a:b], entering
        )[0]
        rows.append(_row(c0, c1, hour, d, state, lo_w + a, grid[a:b], label[a:b], code0[a:b]))
        state = d.exiting
    t = table()
    if replaced:
        session.execute(
            delete(t).where(
                t.c.coach_0 == c0, t.c.coach_1 == c1, t.c.switch_hour == hour, t.c.day.in_(replaced)
            )
        )
    insert_new(session, t, rows, ["coach_0", "coach_1", "switch_hour", "day"])
    _drop_fleet_days(session, {(hour, day) for day in days})
    return state


def _drop_fleet_days(session: Session, days: set[tuple[int, int]]) -> None:
    """Drop the fleet charts of ``days`` (switch hour, day): their pair days changed."""
    by_hour: dict[int, list[int]] = {}
    for hour, day in days:
        by_hour.setdefault(hour, []).append(day)
    for hour, ds in by_hour.items():
        session.execute(
            delete(FleetDay).where(FleetDay.switch_hour == hour, FleetDay.day.in_(sorted(ds)))
        )


def forget(session: Session, coach_windows: dict[str, int]) -> None:
    """Drop the pair days of each coach that end after its window (coach id → the first window
    something changed in): a late row, an override."""
    if not coach_windows:
        return
    t = table()
    ends_after = t.c.first_window + t.c.windows

    def of_coach(coach: str, window: int):
        # a service day starts at most a day before the UTC date of its windows: an index range
        since = pd.Timestamp(window * WINDOW_S, unit="s").toordinal() - 1
        return and_(
            or_(
                and_(t.c.coach_0 == coach, t.c.day >= since),
                and_(t.c.coach_1 == coach, t.c.day >= since),
            ),
            ends_after > window,
        )

    gone = session.execute(
        delete(t)
        .where(or_(*(of_coach(c, w) for c, w in coach_windows.items())))
        .returning(t.c.switch_hour, t.c.day)
    )
    _drop_fleet_days(session, {(hour, day) for hour, day in gone})


def forget_all(session: Session, before_window: int | None = None) -> None:
    """Drop every pair day and fleet day (that starts before ``before_window``, if given)."""
    for t in (table(), cast(Table, FleetDay.__table__)):
        stmt = delete(t)
        if before_window is not None:
            stmt = stmt.where(t.c.first_window < before_window)
        session.execute(stmt)


def fleet_pairs(session: Session, at: datetime) -> list[tuple[str, str, int]]:
    """Every train's pair (:func:`.queries.pick_pair`: coach 0, coach 1) with the switch hour
    of its plan in force at ``at`` [h], by train."""
    by_train: dict[str, list] = {}
    coaches = select(Coach.id, Coach.train_id, Coach.ddpc_active).order_by(Coach.id)
    for c in session.execute(coaches):
        by_train.setdefault(c.train_id, []).append(c)
    pairs = {t: queries.pick_pair(coaches) for t, coaches in sorted(by_train.items())}
    trains = [t for t, pair in pairs.items() if pair is not None]
    in_force = plans.plans_at(session, trains, at)
    out = []
    for t in trains:
        c0, c1 = pairs[t]
        _, hour, _ = plans.terms(in_force.get(t, (None, None))[0])
        out.append((c0.id, c1.id, hour))
    return out
