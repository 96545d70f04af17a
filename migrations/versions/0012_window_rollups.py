"""window rollups: each coach's telemetry summed per 30-minute window, and its feed's state

The pair comparison, the fleet summary and the trial estimates read these sums instead of every
minute; the attention list reads each coach's newest row and newest row within comfort, the read
cache its late rows. Both are
kept by the ingest path; here they are computed once from the telemetry already stored.

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-28 14:30:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.orm import Session

revision: str = "0012"
down_revision: str | None = "0011"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

MASKS = ("present", "connected", "powered", "regular", "split")
TOTALS = (
    "energy_kwh",
    "hvac_kwh",
    "discomfort_up_kh",
    "discomfort_mid_kh",
    "discomfort_low_kh",
)


def upgrade() -> None:
    op.create_table(
        "window_rollups",
        sa.Column("coach_id", sa.String(32), sa.ForeignKey("coaches.id"), primary_key=True),
        sa.Column("window", sa.BigInteger(), primary_key=True, autoincrement=False),
        *(sa.Column(m, sa.BigInteger(), nullable=False) for m in MASKS),
        *(sa.Column(t, sa.Float(), nullable=False) for t in TOTALS),
    )
    op.create_table(
        "coach_feed",
        sa.Column("coach_id", sa.String(32), sa.ForeignKey("coaches.id"), primary_key=True),
        sa.Column("newest", sa.DateTime(timezone=True), nullable=False),
        sa.Column("last_ok", sa.DateTime(timezone=True), nullable=True),
        sa.Column("late_rows", sa.BigInteger(), nullable=False),
    )
    from trainclimate.service.store import rollups  # the sums as the service computes them

    rollups.rebuild(Session(bind=op.get_bind()), firsts=False)  # 0017 adds the first rows


def downgrade() -> None:
    op.drop_table("coach_feed")
    op.drop_table("window_rollups")
