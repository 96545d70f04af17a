"""Writes that concurrent writers cannot make fail: ``INSERT … ON CONFLICT`` on SQLite and
PostgreSQL alike. Two gateways (or replicas) creating the same row at once — a fleet's clock, a
coach and its train, a telemetry minute sent twice — both succeed; one of them creates it."""

from __future__ import annotations

import functools

from sqlalchemy import Table, bindparam, func
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

# The statements are built once per table and columns and kept (building one — its EXCLUDED
# alias above all — costs more than running it); each run binds its rows' values.


def _dialect(session: Session) -> str:
    return session.get_bind().dialect.name


def _insert(dialect: str, table: Table):
    return (postgresql.insert if dialect == "postgresql" else sqlite.insert)(table)


def insert_new(session: Session, table: Table, rows: list[dict], keys: list[str]) -> int:
    """Insert the ``rows`` whose ``keys`` (a unique constraint's columns) are not stored yet;
    returns how many were inserted (the others were there, or inserted concurrently)."""
    key = table.primary_key.columns.values()[0].name
    return len(insert_new_keys(session, table, rows, keys, key))


@functools.lru_cache(maxsize=64)
def _insert_new(dialect: str, table: Table, keys: tuple[str, ...], column: str):
    stmt = _insert(dialect, table).on_conflict_do_nothing(index_elements=list(keys))
    return stmt.returning(table.c[column])


def insert_new_keys(
    session: Session, table: Table, rows: list[dict], keys: list[str], column: str
) -> list:
    """:func:`insert_new`, returning the ``column`` of each row inserted."""
    if not rows:
        return []
    stmt = _insert_new(_dialect(session), table, tuple(keys), column)
    return list(session.scalars(stmt, rows))


@functools.lru_cache(maxsize=64)
def _accumulate(dialect: str, table: Table, keys: tuple[str, ...], add: tuple[str, ...]):
    stmt = _insert(dialect, table)
    return stmt.on_conflict_do_update(
        index_elements=list(keys), set_={c: table.c[c] + stmt.excluded[c] for c in add}
    )


def accumulate(
    session: Session, table: Table, rows: list[dict], keys: list[str], add: list[str]
) -> None:
    """Insert the ``rows``, or add their ``add`` columns to those of the row already stored
    under the same ``keys``, in one statement."""
    if not rows:
        return
    session.execute(_accumulate(_dialect(session), table, tuple(keys), tuple(add)), rows)


def keep_latest(
    dialect: str, table: Table, columns: list[str], keys: list[str], latest: list[str], **also
):
    """The statement that inserts a row of ``columns`` (bound by their names), or moves the
    ``latest`` columns of the row already stored under the same ``keys`` forward to its values
    where later (a NULL is earlier than any time) and sets the columns ``also`` names to their
    expressions (which may use bound parameters of their own). Build it once and keep it."""
    stmt = _insert(dialect, table).values({c: bindparam(c, type_=table.c[c].type) for c in columns})
    if dialect == "postgresql":
        newest = {c: func.greatest(table.c[c], stmt.excluded[c]) for c in latest}  # skips NULL
    else:
        newest = {
            c: func.max(
                func.coalesce(table.c[c], stmt.excluded[c]),
                func.coalesce(stmt.excluded[c], table.c[c]),
            )
            for c in latest
        }
    return stmt.on_conflict_do_update(index_elements=keys, set_={**newest, **also})
