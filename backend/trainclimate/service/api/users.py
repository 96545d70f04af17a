"""Users and their tokens: who a token belongs to, creating, listing and revoking tokens, and
changing a user's role."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Path, Request
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from trainclimate.service.api.deps import (
    AUTH,
    CONFLICT,
    DB,
    INT32_MAX,
    NOT_FOUND,
    UNAUTHORIZED,
    Admin,
    Viewer,
)
from trainclimate.service.api.schemas.base import DIGITS_ONLY
from trainclimate.service.api.schemas.users import (
    Me,
    RoleChange,
    TokenIn,
    TokenInfo,
    TokenOut,
    UserOut,
)
from trainclimate.service.store import commands
from trainclimate.service.store.models import ApiToken, User
from trainclimate.service.store.tokens import USER_NAME_MAX

router = APIRouter()


@router.get("/me", response_model=Me, tags=["users"], responses=UNAUTHORIZED)
def me(who: Viewer) -> dict:
    """Who the token belongs to and its role (the dashboard shows write controls by it)."""
    return {"name": who.name, "role": who.role}


@router.post(
    "/tokens",
    response_model=TokenOut,
    status_code=201,
    tags=["users"],
    responses={**AUTH, **CONFLICT},
)
def create_token(body: TokenIn, s: DB, who: Admin, request: Request) -> dict:
    """A new token (shown once) for a user, created with the role if new. An existing user's
    token has the user's role: another role is 409, and no other token changes (a user's role
    changes only by ``PUT /users/{name}/role``). A gateway token is scoped to ``coaches`` (it may
    register them, push their telemetry and pull their setpoints, nothing else); audited with
    the role and scope. With ``serve --mqtt-dynsec`` a gateway token gets its own broker client
    (``mqtt_username``; 503 and no token if the broker does not create it)."""
    expires_at = None
    if body.expires_in_days is not None:
        expires_at = datetime.now(UTC) + timedelta(days=body.expires_in_days)
    token, user = commands.issue_token(s, who, body.role, body.name, body.coaches, expires_at)
    return {
        "token": token,
        "name": user.name,
        "role": user.role,
        "coaches": body.coaches,
        "expires_at": expires_at,
        "mqtt_username": _add_broker_client(request, s, token, body.coaches),
    }


def _add_broker_client(request: Request, s: Session, token: str, coaches: list[str] | None):
    """With ``--mqtt-dynsec``, a gateway token's broker client: its user name (else None; if the
    broker does not create it, 503 and the transaction rolls back)."""
    clients = request.app.state.broker_clients
    if clients is None or coaches is None:
        return None
    return clients.add(s, token, coaches)


@router.get("/tokens", response_model=list[TokenInfo], tags=["users"], responses=AUTH)
def list_tokens(s: DB, _: Admin) -> list:
    """Every token (its prefix only), its user, role, a gateway token's coaches, and whether it
    is revoked."""
    rows = s.execute(select(ApiToken, User).join(User).order_by(ApiToken.id)).all()
    return [_info(t, u) for t, u in rows]


@router.delete(
    "/tokens/{token_id}",
    response_model=TokenInfo,
    tags=["users"],
    responses={**AUTH, **NOT_FOUND},
)
def revoke_token(
    token_id: Annotated[int, Path(ge=1, le=INT32_MAX), DIGITS_ONLY],
    s: DB,
    who: Admin,
    request: Request,
):
    """Revoke a token: it no longer authenticates, over HTTP or MQTT; audited. With ``serve
    --mqtt-dynsec`` a gateway token's broker client is deleted and disconnected too (if the
    broker cannot be reached, by the next sweep)."""
    t = commands.revoke_token(s, who, token_id)
    clients = request.app.state.broker_clients
    if clients is not None and t.coaches is not None:
        clients.remove(token_id)
    return _info(t, s.get(User, t.user_id))


@router.put(
    "/users/{name}/role",
    response_model=UserOut,
    tags=["users"],
    responses={**AUTH, **NOT_FOUND, **CONFLICT},
)
def set_user_role(
    name: Annotated[str, Path(min_length=1, max_length=USER_NAME_MAX)],
    body: RoleChange,
    s: DB,
    who: Admin,
) -> dict:
    """Change a user's role: every token it holds acts with the new role from its next request.
    Audited as ``user.role`` with the role before and after; the role it has already changes
    nothing. 404 for an unknown user; 409 for a change to or from gateway (a gateway's tokens
    are scoped to its coaches: create tokens under another name)."""
    user = commands.set_user_role(s, who, name, body.role, body.reason)
    tokens = s.scalar(
        select(func.count(ApiToken.id)).where(
            ApiToken.user_id == user.id, ApiToken.revoked_at.is_(None)
        )
    )
    return {"name": user.name, "role": user.role, "tokens": tokens}


def _info(t: ApiToken, u: User) -> dict:
    """A token as listed: a token with a coach scope is a gateway's whatever its user's role."""
    return {
        "id": t.id,
        "user": u.name,
        "role": "gateway" if t.coaches is not None else u.role,
        "prefix": t.prefix,
        "coaches": t.coaches,
        "created_at": t.created_at,
        "expires_at": t.expires_at,
        "revoked_at": t.revoked_at,
    }
