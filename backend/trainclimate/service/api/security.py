"""Authentication of HTTP requests: the bearer token read off ``Authorization: Bearer <token>``
and checked against the store (:mod:`trainclimate.service.store.tokens`, where tokens and roles
are kept) — 401 without a valid token, 403 with too low a role."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from trainclimate.service.store.tokens import Principal, authenticate

bearer = HTTPBearer(auto_error=False, description="a token from `trainclimate token create`")


def require(role: str) -> Callable[..., Principal]:
    """A dependency giving the caller's :class:`Principal` if the request's bearer token is valid
    and its role is ``role`` or above (else 401 or 403)."""

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

    check.role = role  # read by the API reference (service/api/apidoc.py)
    return check
