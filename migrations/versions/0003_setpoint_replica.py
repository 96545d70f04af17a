"""setpoint replica: which service process decided each setpoint

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23 20:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("setpoints", schema=None) as batch_op:
        batch_op.add_column(sa.Column("replica", sa.String(length=64), nullable=True))
        batch_op.create_index("ix_setpoints_created_at", ["created_at"])


def downgrade() -> None:
    with op.batch_alter_table("setpoints", schema=None) as batch_op:
        batch_op.drop_index("ix_setpoints_created_at")
        batch_op.drop_column("replica")
