"""Window rollups: each coach's telemetry summed per 30-minute window as it arrives, so the pair
comparison, the fleet summary and the trial estimates read a few sums per window instead of
every minute, and a refresh does not grow with the history kept.

A row stamped t is the minute (t − 1 min, t]: minute m = t / 60 s − 1 since 1970, window
⌊m / 30⌋, bit m mod 30 of the window's masks (:class:`~.models.WindowRollup`). Rows are only
ever inserted, each (coach, time) once, so a new row adds its bit and its values to its window —
a late row updates the window it belongs to like any other. What a pair comparison needs of a
window (:data:`~.pair_labels.SUMS`) follows from both coaches' rollups exactly whenever the two
coaches have the same minutes (``present``), the same minutes that count for comfort
(present, connected, powered, regular) and no override touches the window: the counts come
from the masks, the energies and the discomfort from each coach's own sums. Any other window —
a minute one coach has and the other not, a link lost on one coach only, an override — is summed
from the raw minutes (:func:`.pair_windows.window_sums`); such windows are few.

Each coach's feed (:class:`~.models.CoachFeed`: its newest row and its newest row within
comfort, for the attention list; the rows that arrived late, for the read cache; its oldest
row, for the fleet summary) is kept the same way.

After raw minutes are dropped (``trainclimate retention``), their windows' rollups stay: a window
that needed its raw minutes and has none left has no sums, and is excluded as one without data.
"""

from __future__ import annotations

import functools
from datetime import UTC, datetime
from typing import cast

import numpy as np
from sqlalchemy import (
    BigInteger,
    Integer,
    Table,
    and_,
    bindparam,
    case,
    delete,
    func,
    literal,
    or_,
    select,
    update,
)
from sqlalchemy import cast as sql_cast
from sqlalchemy.orm import Session

from trainclimate.coach.setpoint import COMFORT_BAND_K
from trainclimate.service.store import binary_rows
from trainclimate.service.store.models import CoachFeed, Telemetry, UTCDateTime, WindowRollup
from trainclimate.service.store.pair_labels import SUMS, SUMS_INDEX
from trainclimate.service.store.records import TelemetryRecord
from trainclimate.service.store.sqltime import EpochSeconds, OnMinute
from trainclimate.service.store.upsert import accumulate, keep_latest

#: The rollups' window. [min]
WINDOW_MIN = 30
_WINDOW_S = WINDOW_MIN * 60
#: Every minute of a window present.
FULL = (1 << WINDOW_MIN) - 1
MASKS = ("present", "connected", "powered", "regular", "split")
DECKS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
DISCOMFORT = ("discomfort_up_kh", "discomfort_mid_kh", "discomfort_low_kh")
TOTALS = ("energy_kwh", "hvac_kwh", *DISCOMFORT)


def _table(model) -> Table:
    """A model's table (declared as a table: its type says only "a FROM clause")."""
    return cast(Table, model.__table__)


def _excess(deck: float | None, rule: float | None, t_max_k: float) -> float:
    """max(0, |T_room − T_rule| − T_max) of one deck (paper, Eq. (4)); 0 if either is unknown.
    [K]"""
    if deck is None or rule is None:
        return 0.0
    return max(0.0, abs(deck - rule) - t_max_k)


def _decks(row: TelemetryRecord) -> tuple[float | None, float | None, float | None]:
    """A row's deck temperatures, in the order of :data:`DECKS`. [°C]"""
    return row["t_room_up_c"], row["t_room_mid_c"], row["t_room_low_c"]


