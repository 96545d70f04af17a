"""The audit log: every override, layer switch, trial plan change, model activation and token
change, with who, when and why."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from sqlalchemy import select

from trainclimate.service.api.deps import AUTH, DB, INT32_MAX, Viewer
from trainclimate.service.api.schemas.base import DIGITS_ONLY
from trainclimate.service.api.schemas.users import AuditOut
from trainclimate.service.store.models import AuditLog

router = APIRouter()


@router.get("/audit", response_model=list[AuditOut], tags=["audit"], responses=AUTH)
def audit_log(
    s: DB,
    _: Viewer,
    limit: Annotated[int, Query(ge=1, le=1000), DIGITS_ONLY] = 100,
    offset: Annotated[int, Query(ge=0, le=INT32_MAX), DIGITS_ONLY] = 0,
    target: Annotated[str | None, Query(max_length=64)] = None,
) -> list:
    """The audit log, newest first."""
    q = select(AuditLog).order_by(AuditLog.id.desc()).limit(limit).offset(offset)
    if target:
        q = q.where(AuditLog.target == target)
    return [
        {
            "id": a.id,
            "time": a.time,
            "user": a.user_name,
            "role": a.role,
            "action": a.action,
            "target": a.target,
            "reason": a.reason,
            "detail": a.detail or {},
        }
        for a in s.scalars(q)
    ]
