"""Predictor models: the versions, which one the controllers use, and their health (the stored
predictions against what happened, :mod:`~trainclimate.service.store.model_health`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request
from sqlalchemy import select

from trainclimate.service.api import schemas
from trainclimate.service.api.deps import AUTH, DB, INT32_MAX, NOT_FOUND, Admin, Viewer, settings
from trainclimate.service.store import commands, model_health
from trainclimate.service.store.models import PredictorModel
from trainclimate.service.store.queries import NotFoundError

router = APIRouter()
#: The window of a model's health: the hours up to its newest prediction (at most 31 days).
Hours = Annotated[float, Query(gt=0, le=744, description="the window, h")]


@router.get("/models", response_model=list[schemas.ModelOut], tags=["models"], responses=AUTH)
def list_models(s: DB, _: Viewer) -> list:
    """The predictor model versions, with which is active."""
    return [_model(m) for m in s.scalars(select(PredictorModel).order_by(PredictorModel.version))]


@router.post(
    "/models/{version}/activate",
    response_model=schemas.ModelOut,
    tags=["models"],
    responses={**AUTH, **NOT_FOUND},
)
def activate_model(
    version: Annotated[int, Path(ge=1, le=INT32_MAX)],
    reason: Annotated[str, Query(min_length=1, max_length=500)],
    s: DB,
    who: Admin,
) -> dict:
    """Make a model version the one the controllers use; audited."""
    return _model(commands.activate_model(s, who, version, reason))


@router.get(
    "/models/active/health",
    response_model=schemas.ModelHealth,
    tags=["models"],
    responses={**AUTH, **NOT_FOUND},
)
def active_model_health(request: Request, s: DB, _: Viewer, hours: Hours = 24.0) -> dict:
    """The active model's health, as ``GET /models/{version}/health`` (404 without one)."""
    model = s.scalar(select(PredictorModel).where(PredictorModel.active.is_(True)))
    if model is None:
        raise NotFoundError("no active model")
    return model_health.model_health(s, model, hours, settings(request).sampling_min)


@router.get(
    "/models/{version}/health",
    response_model=schemas.ModelHealth,
    tags=["models"],
    responses={**AUTH, **NOT_FOUND},
)
def get_model_health(
    version: Annotated[int, Path(ge=1, le=INT32_MAX)],
    request: Request,
    s: DB,
    _: Viewer,
    hours: Hours = 24.0,
) -> dict:
    """A model's stored predictions of the ``hours`` up to its newest one (the data's clock)
    against the telemetry that followed: the MAE per prediction step over every coach and deck,
    per coach the first-step MAE, and whether the first-step MAE exceeds the paper's bound
    (0.25 °C). The actual at step k of a prediction at tick t is the row stamped t + k·Δ; rows
    missing, not connected or not in regular mode are left out."""
    model = s.scalar(select(PredictorModel).where(PredictorModel.version == version))
    if model is None:
        raise NotFoundError(f"no model version {version}")
    return model_health.model_health(s, model, hours, settings(request).sampling_min)


def _model(m: PredictorModel) -> dict:
    return {
        "id": m.id,
        "version": m.version,
        "method": m.method,
        "rho": m.rho,
        "horizon": m.horizon,
        "sampling_min": m.sampling_min,
        "active": m.active,
        "created_at": m.created_at,
        "info": m.info or {},
    }
