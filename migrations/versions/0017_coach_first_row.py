"""coach feed: the time of each coach's oldest row

The fleet summary moves a range's start up to where a pair's data begins; it reads that from
the coach's feed row instead of probing every partition of the telemetry. Filled from the
telemetry already stored.

Revision ID: 0017
Revises: 0016
Create Date: 2026-11-29 14:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0017"
down_revision: str | None = "0016"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("coach_feed", sa.Column("first", sa.DateTime(timezone=True), nullable=True))
    op.execute(
        "UPDATE coach_feed SET first = "
        "(SELECT min(time) FROM telemetry WHERE telemetry.coach_id = coach_feed.coach_id)"
    )


def downgrade() -> None:
    with op.batch_alter_table("coach_feed") as batch:
        batch.drop_column("first")
