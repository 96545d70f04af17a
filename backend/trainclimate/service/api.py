"""The HTTP API (prefix ``/api/v1``): thin routes over :mod:`.queries` and :mod:`.commands`.

Authentication: ``Authorization: Bearer <token>``; reads need ``viewer``, writes ``operator``,
user and model management ``admin``; 401 without a valid token, 403 with too low a role. Each
request that writes runs in one transaction.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import timedelta
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import AwareDatetime
from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate import __version__
from trainclimate.service import commands, queries, schemas
from trainclimate.service.models import (
    ApiToken,
    AuditLog,
    Coach,
    Override,
    PredictorModel,
    Train,
    User,
)
from trainclimate.service.security import Principal, authenticate

bearer = HTTPBearer(auto_error=False, description="a token from `trainclimate token create`")
router = APIRouter(prefix="/api/v1")

UNAUTHORIZED = {401: {"model": schemas.Message, "description": "no valid token"}}
FORBIDDEN = {403: {"model": schemas.Message, "description": "the token's role is too low"}}
NOT_FOUND = {404: {"model": schemas.Message, "description": "no such coach or train"}}
AUTH = {**UNAUTHORIZED, **FORBIDDEN}
#: The largest id, version or offset taken: the columns are 32-bit integers (a larger value
#: cannot exist, and PostgreSQL refuses to compare with it).
INT32_MAX = 2**31 - 1


def session(request: Request) -> Iterator[Session]:
    """One transaction per request: committed when the route returns, rolled back on error.
    Its scope is the route function (``DB``), so the commit happens before the response is
    sent: a commit that fails gives an error response, never a 2xx for a write not stored."""
    with request.app.state.db.transaction() as s:
        yield s


def require(role: str) -> Callable[..., Principal]:
    def check(
        request: Request,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
    ) -> Principal:
        if credentials is None:
            raise HTTPException(401, "missing bearer token", {"WWW-Authenticate": "Bearer"})
        with request.app.state.db.sessions() as s:
            who = authenticate(s, credentials.credentials)
        if who is None:
            raise HTTPException(401, "invalid or revoked token", {"WWW-Authenticate": "Bearer"})
        if not who.can(role):
            raise HTTPException(403, f"this needs the {role} role; the token is {who.role}")
        return who

    check.role = role  # read by the API reference (service/apidoc.py)
    return check


DB = Annotated[Session, Depends(session, scope="function")]
Viewer = Annotated[Principal, Depends(require("viewer"))]
Operator = Annotated[Principal, Depends(require("operator"))]
Admin = Annotated[Principal, Depends(require("admin"))]


def settings(request: Request):
    return request.app.state.settings


def _period(request: Request) -> timedelta:
    return timedelta(minutes=settings(request).sampling_min)


# --- health ----------------------------------------------------------------------------------
@router.get("/health", response_model=schemas.Health, tags=["health"])
def health(request: Request) -> dict:
    """Liveness, without authentication, and what the service is still preparing (e.g. the
    predictor model, with how far it is)."""
    status = request.app.state.preparation.status
    preparing = [status] if status.state != "done" else []
    return {
        "status": "ok",
        "version": __version__,
        "database": request.app.state.db.dialect,
        "preparing": preparing,
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


# --- coaches and trains ----------------------------------------------------------------------
@router.get("/me", response_model=schemas.Me, tags=["users"], responses=UNAUTHORIZED)
def me(who: Viewer) -> dict:
    """Who the token belongs to and its role (the dashboard shows write controls by it)."""
    return {"name": who.name, "role": who.role}


@router.get("/coaches", response_model=list[schemas.CoachOut], tags=["coaches"], responses=AUTH)
def list_coaches(request: Request, s: DB, _: Viewer) -> list:
    """Every coach with its train, layer, status (ok, warm-up, stale, fallback, override,
    inactive, not-regular, no-data), latest readings and setpoint."""
    cfg = settings(request)
    coaches = s.scalars(select(Coach).order_by(Coach.id)).all()
    return [queries.coach_view(s, c, _period(request), cfg.stale_periods) for c in coaches]


@router.post(
    "/coaches",
    response_model=schemas.CoachOut,
    tags=["coaches"],
    status_code=201,
    responses={**AUTH, 200: {"model": schemas.CoachOut}, 409: {"model": schemas.Message}},
)
def register_coach(
    body: schemas.CoachCreate,
    request: Request,
    response: Response,
    s: DB,
    who: Operator,
) -> dict:
    """Register a live coach (and its train); an existing coach is returned as it is (200)."""
    coach, created = commands.register_coach(s, who, body.id, body.train_id, body.ddpc_active)
    if not created:
        response.status_code = 200
    s.flush()
    return queries.coach_view(s, coach, _period(request), settings(request).stale_periods)


@router.get(
    "/coaches/{coach_id}",
    response_model=schemas.CoachOut,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def get_coach(coach_id: str, request: Request, s: DB, _: Viewer):
    """One coach, as in the list."""
    coach = queries.coach_or_404(s, coach_id)
    return queries.coach_view(s, coach, _period(request), settings(request).stale_periods)


@router.get(
    "/coaches/{coach_id}/timeseries",
    response_model=schemas.TimeSeries,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def coach_timeseries(
    coach_id: str,
    s: DB,
    _: Viewer,
    start: Annotated[AwareDatetime | None, Query(description="ISO 8601 with offset")] = None,
    end: Annotated[AwareDatetime | None, Query(description="default: the coach's clock")] = None,
) -> dict:
    """The coach's telemetry, default the last 24 h of its clock."""
    coach = queries.coach_or_404(s, coach_id)
    start, end = queries.time_range(s, coach, start, end)
    return queries.timeseries(s, coach, start, end)


