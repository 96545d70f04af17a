"""Setpoint rollups: each coach's setpoints counted per 30-minute window as the scheduler issues
them, so the pair comparison, the fleet summary and the trial estimates read one row per coach
and window instead of every tick.

A setpoint issued at tick t acts from t: its window is ⌊t / 30 min⌋ (t in whole seconds since
1970, :class:`~.models.SetpointRollup`). Setpoints are only ever inserted, each (coach, tick)
once, so a new setpoint adds one to its window's counts — a tick issued late updates the window
it belongs to like any other. What each count counts (:data:`COUNTS`) is defined once here
(:data:`CONDITIONS`), for the counts kept in Python (:func:`increments`) and those summed in the
database (:func:`aggregates`: the rebuild and :func:`.pair_labels.setpoint_counts` over the raw
setpoints alike).
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
from sqlalchemy import Table, and_, case, delete, func, select
from sqlalchemy.orm import Session
from sqlalchemy.sql.expression import ColumnElement

from trainclimate.service.store import binary_rows
from trainclimate.service.store.models import Setpoint, SetpointRollup
from trainclimate.service.store.sqltime import EpochSeconds
from trainclimate.service.store.upsert import accumulate

#: What is counted per coach and window, in order.
COUNTS = ("ticks", "ddpc", "inactive", "no_model", "override", "fallback", "not_regular")
#: The reasons of a ``rule`` setpoint with the layer off: switched off, or handed back by the
#: train's guard (:mod:`.guard`); either counts as T_rule with the layer off.
LAYER_OFF = ("inactive", "costing_energy")
#: Per count, the values a setpoint's columns must take for it to count (every tick for
#: ``ticks``).
CONDITIONS: dict[str, dict[str, tuple[str, ...]]] = {
    "ticks": {},
    "ddpc": {"source": ("ddpc",)},
    "inactive": {"source": ("rule",), "reason": LAYER_OFF},
    "no_model": {"reason": ("no_model",)},
    "override": {"source": ("override",)},
    "fallback": {"source": ("fallback",)},
    "not_regular": {"reason": ("not_regular",)},
}
#: The rollups' window. [min]
WINDOW_MIN = 30
_WINDOW_S = WINDOW_MIN * 60


def _table() -> Table:
    """The rollups' table (declared as a table: its type says only "a FROM clause")."""
    return cast(Table, SetpointRollup.__table__)


def window_of(tick) -> int:
    """The window of a setpoint issued at ``tick`` (timezone-aware): ⌊t / 30 min⌋, t in whole
    seconds since 1970."""
    return math.floor(tick.timestamp()) // _WINDOW_S


def increments(rows: list[dict]) -> list[dict]:
    """What new setpoint ``rows`` (as the scheduler stores them: ``coach_id``, ``tick``,
    ``source``, ``reason``) add per coach and window: its ``coach_id``, ``window`` and the
    :data:`COUNTS`, ordered by coach and window."""
    out: dict[tuple[str, int], dict] = {}
    for r in rows:
        key = (r["coach_id"], window_of(r["tick"]))
        acc = out.get(key)
        if acc is None:
            acc = out[key] = {"coach_id": key[0], "window": key[1], **dict.fromkeys(COUNTS, 0)}
        for name in COUNTS:
            if all(r[column] in values for column, values in CONDITIONS[name].items()):
                acc[name] += 1
    return [out[key] for key in sorted(out)]


def aggregates(table: Table) -> list[ColumnElement[int]]:
    """The :data:`COUNTS` over the setpoints of ``table`` (a GROUP BY's aggregates), in order."""
    out: list[ColumnElement[int]] = []
    for name in COUNTS:
        condition = CONDITIONS[name]
        if not condition:
            out.append(func.count())
            continue
        match = and_(*(table.c[column].in_(values) for column, values in condition.items()))
        out.append(func.sum(case((match, 1), else_=0)))
    return out


def add(session: Session, rows: list[dict]) -> None:
    """Add newly stored setpoint ``rows`` to their coaches' window counts, in the caller's
    transaction, coach by coach and window by window (two writers take the rows' locks in one
    order)."""
    accumulate(session, _table(), increments(rows), ["coach_id", "window"], list(COUNTS))


def rebuild(session: Session) -> int:
    """Recount every window from the stored setpoints, in the database (for setpoints stored
    around the scheduler, e.g. with COPY, and the migration that adds the rollups). Returns how
    many window rollups there are."""
    t = cast(Table, Setpoint.__table__)
    window = (EpochSeconds(t.c.tick) // _WINDOW_S).label("window")
    # written in key order: a coach's windows on few pages (a hashed grouping wrote them in no
    # order, and reading 256 coaches' windows of a day touched a page per window)
    counted = (
        select(t.c.coach_id, window, *aggregates(t))
        .group_by(t.c.coach_id, window)
        .order_by(t.c.coach_id, window)
    )
    session.execute(delete(SetpointRollup))
    session.execute(_table().insert().from_select(["coach_id", "window", *COUNTS], counted))
    return session.scalar(select(func.count()).select_from(SetpointRollup)) or 0


def read_rows(session: Session, coaches: list[str], lo_w: int, hi_w: int) -> np.ndarray:
    """The ``coaches``' counts of windows ``lo_w`` ≤ w < ``hi_w`` as one structured array
    (fields ``coach`` — the position in ``coaches`` —, ``window`` and :data:`COUNTS`), in no
    particular order (:func:`.binary_rows.coach_windows`)."""
    return binary_rows.coach_windows(session, _table(), list(COUNTS), coaches, lo_w, hi_w)


def read(
    session: Session, coaches: list[str], lo_w: int, hi_w: int
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The ``coaches``' counts of windows ``lo_w`` ≤ w < ``hi_w`` (:func:`read_rows`).

    Returns
    -------
    dict
        Coach id → its windows' indices (n,) int64, ordered, and their counts
        (n, len(COUNTS)) float; coaches without a window are left out.
    """
    rows = np.sort(read_rows(session, coaches, lo_w, hi_w), order=["coach", "window"])
    counts = np.stack([rows[c] for c in COUNTS], axis=-1).reshape(len(rows), len(COUNTS))
    starts = np.flatnonzero(np.r_[True, rows["coach"][1:] != rows["coach"][:-1]])
    ends = [*starts[1:], len(rows)]
    return {
        coaches[int(rows["coach"][a])]: (rows["window"][a:b], counts[a:b].astype(float))
        for a, b in zip(starts, ends, strict=True)
        if b > a
    }
