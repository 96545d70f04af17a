"""feed liveness: when each coach's telemetry last arrived, and the live clock's pace

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-24 11:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("coaches", schema=None) as batch_op:
        batch_op.add_column(sa.Column("last_seen_at", sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table("fleet_clocks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("arrived_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("anchor_time", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("anchor_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("fleet_clocks", schema=None) as batch_op:
        batch_op.drop_column("anchor_at")
        batch_op.drop_column("anchor_time")
        batch_op.drop_column("arrived_at")
    with op.batch_alter_table("coaches", schema=None) as batch_op:
        batch_op.drop_column("last_seen_at")
