"""Predictor models: the versions, which one the controllers use, and their health (the stored
predictions against what happened, :mod:`~trainclimate.service.store.model_health`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request
from sqlalchemy import select

from trainclimate.service.api.deps import (
    AUTH,
    CONFLICT,
    DB,
    INT32_MAX,
    NOT_FOUND,
    Admin,
    Viewer,
    settings,
)
from trainclimate.service.api.schemas.base import DIGITS_ONLY
from trainclimate.service.api.schemas.models import ModelHealth, ModelOut, RetrainIn, RetrainStatus
from trainclimate.service.store import commands, model_health
from trainclimate.service.store.commands import ConflictError
from trainclimate.service.store.models import PredictorModel
from trainclimate.service.store.queries import NotFoundError, RequestError

router = APIRouter()
#: The window of a model's health: the hours up to its newest prediction (at most 31 days).
Hours = Annotated[float, Query(gt=0, le=744, description="the window, h")]


@router.get("/models", response_model=list[ModelOut], tags=["models"], responses=AUTH)
def list_models(request: Request, s: DB, _: Viewer) -> list:
    """The predictor model versions: state, validation MAE and, for the active model and the
    candidates, the online MAE (last 24 h)."""
    period = settings(request).sampling_min
    return [
        _model(
            m,
            model_health.model_health(s, m, 24.0, period)["mae_per_step_c"]
            if m.state != "retired"  # (the overview lists the models at every refresh)
            else [],
        )
        for m in s.scalars(select(PredictorModel).order_by(PredictorModel.version))
    ]


@router.post(
    "/models/retrain",
    response_model=RetrainStatus,
    status_code=202,
    tags=["models"],
    responses={**AUTH, **CONFLICT},
)
def start_retrain(body: RetrainIn, request: Request, s: DB, who: Admin) -> dict:
    """Retrain the model on the stored telemetry in the background (admin only; audited): a new
    version in state ``candidate`` when it is at least as good as the active one on the same
    validation coaches (``force``: anyway). Its progress: ``GET /models/retrain``."""
    if body.days is not None and body.since is not None:
        raise RequestError("give days or since, not both")
    job = request.app.state.retrain
    options = {"days": body.days, "start": body.since, "coaches": body.coaches, "force": body.force}
    if not job.start(who.name, body.reason, **options):
        raise ConflictError("a retraining is running: see GET /models/retrain")
    commands.audit(
        s,
        who,
        "model.retrain",
        "models",
        body.reason,
        **{k: str(v) for k, v in options.items() if v},
    )
    return job.status


@router.get("/models/retrain", response_model=RetrainStatus, tags=["models"], responses=AUTH)
def retrain_status(request: Request, _: Viewer) -> dict:
    """The last retraining's progress and outcome."""
    return request.app.state.retrain.status


@router.post(
    "/models/{version}/activate",
    response_model=ModelOut,
    tags=["models"],
    responses={**AUTH, **NOT_FOUND},
)
def activate_model(
    version: Annotated[int, Path(ge=1, le=INT32_MAX), DIGITS_ONLY],
    reason: Annotated[str, Query(min_length=1, max_length=500)],
    s: DB,
    who: Admin,
) -> dict:
    """Make a model version the one the controllers use from the next tick, retiring the one it
    replaces (admin only; audited with both versions). Rolling back is the same call on the old
    version."""
    model = commands.activate_model(s, who, version, reason)
    return _model(model, [])


@router.get(
    "/models/active/health",
    response_model=ModelHealth,
    tags=["models"],
    responses={**AUTH, **NOT_FOUND},
)
def active_model_health(request: Request, s: DB, _: Viewer, hours: Hours = 24.0) -> dict:
    """The active model's health, as ``GET /models/{version}/health`` (404 without one)."""
    model = s.scalar(select(PredictorModel).where(PredictorModel.state == "active"))
    if model is None:
        raise NotFoundError("no active model")
    return _health(request, s, model, hours)


@router.get(
    "/models/{version}/health",
    response_model=ModelHealth,
    tags=["models"],
    responses={**AUTH, **NOT_FOUND},
)
def get_model_health(
    version: Annotated[int, Path(ge=1, le=INT32_MAX), DIGITS_ONLY],
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
    return _health(request, s, model, hours)


def _health(request: Request, s, model: PredictorModel, hours: float) -> dict:
    cfg = settings(request)
    return model_health.model_health(s, model, hours, cfg.sampling_min, cfg.drift_factor)


def _model(m: PredictorModel, online: list) -> dict:
    return {
        "id": m.id,
        "version": m.version,
        "method": m.method,
        "rho": m.rho,
        "horizon": m.horizon,
        "sampling_min": m.sampling_min,
        "state": m.state,
        "active": m.active,
        "created_at": m.created_at,
        "validation_mae_per_step_c": model_health.validation_mae(m),
        "online_mae_per_step_c": online,
        "info": m.info or {},
    }
