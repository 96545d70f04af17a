"""fleet days: the rows of the pair days they pool

A fleet summary over a new range of days read each whole day's row of every pair (13 500 rows
for 450 trains over 30 days). A fleet day now also keeps those rows as a summary reads them —
its members' coaches and, packed, each one's lead-in states, chart digest and figures — and a
random version set when it is made, by which a summary knows the rows it keeps are still the
day's. The fleet days stored are dropped (they have no members): the scheduler makes them again
from the pair days, and the summary reads the days without one from their pair days meanwhile.

Revision ID: 0019
Revises: 0018
Create Date: 2026-12-01 00:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0019"
down_revision: str | None = "0018"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.execute("DELETE FROM fleet_days")
    with op.batch_alter_table("fleet_days") as batch:
        batch.add_column(sa.Column("version", sa.BigInteger(), nullable=False))
        batch.add_column(sa.Column("members", sa.Text(), nullable=False))
        batch.add_column(sa.Column("member_rows", sa.LargeBinary(), nullable=False))


def downgrade() -> None:
    with op.batch_alter_table("fleet_days") as batch:
        batch.drop_column("member_rows")
        batch.drop_column("members")
        batch.drop_column("version")
