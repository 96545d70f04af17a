"""setpoints by model: an index on (model_id, tick) for a model's health

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-24 13:00:00.000000
"""

from collections.abc import Sequence

from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_index("ix_setpoints_model_tick", "setpoints", ["model_id", "tick"])


def downgrade() -> None:
    op.drop_index("ix_setpoints_model_tick", table_name="setpoints")
