"""Telemetry by calendar month: the partitions of ``telemetry`` on PostgreSQL, and dropping raw
minutes older than a retention period.

On PostgreSQL (from migration 0013) ``telemetry`` is partitioned by range of ``time``: one
partition per calendar month in UTC, named ``telemetry_yYYYYmMM`` (e.g. ``telemetry_y2024m11``
holds 2024-11-01 00:00 ≤ time < 2024-12-01 00:00 UTC), and a default partition
(``telemetry_default``) for any row outside them, so an insert never fails. The service creates
the current month's and the next :data:`AHEAD_MONTHS` months' partitions at start
(:func:`ensure_months`), and ``trainclimate retention`` does too each time it runs. A month past
the retention period is dropped whole (``DROP TABLE``: its disk space is returned at once, without
a ``VACUUM``); the rows older than the cut-off in the month that straddles it, and in the default
partition, are deleted. On SQLite the table is one table and the old rows are deleted.

The window rollups and comfort states (:mod:`.rollups`) are never touched: the comparisons and
summaries over older ranges still answer from them.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta
from typing import Any, cast

from sqlalchemy import CursorResult, Result, delete, text
from sqlalchemy.orm import Session

from trainclimate.service.store import pair_days, rollups
from trainclimate.service.store.models import Telemetry

#: The partitioned table and its default partition.
PARENT = "telemetry"
DEFAULT = "telemetry_default"
#: How many months after the current one have a partition ready.
AHEAD_MONTHS = 2
#: The name of a monthly partition: year and month.
_MONTHLY = re.compile(r"telemetry_y(\d{4})m(\d{2})")


def month_start(t: datetime) -> datetime:
    """The first instant (UTC) of the calendar month (UTC) of the timezone-aware ``t``."""
    t = t.astimezone(UTC)
    return datetime(t.year, t.month, 1, tzinfo=UTC)


def next_month(month: datetime) -> datetime:
    """The first instant of the month after ``month`` (a month's first instant)."""
    return datetime(month.year + month.month // 12, month.month % 12 + 1, 1, tzinfo=UTC)


def months(start: datetime, end: datetime) -> list[datetime]:
    """The first instants of the months from ``start``'s to ``end``'s, both included."""
    out, month = [], month_start(start)
    while month <= end:
        out.append(month)
        month = next_month(month)
    return out


def partition_name(month: datetime) -> str:
    """The partition of ``month`` (its first instant), e.g. ``telemetry_y2024m11``."""
    return f"telemetry_y{month.year:04d}m{month.month:02d}"


def is_partition(name: str) -> bool:
    """Whether the table ``name`` is a partition of ``telemetry`` (a monthly one or the
    default): a piece of the one table the models describe, not a table of its own."""
    return name == DEFAULT or _MONTHLY.fullmatch(name) is not None


def include_name(name: str | None, type_: str, _parents: Any) -> bool:
    """Alembic's ``include_name``: compare every table but the partitions of ``telemetry``
    (autogenerate would otherwise see them as tables the models lack)."""
    return type_ != "table" or name is None or not is_partition(name)


def is_partitioned(session: Session) -> bool:
    """Whether ``telemetry`` is partitioned here (PostgreSQL, migrated to 0013 or later)."""
    if session.get_bind().dialect.name != "postgresql":
        return False
    kind = "SELECT relkind FROM pg_class WHERE oid = to_regclass(:t)"
    return session.scalar(text(kind), {"t": PARENT}) == "p"


def monthly_partitions(session: Session) -> dict[str, datetime]:
    """The monthly partitions of ``telemetry`` (name → the first instant of its month), oldest
    first; none where it is not partitioned (SQLite)."""
    if not is_partitioned(session):
        return {}
    names = session.scalars(
        text(
            "SELECT c.relname FROM pg_inherits i JOIN pg_class c ON c.oid = i.inhrelid "
            "WHERE i.inhparent = to_regclass(:t)"
        ),
        {"t": PARENT},
    )
    found = {}
    for name in names:
        match = _MONTHLY.fullmatch(name)
        if match:
            found[name] = datetime(int(match[1]), int(match[2]), 1, tzinfo=UTC)
    return dict(sorted(found.items(), key=lambda item: item[1]))


def create_month(session: Session, month: datetime) -> str:
    """Create the partition of ``month`` (its first instant), moving that month's rows out of
    the default partition into it first (PostgreSQL refuses to attach a partition whose rows sit
    in the default one). Returns its name."""
    name, upper = partition_name(month), next_month(month)
    bounds = {"lo": month, "hi": upper}
    session.execute(text(f'CREATE TABLE "{name}" (LIKE "{PARENT}" INCLUDING DEFAULTS)'))
    session.execute(
        text(
            f'WITH moved AS (DELETE FROM "{DEFAULT}" WHERE time >= :lo AND time < :hi '
            f'RETURNING *) INSERT INTO "{name}" SELECT * FROM moved'
        ),
        bounds,
    )
    # the bounds are literals in DDL (no parameters there); ISO 8601 with the offset: UTC
    session.execute(
        text(
            f'ALTER TABLE "{PARENT}" ATTACH PARTITION "{name}" '
            f"FOR VALUES FROM ('{month.isoformat()}') TO ('{upper.isoformat()}')"
        )
    )
    return name


def ensure_months(session: Session, start: datetime, end: datetime) -> list[str]:
    """Create the monthly partitions of the months from ``start``'s to ``end``'s (both
    included) that do not exist yet (:func:`create_month`), in the caller's transaction; returns
    their names. Nothing to do where ``telemetry`` is not partitioned (SQLite)."""
    if not is_partitioned(session):
        return []
    have = monthly_partitions(session)
    return [create_month(session, m) for m in months(start, end) if partition_name(m) not in have]


def ensure_ahead(session: Session, now: datetime) -> list[str]:
    """:func:`ensure_months` for the month of ``now`` and the :data:`AHEAD_MONTHS` after it."""
    last = month_start(now)
    for _ in range(AHEAD_MONTHS):
        last = next_month(last)
    return ensure_months(session, now, last)


def raw_retention(session: Session, raw_days: float, now: datetime) -> dict:
    """Drop the telemetry stamped before ``now`` − ``raw_days`` days (the cut-off), in the
    caller's transaction. On PostgreSQL the rows before the cut-off are deleted from the monthly
    partition that straddles it and from the default partition, then every monthly partition
    entirely before the cut-off is dropped (its rows counted first): last, so the exclusive lock
    a drop takes on ``telemetry`` is held only until the commit that follows. On SQLite the rows
    before the cut-off are deleted. The coaches' oldest rows are read again where they were
    dropped (:func:`.rollups.recount_firsts`), and the pair days that begin before the cut-off
    are dropped (:func:`.pair_days.forget_all`): they are made again from the rollups.

    Returns ``cutoff`` (datetime, UTC), ``partitions_dropped`` (names, oldest first),
    ``rows_dropped`` (the rows they held), ``rows_deleted`` and ``database`` (``postgresql`` or
    ``sqlite``)."""
    cutoff = now.astimezone(UTC) - timedelta(days=raw_days)
    whole, counts, deleted = [], [], 0
    if is_partitioned(session):
        monthly = monthly_partitions(session)
        whole = [name for name, month in monthly.items() if next_month(month) <= cutoff]
        straddling = [n for n, month in monthly.items() if month < cutoff < next_month(month)]
        for name in [*straddling, DEFAULT]:
            older = text(f'DELETE FROM "{name}" WHERE time < :cutoff')
            deleted += _rowcount(session.execute(older, {"cutoff": cutoff}))
        counts = [session.scalar(text(f'SELECT count(*) FROM "{name}"')) for name in whole]
        for name in whole:
            session.execute(text(f'DROP TABLE "{name}"'))
    else:
        deleted = _rowcount(session.execute(delete(Telemetry).where(Telemetry.time < cutoff)))
    rollups.recount_firsts(session, before=cutoff)
    # a day summed from minutes now dropped would no longer be the rollups' figures
    pair_days.forget_all(session, before_window=rollups.window_of(cutoff) + 1)
    return {
        "cutoff": cutoff,
        "partitions_dropped": whole,
        "rows_dropped": sum(counts),
        "rows_deleted": deleted,
        "database": session.get_bind().dialect.name,
    }


def _rowcount(result: Result) -> int:
    """The rows a DELETE's ``result`` deleted."""
    return cast(CursorResult, result).rowcount