def increments(rows: list[TelemetryRecord], t_max_k: float = COMFORT_BAND_K) -> list[dict]:
    """What one coach's new telemetry ``rows`` add to its windows: per window its ``window``
    index, the bits of :data:`MASKS` and the sums of :data:`TOTALS` (energy [kWh], discomfort
    [K·h]). Rows off the minute grid add nothing (the comparison counts the grid's minutes)."""
    out: dict[int, dict] = {}
    for r in rows:
        t = r["time"]
        if t.second or t.microsecond:
            continue
        window, bit = divmod(round(t.timestamp()) // 60 - 1, WINDOW_MIN)
        one = 1 << bit
        acc = out.get(window)
        if acc is None:
            acc = out[window] = {"window": window, **dict.fromkeys(MASKS, 0)}
            acc.update(dict.fromkeys(TOTALS, 0.0))
        connected, power = r.get("connected", True), r.get("power_kw")
        regular = r.get("mode", "regular") == "regular"
        acc["present"] += one
        acc["connected"] += one if connected else 0
        acc["powered"] += one if power is not None else 0
        acc["regular"] += one if regular else 0
        acc["split"] += one if r.get("floor_power_kw") is not None else 0
        acc["energy_kwh"] += (power or 0.0) / 60.0
        acc["hvac_kwh"] += ((power or 0.0) - (r.get("floor_power_kw") or 0.0)) / 60.0
        if connected and power is not None and regular:
            for deck, name in zip(_decks(r), DISCOMFORT, strict=True):
                acc[name] += _excess(deck, r.get("t_rule_c"), t_max_k) / 60.0
    return [out[w] for w in sorted(out)]


def comfort_state(rows: list[TelemetryRecord], t_max_k: float = COMFORT_BAND_K) -> dict:
    """One coach's ``newest`` row time among ``rows`` and ``last_ok``, its newest within
    comfort (every deck within T_rule ± T_max, or not in regular mode; None if none is)."""
    ok = [
        r["time"]
        for r in rows
        if r.get("mode", "regular") != "regular"
        or not any(_excess(d, r.get("t_rule_c"), t_max_k) > 0 for d in _decks(r))
    ]
    return {"newest": max(r["time"] for r in rows), "last_ok": max(ok, default=None)}


@functools.cache
def _feed_upsert(dialect: str):
    """The statement that adds a coach's new rows to its feed state (bound: ``coach_id``,
    ``newest``, ``last_ok``, ``first``, and ``n_rows``, which count as late if they reach back
    to or before the newest row stored)."""
    feed = _table(CoachFeed)
    first = bindparam("first", type_=UTCDateTime())
    late = case((feed.c.newest >= first, bindparam("n_rows", type_=Integer())), else_=0)
    return keep_latest(
        dialect,
        feed,
        ["coach_id", "newest", "last_ok", "late_rows", "first"],
        ["coach_id"],
        ["newest", "last_ok"],
        late_rows=feed.c.late_rows + late,
        first=case((feed.c.first <= first, feed.c.first), else_=first),  # NULL: none kept
    )


def add_rows(session: Session, rows_by_coach: dict[str, list[TelemetryRecord]]) -> None:
    """Add newly stored telemetry (coach id → its rows, each stored for the first time) to the
    coaches' window rollups and feed states (:class:`~.models.CoachFeed`), in the caller's
    transaction, coach by coach and window by window (two writers take the rows' locks in one
    order). A coach's rows that reach back to or before its newest row stored count as late."""
    windows = []
    feed = _feed_upsert(session.get_bind().dialect.name)
    for coach_id in sorted(rows_by_coach):
        rows = rows_by_coach[coach_id]
        if not rows:
            continue
        windows += [{"coach_id": coach_id, **inc} for inc in increments(rows)]
        first = min(r["time"] for r in rows)
        state = {"coach_id": coach_id, **comfort_state(rows), "late_rows": 0, "first": first}
        session.execute(feed, {**state, "n_rows": len(rows)})
    accumulate(session, _table(WindowRollup), windows, ["coach_id", "window"], [*MASKS, *TOTALS])


def rebuild(session: Session, t_max_k: float = COMFORT_BAND_K, firsts: bool = True) -> int:
    """Recompute every rollup and feed state (no row late) from the stored telemetry, in the
    database (for data loaded around the ingest path, e.g. with COPY, and the migration that
    adds them); with ``firsts`` each coach's oldest row too (False for that migration, which
    predates the column).
    Returns how many window rollups there are."""
    t = Telemetry.__table__
    minute = (EpochSeconds(t.c.time) - 60) // 60
    window = (minute // WINDOW_MIN).label("window")
    one = sql_cast(literal(1), BigInteger).op("<<")(sql_cast(minute % WINDOW_MIN, Integer))

    def bits(condition):
        return func.sum(case((condition, one), else_=0))

    powered = t.c.power_kw.is_not(None)
    regular = t.c.mode == "regular"
    ok = and_(t.c.connected, powered, regular)
    excess = [func.abs(t.c[d] - t.c.t_rule_c) - t_max_k for d in DECKS]
    columns = {
        "present": func.sum(one),
        "connected": bits(t.c.connected),
        "powered": bits(powered),
        "regular": bits(regular),
        "split": bits(t.c.floor_power_kw.is_not(None)),
        "energy_kwh": func.sum(func.coalesce(t.c.power_kw, 0.0)) / 60.0,
        "hvac_kwh": func.sum(
            func.coalesce(t.c.power_kw, 0.0) - func.coalesce(t.c.floor_power_kw, 0.0)
        )
        / 60.0,
        **{
            name: func.sum(case((and_(ok, e > 0), e), else_=0.0)) / 60.0
            for name, e in zip(DISCOMFORT, excess, strict=True)
        },
    }
    summed = (
        select(t.c.coach_id, window, *(v.label(k) for k, v in columns.items()))
        .where(OnMinute(t.c.time))
        .group_by(t.c.coach_id, window)
    )
    session.execute(delete(WindowRollup))
    session.execute(
        _table(WindowRollup).insert().from_select(["coach_id", "window", *columns], summed)
    )
    within = or_(t.c.mode != "regular", and_(*(func.coalesce(e, 0.0) <= 0 for e in excess)))
    session.execute(delete(CoachFeed))
    session.execute(
        _table(CoachFeed)
        .insert()
        .from_select(
            ["coach_id", "newest", "last_ok", "late_rows", *(["first"] if firsts else [])],
            select(
                t.c.coach_id,
                func.max(t.c.time),
                func.max(case((within, t.c.time))),
                literal(0),
                *([func.min(t.c.time)] if firsts else []),
            ).group_by(t.c.coach_id),
        )
    )
    return session.scalar(select(func.count()).select_from(WindowRollup)) or 0


def recount_firsts(session: Session, before: datetime) -> None:
    """Each coach's oldest row (:class:`~.models.CoachFeed` ``first``) read again from the
    telemetry where it was before ``before`` (rows before it have just been dropped); None for a
    coach with none left."""
    feed = _table(CoachFeed)
    t = Telemetry.__table__
    oldest = select(func.min(t.c.time)).where(t.c.coach_id == feed.c.coach_id).scalar_subquery()
    session.execute(
        update(feed).where(feed.c.first < literal(before, UTCDateTime())).values(first=oldest)
    )


def window_of(time: datetime) -> int:
    """The window of the row stamped ``time``: that of the minute (time − 1 min, time]."""
    return (round(time.timestamp()) // 60 - 1) // WINDOW_MIN


def _index(when: datetime) -> int:
    """The window that starts at ``when`` (a window boundary)."""
    return round(when.timestamp()) // _WINDOW_S


def pair_grids(
    session: Session, pairs: list[tuple[str, str, datetime, datetime]], overrides: list
) -> tuple[dict[str, np.ndarray], list[tuple[str, str, datetime, datetime]]]:
    """Per pair the :data:`~.pair_labels.SUMS` of each window of its range, from the rollups
    where they give them exactly (see the module's description).

    Parameters
    ----------
    pairs : list of (coach 0 id, coach 1 id, lo, hi)
        Each counted over (lo, hi], both on window boundaries.
    overrides : list
        :func:`.pair_windows.overrides_over` the pairs.

    Returns
    -------
    (dict, list)
        Coach 0's id → sums per window of (lo, hi], shape (W, len(SUMS)) (zeros where they
        are not exact); and the windows the rollups cannot give, as ranges (coach 0, coach 1,
        lo, hi) of one window each, for the raw sums.
    """
    if not pairs:
        return {}, []
    coaches = sorted({c for p in pairs for c in p[:2]})
    position = {c: i for i, c in enumerate(coaches)}
    rows = binary_rows.coach_windows(
        session,
        _table(WindowRollup),
        [*MASKS, *TOTALS],
        coaches,
        min(_index(p[2]) for p in pairs),
        max(_index(p[3]) for p in pairs),
    )
    masks = np.stack([rows[m] for m in MASKS], axis=-1) if len(rows) else np.zeros((0, 5), int)
    totals = np.stack([rows[t] for t in TOTALS], axis=-1) if len(rows) else np.zeros((0, 5))
    out: dict[str, np.ndarray] = {}
    raw = []
    by_range: dict[tuple, list] = {}
    for p in pairs:
        by_range.setdefault((_index(p[2]), _index(p[3])), []).append(p)
    for (w_lo, w_hi), group in by_range.items():
        for chunk in (group[i : i + _CHUNK] for i in range(0, len(group), _CHUNK)):
            grids, dirty = _chunk_grids(chunk, w_lo, w_hi, position, rows, masks, totals, overrides)
            for (c0, c1, _, _), grid, bad in zip(chunk, grids, dirty, strict=True):
                out[c0] = grid
                for w in np.flatnonzero(bad) + w_lo:
                    start = datetime.fromtimestamp(int(w) * _WINDOW_S, UTC)
                    end = datetime.fromtimestamp((int(w) + 1) * _WINDOW_S, UTC)
                    raw.append((c0, c1, start, end))
    return out, raw


#: Pairs whose windows are worked out together (bounds the arrays: 128 pairs × 30 days ≈ 25 MB).
_CHUNK = 128


def _chunk_grids(chunk, w_lo, w_hi, position, rows, masks, totals, overrides):
    """:func:`pair_grids` of pairs over the same windows [w_lo, w_hi): their sums (P, W,
    len(SUMS)) and the windows to sum from the raw minutes (P, W) bool."""
    n_w = w_hi - w_lo
    side_masks = np.zeros((2, len(chunk), n_w, len(MASKS)), np.int64)
    side_totals = np.zeros((2, len(chunk), n_w, len(TOTALS)))
    has = np.zeros((2, len(chunk), n_w), bool)
    for side in (0, 1):
        row_of = np.full(len(position), -1)
        row_of[[position[p[side]] for p in chunk]] = np.arange(len(chunk))
        r = row_of[rows["coach"]] if len(rows) else np.zeros(0, int)
        w = rows["window"] - w_lo if len(rows) else np.zeros(0, int)
        mine = (r >= 0) & (w >= 0) & (w < n_w)
        side_masks[side, r[mine], w[mine]] = masks[mine]
        side_totals[side, r[mine], w[mine]] = totals[mine]
        has[side, r[mine], w[mine]] = True
    ma, mb = side_masks
    pa, pb = ma[..., 0], mb[..., 0]
    ok_a = pa & ma[..., 1] & ma[..., 2] & ma[..., 3]
    ok_b = pb & mb[..., 1] & mb[..., 2] & mb[..., 3]
    # a window only one coach has rows in has no paired minute; nor is it in the raw sums
    paired = has[0] & has[1] & ((pa & pb) != 0)
    windows = np.arange(w_lo, w_hi)
    touched = np.zeros((len(chunk), n_w), bool)
    for _, coach_id, starts, ends, cancelled in overrides:
        hit = [coach_id in p[:2] for p in chunk]
        if any(hit):
            lo = starts.astimezone(UTC).timestamp() / _WINDOW_S
            hi = (cancelled or ends).astimezone(UTC).timestamp() / _WINDOW_S
            touched[hit] |= (windows < hi) & (windows + 1 > lo)
    dirty = paired & ((pa != pb) | (ok_a != ok_b) | touched)
    exact = paired & ~dirty
    grids = np.zeros((len(chunk), n_w, len(SUMS)))
    grids[exact] = _sums(ma[exact], mb[exact], side_totals[0][exact], side_totals[1][exact])
    return grids, dirty


def _sums(mask_a: np.ndarray, mask_b: np.ndarray, tot_a: np.ndarray, tot_b: np.ndarray):
    """The :data:`~.pair_labels.SUMS` of windows where both coaches have the same minutes and
    the same minutes that count for comfort, and no override: one row per window, from the two
    coaches' masks (:data:`MASKS` columns) and totals (:data:`TOTALS` columns)."""
    present = mask_a[:, 0]
    connected = mask_a[:, 1] & mask_b[:, 1]
    good = connected & mask_a[:, 2] & mask_b[:, 2]
    sums = np.zeros((len(present), len(SUMS)))
    columns = {
        "minutes": np.bitwise_count(present),
        "affected_minutes": np.bitwise_count(present & ~good),
        "counted_minutes": np.bitwise_count(good & mask_a[:, 3]),
        "energy_0_kwh": tot_a[:, 0],
        "energy_1_kwh": tot_b[:, 0],
        "energy_0_hvac_kwh": tot_a[:, 1],
        "energy_1_hvac_kwh": tot_b[:, 1],
        "unsplit_minutes": np.bitwise_count(present & ~(mask_a[:, 4] & mask_b[:, 4])),
        "disconnected_minutes": np.bitwise_count(present & ~connected),
    }
    for i, deck in enumerate(("up", "mid", "low")):
        columns[f"discomfort_0_{deck}_kh"] = tot_a[:, 2 + i]
        columns[f"discomfort_1_{deck}_kh"] = tot_b[:, 2 + i]
    for name, values in columns.items():
        sums[:, SUMS_INDEX[name]] = values
    return sums
