"""telemetry partitioned by calendar month on PostgreSQL

``telemetry`` becomes a table partitioned by range of ``time``: a partition per calendar month
(UTC) that has rows, and for the current month and the next two, plus a default partition
(:mod:`trainclimate.service.store.partitions`), so a month past the retention period is dropped
whole instead of deleted row by row. The partition key is in every unique constraint: the
primary key becomes (id, time); the unique (coach_id, time) the ingest's ``ON CONFLICT`` needs
stays. The rows are copied with their ids, the id sequence goes on where it was, and any index
the table had besides its constraints is created again. The downgrade copies the rows back into a
plain table. On SQLite nothing changes either way.

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-28 15:00:00.000000
"""

from collections.abc import Sequence
from datetime import UTC, datetime

from alembic import op
from sqlalchemy import text
from sqlalchemy.engine import Connection
from sqlalchemy.orm import Session

revision: str = "0013"
down_revision: str | None = "0012"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: The id sequence both tables take their default from.
SEQUENCE = "telemetry_id_seq"


def _other_indexes(bind: Connection) -> list[tuple[str, str]]:
    """The indexes of ``telemetry`` that no constraint owns: (name, its CREATE INDEX)."""
    rows = bind.execute(
        text(
            "SELECT i.relname, pg_get_indexdef(x.indexrelid) FROM pg_index x "
            "JOIN pg_class i ON i.oid = x.indexrelid WHERE x.indrelid = 'telemetry'::regclass "
            "AND NOT EXISTS (SELECT 1 FROM pg_constraint c "
            "WHERE c.conrelid = x.indrelid AND c.conindid = x.indexrelid) ORDER BY i.relname"
        )
    )
    # a partitioned table's index reads ``ON ONLY telemetry``: created again, it recurses
    return [(name, ddl.replace(" ON ONLY ", " ON ")) for name, ddl in rows]


def _set_aside(bind: Connection, aside: str) -> list[tuple[str, str]]:
    """Rename ``telemetry`` to ``aside`` (its constraints too, freeing their names), release
    the id sequence from it and drop its other indexes; returns those indexes."""
    indexes = _other_indexes(bind)
    for name, _ in indexes:
        op.execute(f'DROP INDEX "{name}"')
    op.execute(f'ALTER TABLE telemetry RENAME TO "{aside}"')
    op.execute(f'ALTER TABLE "{aside}" RENAME CONSTRAINT telemetry_pkey TO "{aside}_pkey"')
    op.execute(f'ALTER TABLE "{aside}" RENAME CONSTRAINT uq_telemetry_coach_time TO "uq_{aside}"')
    op.execute(f"ALTER SEQUENCE {SEQUENCE} OWNED BY NONE")
    return indexes


def _finish(aside: str, primary_key: str, indexes: list[tuple[str, str]]) -> None:
    """Copy the rows of ``aside`` into the new ``telemetry``, drop ``aside``, give the id
    sequence to the new table, and add the constraints (after the copy: one index build each)
    and the other ``indexes``."""
    op.execute(f'INSERT INTO telemetry SELECT * FROM "{aside}"')
    op.execute(f'DROP TABLE "{aside}"')
    op.execute(f"ALTER SEQUENCE {SEQUENCE} OWNED BY telemetry.id")
    op.execute(
        f"ALTER TABLE telemetry ADD CONSTRAINT telemetry_pkey PRIMARY KEY ({primary_key}), "
        "ADD CONSTRAINT uq_telemetry_coach_time UNIQUE (coach_id, time), "
        "ADD CONSTRAINT telemetry_coach_id_fkey FOREIGN KEY (coach_id) REFERENCES coaches (id)"
    )
    for _, ddl in indexes:
        op.execute(ddl)


def upgrade() -> None:
    bind = op.get_bind()
    if bind.dialect.name != "postgresql":
        return
    from trainclimate.service.store import partitions  # the partitions as the service makes them

    aside = "telemetry_unpartitioned"
    indexes = _set_aside(bind, aside)
    op.execute(
        f'CREATE TABLE telemetry (LIKE "{aside}" INCLUDING DEFAULTS) PARTITION BY RANGE (time)'
    )
    op.execute(f"CREATE TABLE {partitions.DEFAULT} PARTITION OF telemetry DEFAULT")
    session = Session(bind=bind)
    with_rows = bind.execute(
        text(f"SELECT DISTINCT date_trunc('month', time, 'UTC') FROM \"{aside}\"")
    ).scalars()
    for month in sorted(with_rows):
        partitions.ensure_months(session, month, month)
    partitions.ensure_ahead(session, datetime.now(UTC))
    _finish(aside, "id, time", indexes)


def downgrade() -> None:
    bind = op.get_bind()
    if bind.dialect.name != "postgresql":
        return
    aside = "telemetry_partitioned"
    indexes = _set_aside(bind, aside)
    op.execute(f'CREATE TABLE telemetry (LIKE "{aside}" INCLUDING DEFAULTS)')
    _finish(aside, "id", indexes)  # dropping the partitioned table drops its partitions
