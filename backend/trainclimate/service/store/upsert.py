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
    if not rows:
        return 0
    stmt = _insert(session, table).on_conflict_do_nothing(index_elements=keys)
    key = table.primary_key.columns.values()[0]
    return len(session.execute(stmt.returning(key), rows).all())


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
