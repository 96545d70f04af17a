"""replica affinity: each coach records the replica that issued its last tick

Replicas claim the coaches they hold first, so a coach stays with one replica (and its
controller's state there) from tick to tick; another replica takes it over when it is free.

Revision ID: 0014
Revises: 0013
Create Date: 2026-11-28 14:45:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0014"
down_revision: str | None = "0013"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("coaches", sa.Column("held_by", sa.String(64), nullable=True))


def downgrade() -> None:
    op.drop_column("coaches", "held_by")
