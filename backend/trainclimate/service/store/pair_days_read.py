"""A range read from the pair days (:mod:`.pair_days`): each pair's figures over (lo, hi] of
30-minute windows, its whole service days from their pair days, the rest from their windows.

A range's days are taken in order from the state of the range's start, and a day is read from
its row only when the state it is entered in is the one it was computed from — else (and for a
range's partial first and last days) from its windows. A range's days without a pair day are
read from the rollups, so a pair day missing costs time, never a figure.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
import pandas as pd
from psycopg import sql as psql
from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate.analysis import trial, trial_plan
from trainclimate.service.store import (
    binary_rows,
    fleet_days,
    pair_days,
    pair_labels,
    pair_trial,
    pair_windows,
    queries,
)
from trainclimate.service.store.cache import ReadCache
from trainclimate.service.store.pair_days import (
    WINDOW_MIN,
    WINDOW_S,
    Day,
    days_from_windows,
    stored_state,
    table,
)
from trainclimate.service.store.pair_labels import NO_STATE
from trainclimate.service.store.pair_trial import CHART_FIELDS, FIELDS


@dataclass(frozen=True)
class _Segment:
    """A pair's service day as its range has it: windows [a, b) of the range, from the day's
    start or not (``opens``), whole or not."""

    day: int
    a: int
    b: int
    opens: bool
    whole: bool


@functools.lru_cache(maxsize=64)
def _segments(lo: datetime, hi: datetime, hour: int) -> tuple[int, tuple[_Segment, ...]]:
    """The first window of the range (lo, hi] and its service days at ``hour``, in order
    (kept: the trains of a summary share their range)."""
    w_lo, n = pair_windows.range_windows(lo, hi, WINDOW_MIN)
    index = np.arange(w_lo - 1, w_lo + n + 1)
    day = trial_plan.service_days(pd.to_datetime(index * WINDOW_S, unit="s", utc=True), hour)
    inner = day[1:-1]
    starts = [*pair_trial.day_starts(inner).tolist(), n]
    out = []
    for a, b in itertools.pairwise(starts):
        d = int(inner[a])
        opens = not (a == 0 and day[0] == d)
        out.append(_Segment(d, a, b, opens, opens and not (b == n and day[-1] == d)))
    return w_lo, tuple(out)


#: A stored pair day's integer columns a range reads: its day, the states it was entered in and
#: leaves, its chart digest.
_INTEGERS = (
    "day",
    "entering_label",
    "entering_age",
    "exiting_label",
    "exiting_age",
    "chart_digest",
)
#: A stored pair day as a range reads it (:func:`_stored`): ``key``, the position of its
#: (coach 0, coach 1, switch hour) among the range's, :data:`_INTEGERS` and its fields
#: (:data:`~.pair_trial.FIELDS`).
_STORED = np.dtype(
    [("key", np.int64)]
    + [(name, np.int64) for name in _INTEGERS]
    + [("fields", np.float64, (len(FIELDS),))]
)


def _stored(
    session: Session,
    pairs: list,
    switch_hours: list[int],
    layout: list,
    fleet: dict | None = None,
    cache: ReadCache | None = None,
) -> tuple:
    """The stored pair days of the pairs' segments (``layout``, :func:`_segments`): their rows
    (:data:`_STORED`) and, per pair, per segment, its row (−1 where none is stored); with
    ``fleet`` (many pairs) read through the fleet days (:func:`_member_rows`, kept in
    ``cache`` and in ``fleet``)."""
    keys = [(c0, c1, h) for (c0, c1, _, _), h in zip(pairs, switch_hours, strict=True)]
    keys = list(dict.fromkeys(keys))
    span = [seg.day for _, segs in layout for seg in segs]
    if not span:
        return np.zeros(0, _STORED), [[] for _ in pairs]
    first, last = min(span), max(span)
    if fleet is not None:
        rows = _member_rows(session, keys, (first, last), cache, fleet)
    else:
        rows = _stored_rows(session, keys, (first, last))
    placed = np.full((len(keys), last - first + 1), -1, np.int64)
    placed[rows["key"], rows["day"] - first] = np.arange(len(rows))
    position = {k: i for i, k in enumerate(keys)}
    # the days' places once per distinct layout: the trains of a summary share theirs
    offsets: dict[int, np.ndarray] = {}
    row_of = []
    for (c0, c1, _, _), hour, (_, segs) in zip(pairs, switch_hours, layout, strict=True):
        at = offsets.get(id(segs))
        if at is None:
            at = offsets[id(segs)] = np.array([seg.day - first for seg in segs], np.int64)
        row_of.append(placed[position[(c0, c1, hour)], at].tolist())
    return rows, row_of


def _stored_rows(session: Session, keys: list[tuple], days: tuple[int, int]) -> np.ndarray:
    """The pair days of ``keys`` (coach 0, coach 1, switch hour) over the days [first, last]
    (:data:`_STORED`, ``key`` the position in ``keys``). On PostgreSQL each key's days through
    an index on its coach and day, packed by the server into one value
    (:func:`.binary_rows.packed_rows`): a new 30-day summary of 450 trains reads 13 500 pair
    days, which took 51 ms a row at a time and 37 ms so (measured through the app)."""
    if session.get_bind().dialect.name == "postgresql":
        columns = [f"p.{name}::int8" for name in _INTEGERS]
        query = psql.SQL(
            "SELECT k.i - 1, {columns}, p.fields "
            "FROM unnest({c0}, {c1}, {hour}) WITH ORDINALITY "
            "AS k(c0, c1, h, i) "
            "CROSS JOIN LATERAL (SELECT * FROM pair_days WHERE coach_0 = k.c0 AND coach_1 = k.c1 "
            "AND switch_hour = k.h AND day >= {first} AND day <= {last} OFFSET 0) AS p"
        ).format(
            columns=psql.SQL(", ").join(psql.SQL(c) for c in columns),
            c0=binary_rows.array_of((k[0] for k in keys), "text"),
            c1=binary_rows.array_of((k[1] for k in keys), "text"),
            hour=binary_rows.array_of((int(k[2]) for k in keys), "int4"),
            first=psql.Literal(int(days[0])),
            last=psql.Literal(int(days[1])),
        )
        rows = binary_rows.packed_rows(session, query, _STORED)
    else:
        position = {k: i for i, k in enumerate(keys)}
        t = table()
        found = [
            r
            for r in session.execute(
                select(
                    t.c.coach_0,
                    t.c.coach_1,
                    t.c.switch_hour,
                    *(t.c[name] for name in _INTEGERS),
                    t.c.fields,
                ).where(
                    t.c.day >= days[0],
                    t.c.day <= days[1],
                    queries.among(t.c.coach_0, {k[0] for k in keys}),
                )
            )
            if (r[0], r[1], r[2]) in position
        ]
        rows = np.zeros(len(found), _STORED)
        rows["key"] = [position[(r[0], r[1], r[2])] for r in found]
        for j, name in enumerate(_INTEGERS, start=3):
            rows[name] = [r[j] for r in found]
        if found:
            rows["fields"] = np.frombuffer(b"".join(r[-1] for r in found), np.float64).reshape(
                len(found), len(FIELDS)
            )
    return rows


def _member_rows(
    session: Session,
    keys: list[tuple],
    days: tuple[int, int],
    cache: ReadCache | None,
    found: dict | None = None,
) -> np.ndarray:
    """:func:`_stored_rows`, each day's rows taken from its fleet day's members where it has one
    (:data:`.fleet_days.MEMBER`: one row per day instead of one per pair and day; the members
    read kept in ``cache`` under the fleet day's version, and in ``found`` for the other
    chunks of the same request), the others (a day without a fleet day, a pair day made after
    its fleet day) from their own rows."""
    hours = sorted({k[2] for k in keys})
    if found is None:
        found = {}
    held = found.get((tuple(hours), days))
    if held is None:
        held = found[(tuple(hours), days)] = _fleet_days(session, hours, days, cache)
    return _placed_members(session, keys, days, held)


def _fleet_days(
    session: Session, hours: list[int], days: tuple[int, int], cache: ReadCache | None
) -> dict[tuple[int, int], tuple]:
    """The fleet days at ``hours`` over the days [first, last]: (hour, day) → (its members'
    places, :func:`_member_index`, and its members' rows), those of an unchanged version from
    ``cache``."""
    f = fleet_days.table()
    in_range = (f.c.day >= days[0], f.c.day <= days[1], f.c.switch_hour.in_(hours))
    versions = session.execute(select(f.c.switch_hour, f.c.day, f.c.version).where(*in_range))
    held: dict[tuple[int, int], tuple] = {}
    missing = set()
    for hour, day, version in versions:
        kept = cache.lookup(("fleet-day", hour, day), version) if cache is not None else None
        if kept is None:
            missing.add((hour, day))
        else:
            held[(hour, day)] = kept
    if missing:
        read = session.execute(
            select(f.c.switch_hour, f.c.day, f.c.version, f.c.members, f.c.member_rows).where(
                *in_range, f.c.day.in_(sorted({day for _, day in missing}))
            )
        )
        for hour, day, version, members, packed in read:
            if (hour, day) in held:
                continue
            held[(hour, day)] = (_member_index(members), np.frombuffer(packed, fleet_days.MEMBER))
            if cache is not None:
                cache.put(("fleet-day", hour, day), version, held[(hour, day)])
    return held


def _placed_members(
    session: Session, keys: list[tuple], days: tuple[int, int], held: dict
) -> np.ndarray:
    """:func:`_member_rows` from the fleet days ``held`` (:func:`_fleet_days`)."""
    by_hour = {h: [k for k, key in enumerate(keys) if key[2] == h] for h, _ in held}
    covered = np.zeros((len(keys), days[1] - days[0] + 1), bool)
    # the keys' places among each day's members, once per distinct list of members
    places: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    at_key, at_day, taken = [], [], []
    for (hour, day), (index, members) in held.items():
        place = places.get((id(index), hour))
        if place is None:
            mine = by_hour[hour]
            at = np.array([index.get(keys[k][:2], -1) for k in mine], np.int64)
            place = places[(id(index), hour)] = (np.array(mine, np.int64)[at >= 0], at[at >= 0])
        at_key.append(place[0])
        at_day.append(np.full(len(place[0]), day, np.int64))
        taken.append(members[place[1]])
    parts = []
    if taken:
        part = np.zeros(sum(map(len, taken)), _STORED)
        part["key"], part["day"] = np.concatenate(at_key), np.concatenate(at_day)
        members = np.concatenate(taken)
        for name in (*fleet_days.MEMBER_INTEGERS, "fields"):
            part[name] = members[name]
        covered[part["key"], part["day"] - days[0]] = True
        parts.append(part)
    k, d = np.nonzero(~covered)
    if len(k):
        others = np.unique(k)
        rows = _stored_rows(
            session,
            [keys[i] for i in others.tolist()],
            (days[0] + int(d.min()), days[0] + int(d.max())),
        )
        rows["key"] = others[rows["key"]]
        parts.append(rows[~covered[rows["key"], rows["day"] - days[0]]])
    return np.concatenate([np.zeros(0, _STORED), *parts])


@functools.lru_cache(maxsize=16)
def _member_index(members: str) -> dict[tuple[str, str], int]:
    """A fleet day's ``members`` (``coach_0 coach_1`` per line) → (coach 0, coach 1) → its place
    (kept: a fleet's days share their members, and the places found in one serve all)."""
    pairs = (line.split(" ") for line in members.split("\n"))
    return {(c0, c1): i for i, (c0, c1) in enumerate(pairs)}


def pair_results(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    switch_hours: list[int],
    overrides: list,
) -> list[dict]:
    """:func:`pair_results_later`, the trial estimates computed here, now."""
    return pair_results_later(session, pairs, switch_hours, overrides, None)()


def pair_results_later(
    session: Session,
    pairs: list[tuple[str, str, datetime, datetime]],
    switch_hours: list[int],
    overrides: list,
    executor: Executor | None,
    cache: ReadCache | None = None,
    marks: dict[str, tuple] | None = None,
    fleet: dict | None = None,
) -> Callable[[], list[dict]]:
    """Each pair's figures over its range (lo, hi] of 30-minute windows as
    :func:`.pair_trial.pair_results` gives them (``meter``, ``totals``, ``estimate``,
    ``reasons``, ``counted_windows``, ``figures``; not the arrays per window), its whole
    service days read from their pair days where they were entered from the state the range
    reaches them in, the others from their windows (stored with the pair day, or from the
    rollups). Its fleet chart as ``chart`` — the counted windows and their energies
    (:data:`~.pair_trial.CHART_FIELDS`) of the days not read from their rows — and
    ``chart_days``, the days read from their pair days' rows and those rows' chart digests
    (two arrays: their charts are pooled by :func:`.fleet_days.charts`). Everything is read
    before this returns; the trial estimates' bootstraps are handed to ``executor``
    (:func:`trainclimate.analysis.trial.estimates_later`: None computes them now), and the
    function returned waits for them and gives the results, in the order of ``pairs``. With
    ``cache``, the windows read from the rollups are kept there from each run's start
    (:func:`.pair_windows.pair_data_extended`): a range ending now reads only the windows of
    its service day that are new since the last range read from the same start (``marks``:
    the coaches' :func:`.pair_windows.coach_marks`, else read there). With ``fleet`` (a summary
    of many trains: a dict, the same for all its calls) the pair days are read through their
    fleet days (:func:`_member_rows`), those read kept in it for the next call."""
    layout = [_segments(lo, hi, h) for (_, _, lo, hi), h in zip(pairs, switch_hours, strict=True)]
    stored, row_of = _stored(session, pairs, switch_hours, layout, fleet, cache)
    windows: dict[tuple[int, int], tuple] = {}  # (pair, segment) → (index, grid, label, code0)
    _windows_from_rollups(session, pairs, layout, row_of, overrides, windows, cache, marks)
    _windows_from_pair_days(session, pairs, switch_hours, layout, windows, row_of, partial=True)
    # per pair its days in order: stored rows (their positions in ``stored``) or Days
    days: list[list] = [[] for _ in pairs]
    state = [stored_state(*NO_STATE) for _ in pairs]
    position = [0] * len(pairs)
    entering_label, entering_age, exiting_label, exiting_age = (
        stored[name].tolist()
        for name in ("entering_label", "entering_age", "exiting_label", "exiting_age")
    )
    while True:
        waiting = []
        for i, segs in enumerate(seg for _, seg in layout):
            label, age = state[i]
            while position[i] < len(segs):
                seg = segs[position[i]]
                r = row_of[i][position[i]] if seg.whole else -1
                if r < 0 or entering_label[r] != label or entering_age[r] != age:
                    break
                days[i].append(r)
                label, age = exiting_label[r], exiting_age[r]
                position[i] += 1
            state[i] = (label, age)
            if position[i] < len(segs):
                waiting.append(i)
        if not waiting:
            break
        missing = [i for i in waiting if (i, position[i]) not in windows]
        if missing:  # whole days entered from another state than they were made from
            _windows_from_pair_days(
                session, pairs, switch_hours, layout, windows, row_of, only=missing, at=position
            )
        _compute(waiting, layout, position, windows, state, days)
    return _assemble(days, stored, executor)


def _windows_from_rollups(session, pairs, layout, row_of, overrides, windows, cache, marks) -> None:
    """The windows of every segment without a pair day (``row_of``, :func:`_stored`), from the
    rollups (those from a day's
    start through ``cache``, :func:`.pair_windows.pair_data_extended`): each pair's consecutive
    such segments read as one range, the pairs' first ranges together, then their second
    ones, …"""
    runs: list[list[tuple[int, int, int]]] = []  # per pair: (first segment, last segment + 1)
    for i, rows in enumerate(row_of):
        mine: list[tuple[int, int, int]] = []
        for k, row in enumerate(rows):
            if row >= 0:
                continue
            if mine and mine[-1][1] == k:
                mine[-1] = (mine[-1][0], k + 1, i)
            else:
                mine.append((k, k + 1, i))
        runs.append(mine)
    for r in range(max((len(x) for x in runs), default=0)):
        batch = [x[r] for x in runs if len(x) > r]
        ranges = []
        for k0, k1, i in batch:
            w_lo, segs = layout[i]
            a, b = segs[k0].a + w_lo, segs[k1 - 1].b + w_lo
            ranges.append((pairs[i][0], pairs[i][1], _window_time(a), _window_time(b)))
        # kept from a day's start only: a range starting within a day starts elsewhere next time
        keep = [layout[i][1][k0].opens for k0, _, i in batch]
        data = pair_windows.pair_data_extended(
            session, ranges, WINDOW_MIN, cache, overrides, marks, keep
        )
        grids = [data[rng[0]][0] for rng in ranges]
        labelled = _base_windows(grids, [data[rng[0]][1] for rng in ranges])
        for (k0, k1, i), grid, (label, code0) in zip(batch, grids, labelled, strict=True):
            w_lo, segs = layout[i]
            base = segs[k0].a
            for k in range(k0, k1):
                a, b = segs[k].a - base, segs[k].b - base
                index = np.arange(segs[k].a, segs[k].b) + w_lo
                windows[(i, k)] = (index, grid[a:b], label[a:b], code0[a:b])


@functools.lru_cache(maxsize=256)
def _window_time(window: int) -> datetime:
    """The start of ``window`` (window lengths since 1970; kept: a summary's trains share
    their ranges' bounds)."""
    return datetime.fromtimestamp(window * WINDOW_S, UTC)


def _base_windows(grids: list, counts: list) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`.pair_labels.base_windows` of each range's sums and setpoint counts, the ranges of
    one length in one call (a call per train cost 135 ms for 450 trains, measured)."""
    by_length: dict[int, list[int]] = {}
    for j, grid in enumerate(grids):
        by_length.setdefault(len(grid), []).append(j)
    out: list = [None] * len(grids)
    for group in by_length.values():
        labels, codes = pair_labels.base_windows(
            np.stack([grids[j] for j in group]), np.stack([counts[j] for j in group]), WINDOW_MIN
        )
        for j, label, code in zip(group, labels, codes, strict=True):
            out[j] = (label, code)
    return out


def _windows_from_pair_days(
    session, pairs, switch_hours, layout, windows, row_of, partial=False, only=None, at=None
) -> None:
    """The windows of segments from their stored pair days (``row_of``, :func:`_stored`): the
    partial ones (``partial``), or those at ``at[i]`` for the pairs ``only``."""
    wanted: dict[tuple, list[tuple[int, int]]] = {}
    bounds: dict[tuple, tuple[int, int]] = {}  # per pair day: the windows its places span
    these = set(only or ())
    # the places of the segments that are not whole days (a range's first and last at most),
    # once per distinct layout: the trains of a summary share theirs (:func:`_segments`)
    partial_at: dict[int, list[int]] = {}
    for i, ((c0, c1, _, _), hour) in enumerate(zip(pairs, switch_hours, strict=True)):
        segs = layout[i][1]
        if partial and id(segs) not in partial_at:
            partial_at[id(segs)] = [k for k, seg in enumerate(segs) if not seg.whole]
        chosen = partial_at[id(segs)] if partial else [at[i]] if i in these else []
        for k in chosen:
            seg = segs[k]
            if (i, k) in windows:
                continue
            if row_of[i][k] >= 0:
                key = (c0, c1, hour, seg.day)
                wanted.setdefault(key, []).append((i, k))
                a, b = seg.a + layout[i][0], seg.b + layout[i][0]
                lo, hi = bounds.get(key, (a, b))
                bounds[key] = (min(lo, a), max(hi, b))
    found = pair_days.stored_windows(session, bounds)
    for key, places in wanted.items():
        first, grid, label, code0 = found[key]
        for i, k in places:
            w_lo, segs = layout[i]
            a, b = segs[k].a + w_lo - first, segs[k].b + w_lo - first
            index = np.arange(segs[k].a, segs[k].b) + w_lo
            windows[(i, k)] = (index, grid[a:b], label[a:b], code0[a:b])


def _compute(waiting, layout, position, windows, state, days) -> None:
    """Take the waiting pairs' next segments from their windows, those of one length at once,
    each from the state its pair is in; advance them."""
    by_length: dict[int, list[int]] = {}
    for i in waiting:
        by_length.setdefault(len(windows[(i, position[i])][0]), []).append(i)
    for group in by_length.values():
        index, grid, label, code0 = (
            np.stack([windows[(i, position[i])][j] for i in group]) for j in range(4)
        )
        label, code0 = label.astype(np.int64), code0.astype(np.int64)  # a pair day's: int8
        found = days_from_windows(
            [layout[i][1][position[i]].day for i in group],
            index,
            grid,
            label,
            code0,
            (np.array([state[i][0] for i in group]), np.array([state[i][1] for i in group])),
        )
        for i, d in zip(group, found, strict=True):
            days[i].append(d)
            state[i] = d.exiting
            position[i] += 1


def _assemble(
    days: list[list], stored: np.ndarray, executor: Executor | None
) -> Callable[[], list[dict]]:
    """Each pair's result from its days in order, stored rows (positions in ``stored``,
    :data:`_STORED`) or :class:`~.pair_days.Day` (:func:`.pair_trial.results_from_fields`),
    with its ``chart`` (of its :class:`~.pair_days.Day`) and ``chart_days`` (its stored rows'
    days and chart digests, two arrays), once its trial estimate is computed (on
    ``executor``): the function returned gives them."""
    # every pair's days one after the other: where each is (pair, slot), and which are rows
    lengths = np.array([len(mine) for mine in days], np.int64)
    flat = [d for mine in days for d in mine]
    computed = np.fromiter((isinstance(d, Day) for d in flat), bool, len(flat))
    pair_of = np.repeat(np.arange(len(days)), lengths)
    slot_of = np.arange(len(flat)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    width = int(lengths.max(initial=0))
    fields = np.zeros((len(days), width, len(FIELDS)))
    ordinals = np.zeros((len(days), width), np.int64)
    # the rows in the order of the pairs
    read = np.flatnonzero(~computed)
    at_row = np.array([flat[k] for k in read.tolist()], np.int64)
    at_pair, at_slot = pair_of[read], slot_of[read]
    read_days, digests = stored["day"][at_row], stored["chart_digest"][at_row]
    fields[at_pair, at_slot] = stored["fields"][at_row]
    ordinals[at_pair, at_slot] = read_days
    made = np.flatnonzero(computed)
    made_days = [flat[k] for k in made.tolist()]
    made_of: list[list[Day]] = [[] for _ in days]  # per pair its computed days, in order
    for p, d in zip(pair_of[made].tolist(), made_days, strict=True):
        made_of[p].append(d)
    if len(made):
        fields[pair_of[made], slot_of[made]] = np.stack([d.fields for d in made_days])
        ordinals[pair_of[made], slot_of[made]] = [d.day for d in made_days]
    estimates = trial.estimates_later(pair_trial.trial_days(fields, ordinals), executor)

    def results() -> list[dict]:
        out = pair_trial.results_from_fields(fields, ordinals, WINDOW_MIN, estimates())
        bounds = np.searchsorted(at_pair, np.arange(len(days) + 1)).tolist()
        none = (np.zeros(0, np.int64), np.zeros((0, len(CHART_FIELDS))))
        for p, (computed, result) in enumerate(zip(made_of, out, strict=True)):
            result["chart"] = (
                np.concatenate([none[0], *(d.chart_windows for d in computed)]),
                np.concatenate([none[1], *(d.chart for d in computed)]),
            )
            a, b = bounds[p], bounds[p + 1]
            result["chart_days"] = (read_days[a:b], digests[a:b])
        return out

    return results
