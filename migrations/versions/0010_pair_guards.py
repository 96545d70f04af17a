"""pair guards: each train's guard against a layer that costs energy

Revision ID: 0010
Revises: 0008
Create Date: 2026-11-27 05:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0010"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "pair_guards",
        sa.Column("train_id", sa.String(32), sa.ForeignKey("trains.id"), primary_key=True),
        sa.Column("checked_day", sa.Date(), nullable=True),
        sa.Column("below_days", sa.Integer(), nullable=False),
        sa.Column("figures", sa.JSON(), nullable=True),
        sa.Column("tripped_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("coach_id", sa.String(32), sa.ForeignKey("coaches.id"), nullable=True),
        sa.Column("counts_from", sa.DateTime(timezone=True), nullable=True),
        sa.Column("reset_by", sa.String(100), nullable=True),
        sa.Column("reset_at", sa.DateTime(timezone=True), nullable=True),
    )


def downgrade() -> None:
    op.drop_table("pair_guards")
