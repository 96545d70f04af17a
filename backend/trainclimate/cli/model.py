"""``model retrain``: a candidate prediction model from the service's own telemetry."""

from __future__ import annotations

import argparse

import pandas as pd

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    db_url,
    emit,
    migrated_database,
    progress_bar,
)


def _time(value: str, flag: str):
    try:
        stamp = pd.Timestamp(value)
    except ValueError:
        raise UsageError(f"{flag} {value!r} is not a date or time (ISO 8601)") from None
    return (
        stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp.tz_convert("UTC")
    ).to_pydatetime()


def cmd_model_retrain(args: argparse.Namespace) -> None:
    """``model retrain``: fit on the stored telemetry, register a candidate (see
    :mod:`trainclimate.service.retrain`)."""
    from trainclimate.service.retrain import MAX_DAYS, RetrainError, retrain
    from trainclimate.service.store.db import Database

    if args.days is not None and args.since is not None:
        raise UsageError("give --days N or --since ISO, not both")
    if args.days is not None and not 0 < args.days <= MAX_DAYS:
        raise UsageError(f"--days must be positive, at most {MAX_DAYS:g}")
    if args.sampling_min < 1 or args.rho < 2 or args.horizon < 1:
        raise UsageError("--sampling-min ≥ 1, --rho ≥ 2 and --horizon ≥ 1")
    since = _time(args.since, "--since") if args.since else None
    coaches = [c.strip() for c in args.coaches.split(",") if c.strip()] if args.coaches else None
    db = Database(migrated_database(db_url(args)))
    try:
        with progress_bar(0, "retrain", "coach") as bar:

            def progress(stage: str, done: int, total: int) -> None:
                if stage == "read":
                    bar.total = total
                    bar.update(done - bar.n)

            result = retrain(
                db,
                start=since,
                days=args.days,
                coaches=coaches,
                sampling_min=args.sampling_min,
                rho=args.rho,
                horizon=args.horizon,
                force=args.force,
                progress=progress,
            )
    except RetrainError as exc:
        raise UsageError(str(exc)) from None
    finally:
        db.dispose()
    emit(args, result.to_dict(), _text)


def _text(d: dict) -> str:
    mine = ", ".join(f"{v:.3f}" for v in d["validation_mae_per_step_c"])
    theirs = d["active_validation_mae_per_step_c"]
    beside = (
        f"; active version {d['active_version']}: " + ", ".join(f"{v:.3f}" for v in theirs)
        if theirs
        else ""
    )
    return (
        f"model version {d['version']} registered as {d['state']}: {d['training_trajectories']} "
        f"training trajectories ({d['start']} … {d['end']}), validated on "
        f"{', '.join(d['validation_coaches'])}: MAE per step {mine} °C{beside}"
    )


def register(sub) -> None:
    """Add ``model retrain`` to ``sub``."""
    group = add_group(sub, "model", "the service's prediction models")
    p = add_command(
        group,
        "retrain",
        cmd_model_retrain,
        "fit a candidate model on the service's stored telemetry (it predicts in the active "
        "model's shadow until an admin activates it)",
    )
    p.add_argument("--db", default=None, help="database URL (default: the embedded SQLite)")
    p.add_argument(
        "--days",
        type=float,
        default=None,
        help="the last N days of telemetry (default 28 without --since; at most 366)",
    )
    p.add_argument("--since", default=None, help="telemetry from this time (ISO 8601, UTC)")
    p.add_argument("--coaches", default=None, help="these coaches only (comma-separated)")
    p.add_argument("--sampling-min", type=int, default=5)
    p.add_argument("--rho", type=int, default=12)
    p.add_argument("--horizon", type=int, default=6)
    p.add_argument("--force", action="store_true", help="register even a worse fit")
