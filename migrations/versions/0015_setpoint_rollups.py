"""setpoint rollups: each coach's setpoints counted per 30-minute window

The pair comparison, the fleet summary and the trial estimates read these counts instead of
every tick. They are kept by the scheduler; here they are counted once from the setpoints
already stored, in one INSERT … SELECT … GROUP BY.

Revision ID: 0015
Revises: 0014
Create Date: 2026-11-28 15:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.orm import Session

revision: str = "0015"
down_revision: str | None = "0014"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

COUNTS = ("ticks", "ddpc", "inactive", "no_model", "override", "fallback", "not_regular")


def upgrade() -> None:
    op.create_table(
        "setpoint_rollups",
        sa.Column("coach_id", sa.String(32), sa.ForeignKey("coaches.id"), primary_key=True),
        sa.Column("window", sa.BigInteger(), primary_key=True, autoincrement=False),
        *(sa.Column(c, sa.Integer(), nullable=False) for c in COUNTS),
    )
    from trainclimate.service.store import setpoint_rollups  # counted as the service counts

    setpoint_rollups.rebuild(Session(bind=op.get_bind()))


def downgrade() -> None:
    op.drop_table("setpoint_rollups")
