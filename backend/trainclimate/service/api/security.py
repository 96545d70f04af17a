"""Authentication of HTTP requests: the bearer token read off ``Authorization: Bearer <token>``
and checked against the store (:mod:`trainclimate.service.store.tokens`, where tokens and roles
are kept) — 401 without a valid token, 403 with too low a role or, for a gateway token, a coach
outside its scope."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.security.utils import get_authorization_scheme_param
from pydantic import BaseModel, ValidationError

from trainclimate.service.store.db import Database
from trainclimate.service.store.tokens import GATEWAY, METRICS, Principal, authenticate

bearer = HTTPBearer(auto_error=False, description="a token from `trainclimate token create`")
Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]


def _principal(request: Request, credentials: HTTPAuthorizationCredentials | None) -> Principal:
    """Whose the request's token is (401 without a valid one)."""
    if credentials is None:
        raise HTTPException(401, "missing bearer token", {"WWW-Authenticate": "Bearer"})
    with request.app.state.db.sessions() as s:
        who = authenticate(s, credentials.credentials)
    if who is None:
        raise HTTPException(401, "invalid or revoked token", {"WWW-Authenticate": "Bearer"})
    return who


def valid_authorization(db: Database, authorization: str) -> bool:
    """Whether an ``Authorization`` header's value is ``Bearer <token>`` with a valid token, as
    :func:`_principal` reads it (the throttle's check of a blocked address's requests)."""
    scheme, token = get_authorization_scheme_param(authorization)
    if scheme.lower() != "bearer" or not token:
        return False
    with db.sessions() as s:
        return authenticate(s, token) is not None


def _too_low(role: str, who: Principal) -> HTTPException:
    return HTTPException(403, f"this needs the {role} role; the token is {who.role}")


def require(role: str) -> Callable[..., Principal]:
    """A dependency giving the caller's :class:`Principal` if the request's bearer token is valid
    and its role is ``role`` or above (else 401 or 403). A gateway token never passes it."""

    def check(request: Request, credentials: Credentials) -> Principal:
        who = _principal(request, credentials)
        if not who.can(role):
            raise _too_low(role, who)
        return who

    check.role = role  # read by the API reference (service/api/apidoc.py)
    return check


def require_coach(
    role: str, body: type[BaseModel] | None = None, field: str = "id"
) -> Callable[..., Principal]:
    """Like :func:`require` (``role`` or above passes), and a gateway token passes too when the
    coach the request names is in its scope: the path's ``coach_id``, or ``field`` of the JSON
    ``body`` (validated with that model first; a body that does not validate is left to the
    route's 422). Another coach, or a gateway token on a route without this check, is 403."""

    async def check(request: Request, credentials: Credentials) -> Principal:
        who = await run_in_threadpool(_principal, request, credentials)
        if who.role != GATEWAY:
            if not who.can(role):
                raise _too_low(role, who)
            return who
        if body is None:
            coach = request.path_params.get("coach_id")
        else:
            try:
                coach = getattr(body.model_validate(await request.json()), field)
            except (ValueError, ValidationError):  # not JSON, or not the route's body: 422 next
                return who
        if not isinstance(coach, str) or not who.serves(coach):
            raise HTTPException(403, f"this gateway token is not for coach {coach!r}")
        return who

    check.role = role  # read by the API reference (service/api/apidoc.py)
    check.gateway = True  # … which notes that a gateway token for the coach may call it too
    return check


def require_metrics() -> Callable[..., Principal]:
    """A dependency giving the caller's :class:`Principal` if the request's bearer token is a
    ``metrics`` token or a viewer's or above (else 401, or 403 for a gateway token)."""

    def check(request: Request, credentials: Credentials) -> Principal:
        who = _principal(request, credentials)
        if who.role == GATEWAY or not who.can(METRICS):
            raise _too_low(METRICS, who)
        return who

    check.role = METRICS  # read by the API reference (service/api/apidoc.py)
    return check
