"""Liveness and readiness, without authentication; the replicas (viewer)."""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime, timedelta

from fastapi import APIRouter, Request
from fastapi.encoders import jsonable_encoder
from fastapi.responses import JSONResponse

from trainclimate import __version__
from trainclimate.service import readiness
from trainclimate.service.api.deps import DB, Viewer
from trainclimate.service.api.schemas.health import Health, NotReady, Ready, ReplicaOut
from trainclimate.service.store import queries

#: ``GET /replicas`` lists the replicas that decided a setpoint this long ago or since.
REPLICAS_SEEN = timedelta(hours=1)

router = APIRouter()


@router.get("/health", response_model=Health, tags=["health"])
async def health(request: Request) -> dict:
    """Liveness, without authentication, and what the service is still preparing (e.g. the
    predictor model, with how far it is), the telemetry rows refused since start, the MQTT
    feed's state and counts, and the storage's state (a full disk named). Answered from memory
    on the event loop: no worker thread, no database, so it answers while the process lives,
    whatever the database or the requests are doing."""
    state = request.app.state
    status = state.preparation.status
    mqtt = state.mqtt
    preparing = [status] if status.state != "done" else []
    return {
        "status": "ok",
        "version": __version__,
        "database": state.db.dialect,
        "preparing": preparing,
        "telemetry_refused": state.backfill.refused,
        "mqtt": dataclasses.asdict(mqtt.status) if mqtt is not None else None,
        "storage": state.db.storage.state.as_dict(),
    }


@router.get(
    "/ready",
    response_model=Ready,
    tags=["health"],
    responses={503: {"model": NotReady}},
)
async def ready(request: Request):
    """Readiness of this replica: the database answers (within ``ready_timeout_s``, 3 s by
    default), its schema is at the newest migration, a predictor model is active (or the first
    one is being prepared while the coaches run under T_rule), the storage takes writes (no
    full disk), and each loop of this replica completed an iteration within two periods of its
    clock. Otherwise 503 with the reasons. Its database check runs on threads and a connection
    of its own, never behind the requests' worker threads."""
    state = request.app.state
    found = await readiness.check_off_pool(
        state.probe_threads,
        state.settings.ready_timeout_s,
        state.db,
        state.migrations_head,
        state.scheduler,
        state.preparation,
    )
    if found.reasons:
        detail = "not ready: " + "; ".join(found.reasons)
        body = {"detail": detail, "reasons": found.reasons, "storage": found.storage}
        return JSONResponse(jsonable_encoder(body), status_code=503)
    return {"status": "ready", **dataclasses.asdict(found)}


@router.get("/replicas", response_model=list[ReplicaOut], tags=["health"])
def replicas(request: Request, s: DB, _: Viewer) -> list[dict]:
    """The service replicas that decided setpoints in the last hour, with the coaches and the
    number of ticks each took (replicas sharing one PostgreSQL database split the coaches)."""
    this = request.app.state.scheduler.replica
    seen = queries.replicas(s, datetime.now(UTC) - REPLICAS_SEEN)
    return [{**r, "this": r["replica"] == this} for r in seen]
