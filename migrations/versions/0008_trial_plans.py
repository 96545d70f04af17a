"""trial plans: each train's plan changes, and each service day's assignment as first applied

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-26 10:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: str | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "train_plans",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("train_id", sa.String(32), sa.ForeignKey("trains.id"), nullable=False),
        sa.Column("plan", sa.String(16), nullable=False),
        sa.Column("switch_hour", sa.Integer(), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False),
        sa.Column("effective_from", sa.DateTime(timezone=True), nullable=False),
        sa.Column("created_by", sa.String(100), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint("switch_hour >= 0 AND switch_hour <= 23", name="ck_train_plans_hour"),
        sa.CheckConstraint(
            "plan IN ('fixed', 'alternate', 'randomized', 'reference')", name="ck_train_plans_plan"
        ),
    )
    op.create_index("ix_train_plans_train_effective", "train_plans", ["train_id", "effective_from"])
    op.create_table(
        "trial_days",
        sa.Column("train_id", sa.String(32), sa.ForeignKey("trains.id"), primary_key=True),
        sa.Column("day", sa.Date(), primary_key=True),
        sa.Column("plan", sa.String(16), nullable=False),
        sa.Column("switch_hour", sa.Integer(), nullable=False),
        sa.Column("activated_coach_id", sa.String(32), sa.ForeignKey("coaches.id"), nullable=True),
    )


def downgrade() -> None:
    op.drop_table("trial_days")
    op.drop_index("ix_train_plans_train_effective", table_name="train_plans")
    op.drop_table("train_plans")
