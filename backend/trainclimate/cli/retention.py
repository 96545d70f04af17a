"""``retention``: drop the raw telemetry minutes older than a number of days from the service's
database, keep the window rollups, and create the next months' partitions
(:mod:`trainclimate.service.store.partitions`)."""

from __future__ import annotations

import argparse

from trainclimate.cli.common import UsageError, add_command, db_url, emit, migrated_database


def cmd_retention(args: argparse.Namespace) -> None:
    """``retention``: create this month's and the next months' partitions where missing, then
    drop the telemetry older than ``--raw-days`` days, and print what was done."""
    from trainclimate.service.store import partitions
    from trainclimate.service.store.db import Database
    from trainclimate.service.store.models import utcnow

    if args.raw_days < 1:
        raise UsageError(f"--raw-days {args.raw_days}: keep at least 1 day of raw telemetry")
    db = Database(migrated_database(db_url(args)))
    try:
        now = utcnow()
        with db.transaction() as session:
            created = partitions.ensure_ahead(session, now)
        with db.transaction() as session:
            report = partitions.raw_retention(session, args.raw_days, now)
    finally:
        db.dispose()
    data = {**report, "cutoff": report["cutoff"].isoformat(), "partitions_created": created}
    emit(args, data, _text)


def _text(r: dict) -> str:
    dropped = ", ".join(r["partitions_dropped"]) or "none"
    created = ", ".join(r["partitions_created"]) or "none"
    return (
        f"telemetry before {r['cutoff']} ({r['database']}): {r['rows_dropped']} rows dropped "
        f"with the partitions {dropped}, {r['rows_deleted']} rows deleted; "
        f"partitions created: {created}"
    )


def register(sub) -> None:
    """Add ``retention`` to ``sub``."""
    p = add_command(
        sub,
        "retention",
        cmd_retention,
        "drop the raw telemetry older than --raw-days days (whole monthly partitions on "
        "PostgreSQL), keep the 30-minute window rollups, and create the next months' partitions",
    )
    p.add_argument(
        "--raw-days",
        type=int,
        required=True,
        help="days of raw 1-minute telemetry to keep, at least 1",
    )
    p.add_argument(
        "--db",
        default=None,
        help="database URL (default: $TRAINCLIMATE_DATABASE_URL, then the service's SQLite file)",
    )
