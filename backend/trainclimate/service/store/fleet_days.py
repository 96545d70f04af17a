"""Fleet days: the fleet chart of each whole service day, pooled over the pair days stored for it,
so that a fleet summary over a new range of days reads one chart per day instead of every pair
day's.

The fleet summary's chart pools, per 30-minute window, the energies of the trains that count
it (:func:`.fleet_summary.summary`). A pair day keeps its own counted windows' energies
(:mod:`.pair_days`); a fleet day (:class:`~.models.FleetDay`) adds them up over every pair
day stored for its service day and switch hour, with how many pair days it pools and the sum of
their chart digests (:func:`.pair_days.digest`). A summary takes a day's chart from its fleet
day only when the pair days it read for that day are exactly the ones pooled — the same count,
the same digests — and otherwise pools their own charts (:func:`charts`): a fleet day missing
or out of date costs time, never a figure.

A fleet day also keeps its pair days as a summary over many trains reads them (their coaches,
lead-in states, chart digests and figures: :data:`MEMBER`), so that a new range of 30 days
reads 30 rows instead of a row per pair and day (:mod:`.pair_days_read`), and a random
``version``, so that a reader keeping them knows when the day was made again.

Fleet days are made by the scheduler after the pair days (:func:`build`); every pair day
written or dropped drops its day's fleet day (:mod:`.pair_days`). The builder holds a share
lock on the pair days it pools until it commits, so a pair day dropped or replaced meanwhile
waits for it and then drops the new fleet day: a fleet day never keeps a pair day's rows
after they changed. (A pair day made meanwhile is only missing from it: a summary reads it
from its own row.)
"""

from __future__ import annotations

import secrets
from typing import cast

import numpy as np
from sqlalchemy import Table, select
from sqlalchemy.orm import Session

from trainclimate.service.store import pair_days, queries
from trainclimate.service.store.models import FleetDay
from trainclimate.service.store.pair_trial import FIELDS
from trainclimate.service.store.upsert import insert_new

#: Digests add up modulo this (they are 63-bit: a sum fits a signed 64-bit column).
_MODULUS = 1 << 63
#: A chart's columns: the pairs that count the window, then the energies per meter and role
#: (:data:`~.pair_trial.CHART_FIELDS`'s order). [1, kWh × 4]
_COLUMNS = 5
#: A fleet day's member as a summary reads it: the pair day's lead-in states (the one it was
#: entered in, the one it leaves) and chart digest (:data:`MEMBER_INTEGERS`) and its figures
#: (:data:`~.pair_trial.FIELDS`).
MEMBER_INTEGERS = ("entering_label", "entering_age", "exiting_label", "exiting_age", "chart_digest")
MEMBER = np.dtype([(name, "<i8") for name in MEMBER_INTEGERS] + [("fields", "<f8", (len(FIELDS),))])


def table() -> Table:
    return cast(Table, FleetDay.__table__)


def _pool(windows: int, charts: list[bytes]) -> np.ndarray:
    """The pair days' ``charts`` (each k × 5 float64: offset, energies) over a day of ``windows``
    windows, pooled per window: shape (windows, 5), the pairs counting each, then the sums of
    their energies."""
    entries = np.frombuffer(b"".join(charts), np.float64).reshape(-1, _COLUMNS)
    offset = entries[:, 0].astype(np.int64)
    out = np.zeros((windows, _COLUMNS))
    out[:, 0] = np.bincount(offset, minlength=windows)
    for k in range(1, _COLUMNS):
        out[:, k] = np.bincount(offset, entries[:, k], minlength=windows)
    return out


def build(session: Session, max_days: int | None = None) -> int:
    """Make the fleet days missing: each service day and switch hour with pair days stored and
    no fleet day, from its pair days (in the order of their coaches, so that the sums are
    the same whoever makes them), which stay share-locked until the transaction ends; at most
    ``max_days``, oldest first. Concurrent builders insert each once. Returns how many were
    made."""
    p, f = pair_days.table(), table()
    have = select(f.c.switch_hour, f.c.day)
    missing = sorted(
        session.execute(select(p.c.switch_hour, p.c.day).distinct().except_(have)).all(),
        key=lambda r: (r[1], r[0]),
    )
    made = []
    for hour, day in missing[:max_days]:
        rows = session.execute(
            select(
                p.c.coach_0,
                p.c.coach_1,
                p.c.first_window,
                p.c.windows,
                p.c.chart,
                *(p.c[name] for name in MEMBER_INTEGERS),
                p.c.fields,
            )
            .where(p.c.switch_hour == hour, p.c.day == day)
            .order_by(p.c.coach_0, p.c.coach_1)
            .with_for_update(read=True)
        ).all()
        first, windows = rows[0].first_window, rows[0].windows
        members = np.zeros(len(rows), MEMBER)
        for name in MEMBER_INTEGERS:
            members[name] = [r._mapping[name] for r in rows]
        members["fields"] = np.frombuffer(b"".join(r.fields for r in rows), np.float64).reshape(
            len(rows), len(FIELDS)
        )
        made.append(
            {
                "day": day,
                "switch_hour": hour,
                "first_window": first,
                "windows": windows,
                "pairs": len(rows),
                "digest": sum(r.chart_digest for r in rows) % _MODULUS,
                "chart": _pool(windows, [r.chart for r in rows]).tobytes(),
                "version": secrets.randbits(63),
                "members": "\n".join(f"{r.coach_0} {r.coach_1}" for r in rows),
                "member_rows": members.tobytes(),
            }
        )
    insert_new(session, f, made, ["day", "switch_hour"])
    return len(made)


