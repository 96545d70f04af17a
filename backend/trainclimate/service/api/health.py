"""Liveness and readiness, without authentication; the replicas (viewer)."""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime, timedelta

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from trainclimate import __version__
from trainclimate.service import readiness
from trainclimate.service.api import schemas
from trainclimate.service.api.deps import DB, Viewer
from trainclimate.service.store import queries

#: ``GET /replicas`` lists the replicas that decided a setpoint this long ago or since.
REPLICAS_SEEN = timedelta(hours=1)

router = APIRouter()


@router.get("/health", response_model=schemas.Health, tags=["health"])
def health(request: Request) -> dict:
    """Liveness, without authentication, and what the service is still preparing (e.g. the
    predictor model, with how far it is), the telemetry rows refused since start, and the MQTT
    feed's state and counts."""
    status = request.app.state.preparation.status
    mqtt = request.app.state.mqtt
    preparing = [status] if status.state != "done" else []
    return {
        "status": "ok",
        "version": __version__,
        "database": request.app.state.db.dialect,
        "preparing": preparing,
        "telemetry_refused": request.app.state.backfill.refused,
        "mqtt": dataclasses.asdict(mqtt.status) if mqtt is not None else None,
    }


@router.get(
    "/ready",
    response_model=schemas.Ready,
    tags=["health"],
    responses={503: {"model": schemas.NotReady}},
)
def ready(request: Request):
    """Readiness of this replica: the database answers, its schema is at the newest migration,
    a predictor model is active (or the first one is being prepared while the coaches run under
    T_rule), and each loop of this replica completed an iteration within two periods of its
    clock. Otherwise 503 with the reasons."""
    state = request.app.state
    found = readiness.check(state.db, state.migrations_head, state.scheduler, state.preparation)
    if found.reasons:
        detail = "not ready: " + "; ".join(found.reasons)
        return JSONResponse({"detail": detail, "reasons": found.reasons}, status_code=503)
    return {"status": "ready", **dataclasses.asdict(found)}


@router.get("/replicas", response_model=list[schemas.ReplicaOut], tags=["health"])
def replicas(request: Request, s: DB, _: Viewer) -> list[dict]:
    """The service replicas that decided setpoints in the last hour, with the coaches and the
    number of ticks each took (replicas sharing one PostgreSQL database split the coaches)."""
    this = request.app.state.scheduler.replica
    seen = queries.replicas(s, datetime.now(UTC) - REPLICAS_SEEN)
    return [{**r, "this": r["replica"] == this} for r in seen]
