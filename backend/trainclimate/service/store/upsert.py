"""Writes that concurrent writers cannot make fail: ``INSERT … ON CONFLICT`` on SQLite and
PostgreSQL alike. Two gateways (or replicas) creating the same row at once — a fleet's clock, a
coach and its train, a telemetry minute sent twice — both succeed; one of them creates it."""

from __future__ import annotations

from sqlalchemy import Table, func
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session


def _insert(session: Session, table: Table):
    dialect = session.get_bind().dialect.name
    return (postgresql.insert if dialect == "postgresql" else sqlite.insert)(table)


def insert_new(session: Session, table: Table, rows: list[dict], keys: list[str]) -> int:
    """Insert the ``rows`` whose ``keys`` (a unique constraint's columns) are not stored yet;
    returns how many were inserted (the others were there, or inserted concurrently)."""
    key = table.primary_key.columns.values()[0].name
    return len(insert_new_keys(session, table, rows, keys, key))


def insert_new_keys(
    session: Session, table: Table, rows: list[dict], keys: list[str], column: str
) -> list:
    """:func:`insert_new`, returning the ``column`` of each row inserted."""
    if not rows:
        return []
    stmt = _insert(session, table).on_conflict_do_nothing(index_elements=keys)
    return list(session.scalars(stmt.returning(table.c[column]), rows))


def advance(session: Session, table: Table, key: dict, column: str, value) -> None:
    """Create the row ``key`` with ``column`` = ``value``, or move its ``column`` forward to
    ``value`` if that is later (never back), in one statement."""
    stmt = _insert(session, table).values(**key, **{column: value})
    newest = func.greatest if session.get_bind().dialect.name == "postgresql" else func.max
    stmt = stmt.on_conflict_do_update(
        index_elements=list(key),
        set_={column: newest(table.c[column], stmt.excluded[column])},
    )
    session.execute(stmt)


def accumulate(
    session: Session, table: Table, rows: list[dict], keys: list[str], add: list[str]
) -> None:
    """Insert the ``rows``, or add their ``add`` columns to those of the row already stored
    under the same ``keys``, in one statement."""
    if not rows:
        return
    stmt = _insert(session, table)
    stmt = stmt.on_conflict_do_update(
        index_elements=keys, set_={c: table.c[c] + stmt.excluded[c] for c in add}
    )
    session.execute(stmt, rows)


def keep_latest(
    session: Session, table: Table, row: dict, keys: list[str], columns: list[str], **also
) -> None:
    """Insert ``row``, or move the ``columns`` of the row already stored under the same ``keys``
    forward to its values where later (a NULL is earlier than any time) and set the columns
    ``also`` names to their expressions, in one statement."""
    stmt = _insert(session, table).values(**row)
    if session.get_bind().dialect.name == "postgresql":
        newest = {c: func.greatest(table.c[c], stmt.excluded[c]) for c in columns}  # skips NULL
    else:
        newest = {
            c: func.max(
                func.coalesce(table.c[c], stmt.excluded[c]),
                func.coalesce(stmt.excluded[c], table.c[c]),
            )
            for c in columns
        }
    session.execute(stmt.on_conflict_do_update(index_elements=keys, set_={**newest, **also}))
