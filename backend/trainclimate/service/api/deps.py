"""What the routes share: the request's transaction, the caller's role (or a gateway token's coach
scope), the settings, and the error answers they document."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import timedelta
from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from sqlalchemy.orm import Session

from trainclimate.service.api.schemas.base import Message
from trainclimate.service.api.schemas.coaches import CoachCreate
from trainclimate.service.api.schemas.telemetry import TelemetryBatch
from trainclimate.service.api.security import require, require_coach
from trainclimate.service.settings import Settings
from trainclimate.service.store.queries import RequestError
from trainclimate.service.store.tokens import Principal

#: A route's documented answers besides its success, as FastAPI's ``responses=`` takes them.
Responses = dict[int | str, dict[str, Any]]

UNAUTHORIZED: Responses = {401: {"model": Message, "description": "no valid token"}}
FORBIDDEN: Responses = {
    403: {
        "model": Message,
        "description": "the token's role is too low, or a gateway token is not for the coach "
        "or its train",
    }
}
NOT_FOUND: Responses = {404: {"model": Message, "description": "no such coach or train"}}
AUTH: Responses = {**UNAUTHORIZED, **FORBIDDEN}
CONFLICT: Responses = {409: {"model": Message, "description": "a conflict with the stored state"}}
#: The largest id, version or offset taken: the columns are 32-bit integers (a larger value
#: cannot exist, and PostgreSQL refuses to compare with it).
INT32_MAX = 2**31 - 1


def session(request: Request) -> Iterator[Session]:
    """One transaction per request: committed when the route returns, rolled back on error.
    Its scope is the route function (``DB``), so the commit happens before the response is
    sent: a commit that fails gives an error response, never a 2xx for a write not stored."""
    with request.app.state.db.transaction() as s:
        yield s


DB = Annotated[Session, Depends(session, scope="function")]
Viewer = Annotated[Principal, Depends(require("viewer"))]
Operator = Annotated[Principal, Depends(require("operator"))]
Admin = Annotated[Principal, Depends(require("admin"))]
#: The live feed's routes, which a gateway token scoped to the coach may call too (and only these):
#: registering a coach (the body's ``id``), pushing its telemetry (the body's ``coach_id``) and
#: pulling its setpoint (the path's ``coach_id``).
GatewayOrOperatorCoach = Annotated[Principal, Depends(require_coach("operator", CoachCreate, "id"))]
GatewayOrOperatorTelemetry = Annotated[
    Principal, Depends(require_coach("operator", TelemetryBatch, "coach_id"))
]
GatewayOrViewer = Annotated[Principal, Depends(require_coach("viewer"))]


def _query_names(dependant: Dependant) -> set[str]:
    """The query parameters ``dependant`` and its dependencies declare."""
    names = {p.alias for p in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _query_names(sub)
    return names


async def known_query_only(request: Request) -> None:
    """Refuse (422, one sentence) a query parameter the route does not declare: a misspelt
    ``strat=`` would otherwise be ignored, and the answer computed over a range the caller did
    not ask for. Async: it runs on the event loop, taking no worker thread."""
    route = request.scope.get("route")
    if not isinstance(route, APIRoute) or not request.query_params:
        return
    declared = _query_names(route.dependant)
    unknown = sorted(set(request.query_params) - declared)
    if unknown:
        allowed = ", ".join(sorted(declared)) or "none"
        raise RequestError(
            f"unknown query parameter {', '.join(unknown)} (this route takes: {allowed})"
        )


def settings(request: Request) -> Settings:
    """The running app's settings."""
    return request.app.state.settings


def period(request: Request) -> timedelta:
    """The controller's sampling period (``sampling_min`` of the settings)."""
    return timedelta(minutes=settings(request).sampling_min)
