"""Liveness and readiness, without authentication."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter, HTTPException, Request
from sqlalchemy import select

from trainclimate import __version__
from trainclimate.service.api import schemas
from trainclimate.service.api.deps import DB
from trainclimate.service.store.models import PredictorModel

router = APIRouter()


@router.get("/health", response_model=schemas.Health, tags=["health"])
def health(request: Request) -> dict:
    """Liveness, without authentication, and what the service is still preparing (e.g. the
    predictor model, with how far it is), and the MQTT feed's state and counts."""
    status = request.app.state.preparation.status
    mqtt = request.app.state.mqtt
    preparing = [status] if status.state != "done" else []
    return {
        "status": "ok",
        "version": __version__,
        "database": request.app.state.db.dialect,
        "preparing": preparing,
        "mqtt": dataclasses.asdict(mqtt.status) if mqtt is not None else None,
    }


@router.get(
    "/ready",
    response_model=schemas.Ready,
    tags=["health"],
    responses={503: {"model": schemas.Message}},
)
def ready(request: Request, s: DB) -> dict:
    """Readiness: the database answers, the schema is migrated and a model is active."""
    from sqlalchemy import text

    try:
        revision = s.execute(text("SELECT version_num FROM alembic_version")).scalar()
    except Exception as exc:
        raise HTTPException(503, f"database not ready: {type(exc).__name__}") from None
    model = s.scalar(select(PredictorModel.version).where(PredictorModel.active.is_(True)))
    return {"status": "ready", "migrations": revision, "model_version": model}
