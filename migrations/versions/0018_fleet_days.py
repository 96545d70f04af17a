"""fleet days: the fleet chart of each whole service day, pooled over its pair days

A fleet summary over a new range of days reads each whole day's fleet chart as one row instead
of every pair day's chart. Each pair day now carries a digest of its chart, by which a summary
checks that a fleet day pools exactly the pair days it read. The pair days stored are dropped
(they have no digest): the scheduler makes them again from the window rollups, a few days at a
time, and the summary reads the days without a row from the rollups meanwhile.

Revision ID: 0018
Revises: 0017
Create Date: 2026-11-30 00:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0018"
down_revision: str | None = "0017"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.execute("DELETE FROM pair_days")
    with op.batch_alter_table("pair_days") as batch:
        batch.add_column(sa.Column("chart_digest", sa.BigInteger(), nullable=False))
    op.create_table(
        "fleet_days",
        sa.Column("day", sa.Integer(), primary_key=True, autoincrement=False),
        sa.Column("switch_hour", sa.Integer(), primary_key=True, autoincrement=False),
        sa.Column("first_window", sa.BigInteger(), nullable=False),
        sa.Column("windows", sa.Integer(), nullable=False),
        sa.Column("pairs", sa.Integer(), nullable=False),
        sa.Column("digest", sa.BigInteger(), nullable=False),
        sa.Column("chart", sa.LargeBinary(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("fleet_days")
    with op.batch_alter_table("pair_days") as batch:
        batch.drop_column("chart_digest")
