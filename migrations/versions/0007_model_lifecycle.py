"""model lifecycle: a state per model version (active, candidate, retired) with at most one
active, and the candidates' shadow predictions

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-24 23:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

ONE_ACTIVE = sa.text("state = 'active'")


def upgrade() -> None:
    op.add_column(
        "predictor_models",
        sa.Column("state", sa.String(16), nullable=False, server_default="retired"),
    )
    op.execute("UPDATE predictor_models SET state = 'active' WHERE active")
    with op.batch_alter_table("predictor_models") as batch:
        batch.drop_column("active")
    op.create_index(
        "ix_predictor_models_one_active",
        "predictor_models",
        ["state"],
        unique=True,
        postgresql_where=ONE_ACTIVE,
        sqlite_where=ONE_ACTIVE,
    )
    op.create_table(
        "shadow_predictions",
        sa.Column(
            "id",
            sa.BigInteger().with_variant(sa.Integer(), "sqlite"),
            primary_key=True,
            autoincrement=True,
        ),
        sa.Column("model_id", sa.Integer(), sa.ForeignKey("predictor_models.id"), nullable=False),
        sa.Column("coach_id", sa.String(32), sa.ForeignKey("coaches.id"), nullable=False),
        sa.Column("tick", sa.DateTime(timezone=True), nullable=False),
        sa.Column("y_pred_c", sa.JSON(), nullable=False),
        sa.UniqueConstraint("model_id", "coach_id", "tick", name="uq_shadow_model_coach_tick"),
    )
    op.create_index("ix_shadow_model_tick", "shadow_predictions", ["model_id", "tick"])


def downgrade() -> None:
    op.drop_index("ix_shadow_model_tick", table_name="shadow_predictions")
    op.drop_table("shadow_predictions")
    op.drop_index("ix_predictor_models_one_active", table_name="predictor_models")
    op.add_column(
        "predictor_models",
        sa.Column("active", sa.Boolean(), nullable=False, server_default=sa.false()),
    )
    op.execute("UPDATE predictor_models SET active = (state = 'active')")
    with op.batch_alter_table("predictor_models") as batch:
        batch.drop_column("state")
