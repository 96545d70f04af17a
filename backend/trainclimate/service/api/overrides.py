"""Operator overrides of a coach's T_ref: set one, cancel the one in force, list them."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from sqlalchemy import select

from trainclimate.service.api.deps import AUTH, DB, NOT_FOUND, Operator, Viewer
from trainclimate.service.api.schemas.base import Message
from trainclimate.service.api.schemas.coaches import OverrideIn, OverrideOut
from trainclimate.service.store import commands, queries
from trainclimate.service.store.models import Override

router = APIRouter()


@router.post(
    "/coaches/{coach_id}/override",
    response_model=OverrideOut,
    status_code=201,
    tags=["overrides"],
    responses={**AUTH, **NOT_FOUND, 409: {"model": Message}},
)
def create_override(
    coach_id: str,
    body: OverrideIn,
    s: DB,
    who: Operator,
) -> dict:
    """Set T_ref for ``duration_min`` (within T_rule ± 2 K, like the driver's limit); audited."""
    o = commands.create_override(s, who, coach_id, body.t_ref_c, body.duration_min, body.reason)
    return _override(o, active=True)


@router.delete(
    "/coaches/{coach_id}/override",
    response_model=OverrideOut,
    tags=["overrides"],
    responses={**AUTH, **NOT_FOUND},
)
def cancel_override(
    coach_id: str,
    s: DB,
    who: Operator,
    reason: Annotated[str, Query(max_length=500)] = "cancelled by an operator",
) -> dict:
    """End the override in force; audited."""
    return _override(commands.cancel_override(s, who, coach_id, reason), active=False)


@router.get(
    "/coaches/{coach_id}/overrides",
    response_model=list[OverrideOut],
    tags=["overrides"],
    responses={**AUTH, **NOT_FOUND},
)
def list_overrides(coach_id: str, s: DB, _: Viewer) -> list:
    """The coach's overrides, newest first, with whether each is in force."""
    coach = queries.coach_or_404(s, coach_id)
    now = queries.fleet_clock(s, coach)
    rows = s.scalars(
        select(Override).where(Override.coach_id == coach.id).order_by(Override.created_at.desc())
    ).all()
    return [
        _override(o, now is not None and o.cancelled_at is None and o.starts_at <= now < o.ends_at)
        for o in rows
    ]


def _override(o: Override, active: bool) -> dict:
    return {
        "id": o.id,
        "coach_id": o.coach_id,
        "t_ref_c": o.t_ref_c,
        "starts_at": o.starts_at,
        "ends_at": o.ends_at,
        "reason": o.reason,
        "created_by": o.created_by,
        "cancelled_at": o.cancelled_at,
        "cancelled_by": o.cancelled_by,
        "active": active,
    }
