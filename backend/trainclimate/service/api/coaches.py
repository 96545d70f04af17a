"""Coaches: the fleet's list, one coach (each coach's view kept in the read cache while its data
is unchanged), registering a live coach, its time series, its setpoint now (the live feed's pull)
and its history, and switching the DDPC layer for it."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from pydantic import AwareDatetime
from sqlalchemy.orm import Session

from trainclimate.service import exports
from trainclimate.service.api.deps import (
    AUTH,
    DB,
    NOT_FOUND,
    GatewayOrOperatorCoach,
    GatewayOrViewer,
    Operator,
    Viewer,
    period,
    settings,
)
from trainclimate.service.api.schemas.base import Message
from trainclimate.service.api.schemas.coaches import (
    CoachCreate,
    CoachOut,
    ControllerChange,
    SetpointHistory,
    TimeSeries,
)
from trainclimate.service.api.schemas.telemetry import SetpointOut
from trainclimate.service.store import commands, queries, records
from trainclimate.service.store.models import Coach, utcnow

router = APIRouter()


@router.get("/coaches", response_model=list[CoachOut], tags=["coaches"], responses=AUTH)
def list_coaches(request: Request, s: DB, _: Viewer) -> list[records.CoachView]:
    """Every coach with its train, layer, status (ok, warm-up, stale, disconnected, fallback,
    override, inactive, not-regular, preparing, no-data), latest readings, whether its decks are
    within the comfort band now, and its setpoint (and whether the coach receives it)."""
    return current_views(request, s)


@router.post(
    "/coaches",
    response_model=CoachOut,
    tags=["coaches"],
    status_code=201,
    responses={**AUTH, 200: {"model": CoachOut}, 409: {"model": Message}},
)
def register_coach(
    body: CoachCreate,
    request: Request,
    response: Response,
    s: DB,
    who: GatewayOrOperatorCoach,
) -> records.CoachView:
    """Register a live coach (and its train); an existing coach is returned as it is (200). A
    coach's train is fixed when it is registered: another train for an existing coach is 409,
    whatever the role. A gateway token may register the coaches of its scope into its own trains
    only: a new train, or one whose coaches are all in its scope (else 403)."""
    coach, created = commands.register_coach(s, who, body.id, body.train_id, body.ddpc_active)
    if not created:
        response.status_code = 200
    s.flush()
    return queries.coach_view(s, coach, period(request), settings(request).stale_periods)


@router.get(
    "/coaches/{coach_id}",
    response_model=CoachOut,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def get_coach(coach_id: str, request: Request, s: DB, _: Viewer) -> records.CoachView:
    """One coach, as in the list."""
    return current_views(request, s, coach_id)[0]


def current_views(
    request: Request, s: Session, coach_id: str | None = None
) -> list[records.CoachView]:
    """Every coach's view (or only ``coach_id``'s: :class:`~.queries.NotFoundError` if there is
    none) as the fleet list and the fleet summary show it: from the read cache while its state
    (:func:`.queries.coach_states`) is unchanged, else computed from its coach row (those rows
    read together); with a live coach's silence judged now on its own clock
    (:func:`.queries.live_clocks`, :func:`.queries.with_liveness`)."""
    states = queries.coach_states(s, coach_id)
    cache = request.app.state.read_cache
    to_compute = [cid for cid, state in states if not cache.holds(("coach", cid), state)]
    coaches = queries.coach_rows(s, to_compute)
    clocks = queries.live_clocks(s)
    # read once: the fleet summary's list is 900 coaches
    stale_periods, tick_period = settings(request).stale_periods, period(request)
    now = utcnow()

    def view(cid: str, state: tuple) -> records.CoachView:
        found: records.CoachView = cache.get(
            ("coach", cid),
            state,
            lambda: queries.coach_view(
                s, coaches.get(cid) or s.get_one(Coach, cid), tick_period, stale_periods
            ),
        )
        clock, prior = clocks.get(cid), clocks.fleet_pace
        return queries.with_liveness(found, clock, now, tick_period, stale_periods, prior)

    return [view(cid, state) for cid, state in states]


@router.get(
    "/coaches/{coach_id}/timeseries",
    response_model=TimeSeries,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def coach_timeseries(
    coach_id: str,
    s: DB,
    _: Viewer,
    start: Annotated[AwareDatetime | None, Query(description="ISO 8601 with offset")] = None,
    end: Annotated[AwareDatetime | None, Query(description="default: the coach's clock")] = None,
) -> records.TimeSeries:
    """The coach's telemetry, default the last 24 h of its clock."""
    coach = queries.coach_or_404(s, coach_id)
    start, end = queries.time_range(s, coach, start, end)
    return queries.timeseries(s, coach, start, end)


@router.get(
    "/coaches/{coach_id}/timeseries.csv",
    response_class=Response,
    tags=["coaches"],
    responses={**exports.CSV_RESPONSE, **AUTH, **NOT_FOUND},
)
def coach_timeseries_csv(
    coach_id: str,
    s: DB,
    who: Viewer,
    start: Annotated[AwareDatetime | None, Query(description="ISO 8601 with offset")] = None,
    end: Annotated[AwareDatetime | None, Query(description="default: the coach's clock")] = None,
) -> Response:
    """The coach's telemetry as CSV (``text/csv``), the same rows as
    ``GET /coaches/{coach_id}/timeseries`` over the same range (default the last 24 h of its
    clock): one row a minute, times in UTC on the fleet clock, the decks split into columns."""
    ts = coach_timeseries(coach_id, s, who, start, end)
    return exports.response(exports.telemetry_csv(ts), "telemetry", coach_id)


@router.get(
    "/coaches/{coach_id}/setpoint",
    response_model=SetpointOut,
    tags=["live feed"],
    responses={**AUTH, **NOT_FOUND},
)
def coach_setpoint(
    coach_id: str, request: Request, s: DB, _: GatewayOrViewer
) -> records.SetpointView | records.NoSetpoint:
    """The setpoint the coach's gateway should apply now (the live feed's pull); a gateway token
    may pull it for the coaches of its scope."""
    coach = queries.coach_or_404(s, coach_id)
    return queries.current_setpoint(s, coach, period(request), settings(request).stale_periods)


@router.get(
    "/coaches/{coach_id}/setpoints",
    response_model=SetpointHistory,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def coach_setpoints(
    coach_id: str,
    s: DB,
    _: Viewer,
    start: AwareDatetime | None = None,
    end: AwareDatetime | None = None,
) -> records.SetpointHistory:
    """Issued setpoints with their source, reason, solve time and predicted trajectory."""
    coach = queries.coach_or_404(s, coach_id)
    start, end = queries.time_range(s, coach, start, end)
    return queries.setpoint_history(s, coach, start, end)


@router.put(
    "/coaches/{coach_id}/controller",
    response_model=CoachOut,
    tags=["coaches"],
    responses={**AUTH, **NOT_FOUND},
)
def set_controller(
    coach_id: str,
    body: ControllerChange,
    request: Request,
    s: DB,
    who: Operator,
) -> records.CoachView:
    """Switch the DDPC layer on or off for a coach; audited."""
    coach = commands.set_controller(s, who, coach_id, body.active, body.reason)
    request.app.state.scheduler.forget(coach.id)
    stale_periods = settings(request).stale_periods
    view = queries.coach_view(s, coach, period(request), stale_periods)
    clocks = queries.live_clocks(s)
    clock, prior = clocks.get(coach.id), clocks.fleet_pace
    return queries.with_liveness(view, clock, utcnow(), period(request), stale_periods, prior)
