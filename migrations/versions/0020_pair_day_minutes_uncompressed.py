"""pair days: their windows stored uncompressed

A new range's first and last days are partial: a summary of 450 trains reads about 900 pair
days' windows, and PostgreSQL decompressed each 6 240-byte ``minutes`` value (pglz, about
3 100 bytes stored) to cut out the windows it needs. Stored out of line but uncompressed
(``STORAGE EXTERNAL``), the same statement took 5.2 instead of 7.7 ms per 256 pair days
(measured on 450 pairs × 60 days), for 3.1 kB more per pair day (about 1.1 MB per pair-year).
Pair days written from now on are stored so; those already stored keep their compression until
rebuilt, and are read the same way. SQLite has no such setting: nothing changes there.

Revision ID: 0020
Revises: 0019
Create Date: 2026-12-01 08:00:00.000000
"""

from collections.abc import Sequence

from alembic import op

revision: str = "0020"
down_revision: str | None = "0019"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        op.execute("ALTER TABLE pair_days ALTER COLUMN minutes SET STORAGE EXTERNAL")


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        op.execute("ALTER TABLE pair_days ALTER COLUMN minutes SET STORAGE EXTENDED")
