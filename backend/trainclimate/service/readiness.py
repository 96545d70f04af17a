"""Whether this replica is ready to serve (``GET /api/v1/ready``): its database answers, the
schema is at the newest migration, a predictor model is active or the layer knowingly runs under
T_rule while the first one is prepared, and each of this replica's loops completed an iteration
within two periods of its clock (:meth:`~trainclimate.service.scheduler.Scheduler.beat`), and
its storage takes writes (:mod:`~trainclimate.service.store.storage`: a full disk is named).

The database check runs on threads of its own (:func:`check_off_pool`) with the database's probe
connection (:meth:`~trainclimate.service.store.db.Database.probe`), so a pool whose connections
all wait — for locks a paused replica holds, say — leaves the probe an answer within its timeout.
"""

from __future__ import annotations

import asyncio
from concurrent.futures import Executor
from dataclasses import dataclass, field

from sqlalchemy import select, text
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session

from trainclimate.service.preparation import ModelPreparation
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import PredictorModel
from trainclimate.service.store.storage import StorageState


@dataclass
class Readiness:
    """``reasons`` (empty: ready) and what was found: the database's ``migrations`` revision,
    the active ``model_version``, whether the layer runs ``under_rule`` (no model yet), this
    ``replica``'s name and the seconds since each loop's last completed iteration."""

    replica: str
    reasons: list[str] = field(default_factory=list)
    storage: dict = field(default_factory=lambda: StorageState().as_dict())
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
        with Session(db.probe()) as session, session.begin():
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
    storage = db.storage.state
    ready.storage = storage.as_dict()
    if storage.state != "ok":
        since = f"{storage.since:%Y-%m-%dT%H:%M:%SZ}"
        ready.reasons.append(f"storage: {storage.detail} (since {since})")
    ready.loops_s = scheduler.loop_ages()
    ready.reasons += scheduler.stalled_loops()
    return ready


async def check_off_pool(
    threads: Executor,
    timeout_s: float,
    db: Database,
    head: str,
    scheduler: Scheduler,
    preparation: ModelPreparation,
) -> Readiness:
    """:func:`check` on ``threads`` (not the requests' worker threads), waited for at most
    ``timeout_s`` seconds: a check that takes longer is a reason (the database does not
    answer), the rest checked without it."""
    loop = asyncio.get_running_loop()
    job = loop.run_in_executor(threads, check, db, head, scheduler, preparation)
    try:
        return await asyncio.wait_for(job, timeout_s)
    except TimeoutError:
        ready = Readiness(replica=scheduler.replica, storage=db.storage.state.as_dict())
        ready.reasons.append(f"database: no answer within {timeout_s:g} s")
        ready.loops_s = scheduler.loop_ages()
        ready.reasons += scheduler.stalled_loops()
        return ready
