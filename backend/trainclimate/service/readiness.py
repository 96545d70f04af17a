"""Whether this replica is ready to serve (``GET /api/v1/ready``): its database answers, the
schema is at the newest migration, a predictor model is active or the layer knowingly runs under
T_rule while the first one is prepared, and each of this replica's loops completed an iteration
within two periods of its clock (:meth:`~trainclimate.service.scheduler.Scheduler.beat`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sqlalchemy import select, text
from sqlalchemy.exc import SQLAlchemyError

from trainclimate.service.preparation import ModelPreparation
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import PredictorModel


@dataclass
class Readiness:
    """``reasons`` (empty: ready) and what was found: the database's ``migrations`` revision,
    the active ``model_version``, whether the layer runs ``under_rule`` (no model yet), this
    ``replica``'s name and the seconds since each loop's last completed iteration."""

    replica: str
    reasons: list[str] = field(default_factory=list)
    migrations: str | None = None
    model_version: int | None = None
    under_rule: bool = False
    loops_s: dict[str, float] = field(default_factory=dict)


def check(
    db: Database, head: str, scheduler: Scheduler, preparation: ModelPreparation
) -> Readiness:
    """Check everything (see the module docstring); a failing database is one reason, not an
    error."""
    ready = Readiness(replica=scheduler.replica)
    try:
        with db.transaction() as session:
            ready.migrations = session.execute(
                text("SELECT version_num FROM alembic_version")
            ).scalar()
            if ready.migrations == head:  # (an older schema may lack the columns asked here)
                ready.model_version = session.scalar(
                    select(PredictorModel.version).where(PredictorModel.state == "active")
                )
    except SQLAlchemyError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        ready.reasons.append(f"database: {first}")
    else:
        if ready.migrations != head:
            ready.reasons.append(f"migrations at {ready.migrations}, not at the newest {head}")
        elif ready.model_version is None:
            status = preparation.status
            if status.state == "running":
                ready.under_rule = True  # knowingly: the coaches run under T_rule meanwhile
            elif status.state == "failed":
                ready.reasons.append(f"no predictor model: its preparation failed: {status.detail}")
            else:
                ready.reasons.append("no active predictor model")
    ready.loops_s = scheduler.loop_ages()
    ready.reasons += scheduler.stalled_loops()
    return ready