@router.get(
    "/coaches/{coach_id}/setpoint",
    response_model=schemas.SetpointOut,
    tags=["live feed"],
    responses={**AUTH, **NOT_FOUND},
)
def coach_setpoint(coach_id: str, request: Request, s: DB, _: Viewer) -> dict:
    """The setpoint the coach's gateway should apply now (the live feed's pull)."""
    coach = queries.coach_or_404(s, coach_id)
    return queries.current_setpoint(s, coach, _period(request), settings(request).stale_periods)


@router.get(
    "/coaches/{coach_id}/setpoints",
    response_model=schemas.SetpointHistory,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def coach_setpoints(
    coach_id: str,
    s: DB,
    _: Viewer,
    start: AwareDatetime | None = None,
    end: AwareDatetime | None = None,
) -> dict:
    """Issued setpoints with their source, reason, solve time and predicted trajectory."""
    coach = queries.coach_or_404(s, coach_id)
    start, end = queries.time_range(s, coach, start, end)
    return queries.setpoint_history(s, coach, start, end)


@router.post(
    "/coaches/{coach_id}/override",
    response_model=schemas.OverrideOut,
    status_code=201,
    tags=["overrides"],
    responses={**AUTH, **NOT_FOUND, 409: {"model": schemas.Message}},
)
def create_override(
    coach_id: str,
    body: schemas.OverrideIn,
    s: DB,
    who: Operator,
) -> dict:
    """Set T_ref for ``duration_min`` (within T_rule ± 2 K, like the driver's limit); audited."""
    o = commands.create_override(s, who, coach_id, body.t_ref_c, body.duration_min, body.reason)
    return _override(o, active=True)


@router.delete(
    "/coaches/{coach_id}/override",
    response_model=schemas.OverrideOut,
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
    response_model=list[schemas.OverrideOut],
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


@router.put(
    "/coaches/{coach_id}/controller",
    response_model=schemas.CoachOut,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def set_controller(
    coach_id: str,
    body: schemas.ControllerChange,
    request: Request,
    s: DB,
    who: Operator,
) -> dict:
    """Switch the DDPC layer on or off for a coach; audited."""
    coach = commands.set_controller(s, who, coach_id, body.active, body.reason)
    request.app.state.scheduler.forget(coach.id)
    return queries.coach_view(s, coach, _period(request), settings(request).stale_periods)


@router.get("/trains", response_model=list[schemas.TrainOut], tags=["trains"], responses=AUTH)
def list_trains(s: DB, _: Viewer) -> list:
    """Every train with its activated and deactivated coaches."""
    return [_train(t) for t in s.scalars(select(Train).order_by(Train.id))]


@router.get(
    "/trains/{train_id}",
    response_model=schemas.TrainOut,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND},
)
def get_train(train_id: str, s: DB, _: Viewer) -> dict:
    """One train with its activated and deactivated coaches."""
    return _train(queries.train_or_404(s, train_id))


def _train(t: Train) -> dict:
    return {
        "id": t.id,
        "name": t.name,
        "coaches": [c.id for c in t.coaches],
        "activated": [c.id for c in t.coaches if c.ddpc_active],
        "deactivated": [c.id for c in t.coaches if not c.ddpc_active],
    }


@router.get(
    "/trains/{train_id}/comparison",
    response_model=schemas.Comparison,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND},
)
def train_comparison(
    train_id: str,
    s: DB,
    _: Viewer,
    start: AwareDatetime | None = None,
    end: AwareDatetime | None = None,
    window_min: Annotated[float, Query(gt=0, le=24 * 60)] = 30.0,
) -> dict:
    """Activated vs deactivated coach: energy and savings per window (30 min by default),
    overall savings, average hourly violation of both, excluded minutes."""
    train = queries.train_or_404(s, train_id)
    act, _deact = queries.pair_of(train)
    start, end = queries.time_range(s, act, start, end)
    return queries.comparison(s, train, start, end, window_min)


# --- the live feed ---------------------------------------------------------------------------
@router.post(
    "/telemetry",
    response_model=schemas.TelemetryAccepted,
    tags=["live feed"],
    responses={**AUTH, **NOT_FOUND},
)
def post_telemetry(batch: schemas.TelemetryBatch, s: DB, _: Operator) -> dict:
    """A gateway's batch of 1-minute rows for one coach; rows already stored are skipped."""
    rows = [_telemetry_row(r) for r in batch.rows]
    stored, dup = commands.ingest(s, batch.coach_id, rows)
    return {"received": len(rows), "stored": stored, "duplicates": dup}


def _telemetry_row(r: schemas.TelemetryRow) -> dict:
    up, mid, low = r.t_room_c
    return {
        "time": r.time,
        "t_room_up_c": up,
        "t_room_mid_c": mid,
        "t_room_low_c": low,
        "t_ref_c": r.t_ref_c,
        "t_rule_c": r.t_rule_c,
        "t_amb_c": r.t_amb_c,
        "ghi_w_m2": r.ghi_w_m2,
        "q_gt_w_m2": r.q_gt_w_m2,
        "q_gs_w_m2": r.q_gs_w_m2,
        "occupancy_pct": r.occupancy_pct,
        "speed_kmh": r.speed_kmh,
        "power_kw": r.power_kw,
        "mode": r.mode,
        "connected": r.connected,
    }


# --- models, audit, tokens -------------------------------------------------------------------
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


@router.get("/audit", response_model=list[schemas.AuditOut], tags=["audit"], responses=AUTH)
def audit_log(
    s: DB,
    _: Viewer,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=INT32_MAX)] = 0,
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


