"""coach liveness: each live coach's clock and arrivals in a table of their own

The ingest path stamps a coach's arrival and clock here, not in ``coaches`` (whose rows the
scheduler's ticks lock) nor in the one shared ``fleet_clocks`` row ``live`` (which every
ingest locked): each live coach now has its own clock, the newest time of its own telemetry.

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-27 09:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0011"
down_revision: str | None = "0010"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "coach_liveness",
        sa.Column("coach_id", sa.String(32), sa.ForeignKey("coaches.id"), primary_key=True),
        sa.Column("time", sa.DateTime(timezone=True), nullable=False),
        sa.Column("last_seen_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("anchor_time", sa.DateTime(timezone=True), nullable=True),
        sa.Column("anchor_at", sa.DateTime(timezone=True), nullable=True),
    )
    op.execute(
        "INSERT INTO coach_liveness (coach_id, time, last_seen_at) "
        "SELECT c.id, (SELECT max(t.time) FROM telemetry t WHERE t.coach_id = c.id), "
        "c.last_seen_at FROM coaches c WHERE c.fleet = 'live' "
        "AND EXISTS (SELECT 1 FROM telemetry t WHERE t.coach_id = c.id)"
    )
    op.execute("DELETE FROM fleet_clocks WHERE name = 'live'")
    op.drop_column("coaches", "last_seen_at")
    op.drop_column("fleet_clocks", "anchor_at")
    op.drop_column("fleet_clocks", "anchor_time")
    op.drop_column("fleet_clocks", "arrived_at")


def downgrade() -> None:
    op.add_column("fleet_clocks", sa.Column("arrived_at", sa.DateTime(timezone=True)))
    op.add_column("fleet_clocks", sa.Column("anchor_time", sa.DateTime(timezone=True)))
    op.add_column("fleet_clocks", sa.Column("anchor_at", sa.DateTime(timezone=True)))
    op.add_column("coaches", sa.Column("last_seen_at", sa.DateTime(timezone=True)))
    op.execute(
        "UPDATE coaches SET last_seen_at = (SELECT l.last_seen_at FROM coach_liveness l "
        "WHERE l.coach_id = coaches.id)"
    )
    op.execute(
        "INSERT INTO fleet_clocks (name, time, updated_at, arrived_at) "
        "SELECT 'live', max(time), CURRENT_TIMESTAMP, max(last_seen_at) FROM coach_liveness "
        "HAVING count(*) > 0"
    )
    op.drop_table("coach_liveness")