def charts(session: Session, read: list[tuple]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fleet chart of the pair days a summary took whole from their rows, pooled per day
    and window: from each day's fleet day where it pools exactly these pair days, else from
    their own charts.

    Parameters
    ----------
    read : list of tuple
        Per pair: coach 0, coach 1, switch hour (0–23), and the days it read whole from its
        pair days and their chart digests (two int64 arrays, as :func:`.pair_days_read.pair_results`
        gives them in ``chart_days``).

    Returns
    -------
    tuple
        The windows (since 1970) with a pair counting them, how many pairs count each, and
        their energies per meter and role (:data:`~.pair_trial.CHART_FIELDS`), shapes (k,),
        (k,), (k, 4) [kWh].
    """
    sizes = [len(r[3]) for r in read]
    if not sum(sizes):
        return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, _COLUMNS - 1))
    hours = np.repeat(np.array([r[2] for r in read], np.int64), sizes)
    days = np.concatenate([r[3] for r in read])
    digests = np.concatenate([r[4] for r in read])
    # each (switch hour, day): how many pair days were read and their digests' sum, which
    # wraps modulo 2^64 in unsigned integers, so modulo 2^63 too
    groups, group = np.unique(days * 24 + hours, return_inverse=True)
    members = np.bincount(group)
    digest_sums = np.zeros(len(groups), np.uint64)
    np.add.at(digest_sums, group, digests.astype(np.uint64))
    digest_sums %= np.uint64(_MODULUS)
    f = table()
    stored = {
        (r.switch_hour, r.day): r
        for r in session.execute(
            select(
                f.c.switch_hour,
                f.c.day,
                f.c.first_window,
                f.c.windows,
                f.c.pairs,
                f.c.digest,
                f.c.chart,
            ).where(f.c.day >= int(days.min()), f.c.day <= int(days.max()))
        )
    }
    pooled, exact = [], np.zeros(len(groups), bool)
    for g, (key, n, digest) in enumerate(
        zip(groups.tolist(), members.tolist(), digest_sums.tolist(), strict=True)
    ):
        row = stored.get((key % 24, key // 24))
        if row is not None and row.pairs == n and row.digest == digest:
            pooled.append(row)
            exact[g] = True
    apart = np.flatnonzero(~exact[group])  # the pair days read of a day not pooled as read
    which = np.repeat(np.arange(len(read)), sizes)[apart]
    others = [
        (*read[p][:3], int(days[i]), int(digests[i]))
        for i, p in zip(apart.tolist(), which.tolist(), strict=True)
    ]
    w, c = _pair_charts(session, others)
    windows = np.concatenate([*(r.first_window + np.arange(r.windows) for r in pooled), w])
    chart = np.concatenate([*(np.frombuffer(r.chart).reshape(-1, _COLUMNS) for r in pooled), c])
    counted = chart[:, 0] > 0
    return windows[counted], chart[counted, 0], chart[counted, 1:]


def _pair_charts(session: Session, keys: list[tuple]) -> tuple:
    """The charts of the pair days ``keys`` (coach 0, coach 1, switch hour, day, digest), each
    counted window with the 1 pair counting it: windows (k,) and (k, 5)."""
    if not keys:
        return np.zeros(0, np.int64), np.zeros((0, _COLUMNS))
    p = pair_days.table()
    wanted = set(keys)
    rows = [
        r
        for r in session.execute(
            select(
                p.c.coach_0,
                p.c.coach_1,
                p.c.switch_hour,
                p.c.day,
                p.c.chart_digest,
                p.c.first_window,
                p.c.chart,
            ).where(
                p.c.day.in_(sorted({k[3] for k in keys})),
                queries.among(p.c.coach_0, {k[0] for k in keys}),
            )
        )
        if tuple(r[:5]) in wanted
    ]
    if len(rows) != len(wanted):
        raise pair_days.PairDaysChangedError("a pair day read by this summary changed")
    entries = np.frombuffer(b"".join(r.chart for r in rows), np.float64).reshape(-1, _COLUMNS)
    k = [len(r.chart) // (8 * _COLUMNS) for r in rows]
    windows = entries[:, 0].astype(np.int64) + np.repeat([r.first_window for r in rows], k)
    return windows, np.column_stack([np.ones(len(entries)), entries[:, 1:]])