@router.post(
    "/tokens", response_model=schemas.TokenOut, status_code=201, tags=["users"], responses=AUTH
)
def create_token(body: schemas.TokenIn, s: DB, who: Admin) -> dict:
    """A new token (shown once) for a user, created with the role if new; audited."""
    token, user = commands.issue_token(s, who, body.role, body.name)
    return {"token": token, "name": user.name, "role": user.role}


@router.get("/tokens", response_model=list[schemas.TokenInfo], tags=["users"], responses=AUTH)
def list_tokens(s: DB, _: Admin) -> list:
    """Every token (its prefix only), its user, role and whether it is revoked."""
    rows = s.execute(select(ApiToken, User).join(User).order_by(ApiToken.id)).all()
    return [
        {
            "id": t.id,
            "user": u.name,
            "role": u.role,
            "prefix": t.prefix,
            "created_at": t.created_at,
            "revoked_at": t.revoked_at,
        }
        for t, u in rows
    ]


@router.delete(
    "/tokens/{token_id}",
    response_model=schemas.TokenInfo,
    tags=["users"],
    responses={**AUTH, **NOT_FOUND},
)
def revoke_token(token_id: Annotated[int, Path(ge=1, le=INT32_MAX)], s: DB, who: Admin):
    """Revoke a token: it no longer authenticates; audited."""
    t = commands.revoke_token(s, who, token_id)
    user = s.get(User, t.user_id)
    return {
        "id": t.id,
        "user": user.name,
        "role": user.role,
        "prefix": t.prefix,
        "created_at": t.created_at,
        "revoked_at": t.revoked_at,
    }


ERROR_STATUS = {
    queries.NotFoundError: status.HTTP_404_NOT_FOUND,
    commands.ConflictError: status.HTTP_409_CONFLICT,
    queries.RequestError: status.HTTP_422_UNPROCESSABLE_CONTENT,
}
