"""``train plan``: a train's trial plan, read or changed on the service's database directly."""

from __future__ import annotations

import argparse
import getpass

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    db_url,
    emit,
    migrated_database,
)

#: The longest reason and the largest seed (as ``PUT /trains/{id}/plan`` takes them).
REASON_MAX = 500
SEED_MAX = 2**31 - 1


def cli_user() -> str:
    """Who runs the command, as the audit log records a change made here: ``cli:USER``."""
    try:
        return f"cli:{getpass.getuser()}"
    except (KeyError, OSError):  # no user name in the environment nor the password database
        return "cli:unknown"


def cmd_train_plan(args: argparse.Namespace) -> None:
    """``train plan``: print the plan view; with ``--plan``, change the plan first (audited as
    the CLI user, with the admin's rights a database URL gives)."""
    from trainclimate.analysis.trial_plan import DEFAULT_SWITCH_HOUR, PLANS
    from trainclimate.service.api.schemas.trains import TrainPlanOut
    from trainclimate.service.store import commands, plans, queries
    from trainclimate.service.store.db import Database
    from trainclimate.service.store.tokens import Principal

    changing = args.plan is not None
    given = [f for f in ("switch_hour", "seed", "reason") if getattr(args, f) is not None]
    if not changing and given:
        raise UsageError(f"--{given[0].replace('_', '-')} changes the plan: give --plan too")
    if changing and args.plan not in PLANS:
        raise UsageError(f"--plan {args.plan!r}: expected one of {', '.join(PLANS)}")
    hour = DEFAULT_SWITCH_HOUR if args.switch_hour is None else args.switch_hour
    seed = 0 if args.seed is None else args.seed
    if not 0 <= hour <= 23:
        raise UsageError(f"--switch-hour {hour}: a local hour, 0–23")
    if not 0 <= seed <= SEED_MAX:
        raise UsageError(f"--seed {seed}: 0 … {SEED_MAX}")
    if changing and not (args.reason or "").strip():
        raise UsageError("--plan needs --reason TEXT: why the plan changes (audited)")
    if changing and len(args.reason) > REASON_MAX:
        raise UsageError(f"--reason is at most {REASON_MAX} characters")
    db = Database(migrated_database(db_url(args)))
    try:
        with db.transaction() as session:
            if changing:
                view = commands.set_plan(
                    session,
                    Principal(cli_user(), "admin"),
                    args.id,
                    args.plan,
                    hour,
                    seed,
                    args.reason,
                )
            else:
                view = plans.view(session, queries.train_or_404(session, args.id))
    except (queries.NotFoundError, queries.RequestError, commands.ConflictError) as exc:
        raise UsageError(str(exc)) from None
    finally:
        db.dispose()
    # the API's answer to the same request, field for field
    emit(args, TrainPlanOut.model_validate(view).model_dump(mode="json"), _text)


def _text(v: dict) -> str:
    return f"train {v['train_id']}: {v['message']}"


def register(sub) -> None:
    """Add ``train plan`` to ``sub``."""
    group = add_group(sub, "train", "the service's trains")
    p = add_command(
        group,
        "plan",
        cmd_train_plan,
        "a train's trial plan (which coach runs the layer on which service day); with --plan, "
        "change it: from the next switch hour of the train's clock, at once on a train without "
        "telemetry",
    )
    p.add_argument("id", help="the train's id")
    p.add_argument(
        "--plan", default=None, help="the new plan: fixed, alternate, randomized or reference"
    )
    p.add_argument(
        "--switch-hour",
        type=int,
        default=None,
        help="local hour a service day starts at, 0–23 (default 3)",
    )
    p.add_argument("--seed", type=int, default=None, help="the randomized plan's seed (default 0)")
    p.add_argument("--reason", default=None, help="why the plan changes (required with --plan)")
    p.add_argument("--db", default=None, help="database URL (default: the embedded SQLite)")
