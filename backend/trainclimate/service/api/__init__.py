"""The HTTP API (prefix ``/api/v1``): thin routes over :mod:`~trainclimate.service.store.queries`
and :mod:`~trainclimate.service.store.commands`, one router per resource.

Authentication: ``Authorization: Bearer <token>``; reads need ``viewer``, writes ``operator``,
user and model management ``admin``; 401 without a valid token, 403 with too low a role. Each
request that writes runs in one transaction.

- :mod:`.deps` — the request's transaction, the role dependencies, the settings, the documented
  error answers; :mod:`.security` — the bearer token's check;
- :mod:`.health`, :mod:`.metrics`, :mod:`.users`, :mod:`.coaches`, :mod:`.overrides`,
  :mod:`.trains`, :mod:`.fleet`, :mod:`.telemetry` (the live feed's push), :mod:`.models`,
  :mod:`.audit` — the routes;
- :mod:`.schemas` — the request and response bodies; :mod:`.apidoc` — ``docs/api.md``.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, status

from trainclimate.service.api import (
    audit,
    coaches,
    deps,
    fleet,
    health,
    metrics,
    models,
    overrides,
    telemetry,
    trains,
    users,
)
from trainclimate.service.store import commands, queries

#: Every route refuses a query parameter it does not declare (:func:`.deps.known_query_only`).
router = APIRouter(prefix="/api/v1", dependencies=[Depends(deps.known_query_only)])
router.include_router(health.router)
router.include_router(metrics.router)
router.include_router(users.router)
router.include_router(coaches.router)
router.include_router(overrides.router)
router.include_router(trains.router)
router.include_router(fleet.router)
router.include_router(telemetry.router)
router.include_router(models.router)
router.include_router(audit.router)

#: The store's errors as HTTP statuses (the app's exception handlers answer with them).
ERROR_STATUS = {
    queries.NotFoundError: status.HTTP_404_NOT_FOUND,
    commands.ForbiddenError: status.HTTP_403_FORBIDDEN,
    commands.ConflictError: status.HTTP_409_CONFLICT,
    queries.RequestError: status.HTTP_422_UNPROCESSABLE_CONTENT,
}
