"""The fleet at a glance: savings, comfort, coaches by status and what needs attention
(:mod:`trainclimate.service.store.fleet_summary`)."""

from __future__ import annotations

from datetime import timedelta
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from pydantic import AwareDatetime

from trainclimate.service import exports
from trainclimate.service.api.coaches import current_views
from trainclimate.service.api.deps import AUTH, DB, Viewer
from trainclimate.service.api.schemas.base import DIGITS_ONLY
from trainclimate.service.api.schemas.savings import FleetSummary
from trainclimate.service.store import fleet_summary, queries

router = APIRouter()
#: The summary's window up to its end, whole hours 1 … 744 (31 days): its windows are 30
#: minutes, and a float let 5e-324 hours through.
Hours = Annotated[
    int, Query(ge=1, le=744, description="the window, whole hours (1 … 744)"), DIGITS_ONLY
]


@router.get("/fleet/summary", response_model=FleetSummary, tags=["fleet"], responses=AUTH)
def get_fleet_summary(
    request: Request,
    s: DB,
    _: Viewer,
    hours: Hours = 24,
    end: Annotated[
        AwareDatetime | None, Query(description="default: each train's fleet clock")
    ] = None,
) -> dict:
    """Fleet savings and comfort over the last ``hours``, per train as its pair comparison gives
    them (windows counted only where one coach ran the layer and the other T_rule; each train's
    trial estimate with its 95 % interval), pooled over the trains with an interval (random
    effects) beside the naive energy-over-energy figure; the coaches by status; the coaches
    stale, disconnected, in fallback,
    overridden or outside the comfort band for more than 30 min."""
    if end is not None:
        queries.checked_range(end, None, timedelta(hours=hours))  # the API's bounds
    views = current_views(request, s)
    return fleet_summary.summary(s, views, hours, end, cache=request.app.state.read_cache)


@router.get(
    "/fleet/summary.csv",
    response_class=Response,
    tags=["fleet"],
    responses={**exports.CSV_RESPONSE, **AUTH},
)
def get_fleet_summary_csv(
    request: Request,
    s: DB,
    who: Viewer,
    hours: Hours = 24,
    end: Annotated[
        AwareDatetime | None, Query(description="default: each train's fleet clock")
    ] = None,
) -> Response:
    """The fleet summary per train as CSV (``text/csv``), the same figures as
    ``GET /fleet/summary``: each train's pair, range (UTC, fleet clock), savings with their
    95 % interval, energies, violations, excluded minutes and counted windows."""
    summary = get_fleet_summary(request, s, who, hours, end)
    return exports.response(exports.fleet_csv(summary), "fleet-summary", f"{hours}h")
