"""Predictor models: the versions, and which one the controllers use."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query
from sqlalchemy import select

from trainclimate.service.api import schemas
from trainclimate.service.api.deps import AUTH, DB, INT32_MAX, NOT_FOUND, Admin, Viewer
from trainclimate.service.store import commands
from trainclimate.service.store.models import PredictorModel

router = APIRouter()


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
