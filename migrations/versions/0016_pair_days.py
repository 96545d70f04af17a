"""pair days: each pair's figures over each whole service day

A fleet summary over a new range of days reads one row per pair and day instead of every
window. The table starts empty: the scheduler fills it a few days at a time, and the summary
reads the days without a row from the window rollups meanwhile.

Revision ID: 0016
Revises: 0015
Create Date: 2026-11-29 09:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0016"
down_revision: str | None = "0015"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "pair_days",
        sa.Column("day", sa.Integer(), primary_key=True, autoincrement=False),
        sa.Column("coach_0", sa.String(32), sa.ForeignKey("coaches.id"), primary_key=True),
        sa.Column("coach_1", sa.String(32), sa.ForeignKey("coaches.id"), primary_key=True),
        sa.Column("switch_hour", sa.Integer(), primary_key=True, autoincrement=False),
        sa.Column("first_window", sa.BigInteger(), nullable=False),
        sa.Column("windows", sa.Integer(), nullable=False),
        *(
            sa.Column(c, sa.Integer(), nullable=False)
            for c in ("entering_label", "entering_age", "exiting_label", "exiting_age")
        ),
        *(sa.Column(c, sa.LargeBinary(), nullable=False) for c in ("fields", "chart", "minutes")),
    )
    op.create_index("ix_pair_days_coach_0", "pair_days", ["coach_0", "day"])
    op.create_index("ix_pair_days_coach_1", "pair_days", ["coach_1", "day"])


def downgrade() -> None:
    op.drop_table("pair_days")
