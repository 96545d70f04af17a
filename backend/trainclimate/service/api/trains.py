"""Trains: the list, one train with its activated and deactivated coaches and its trial plan, the
plan itself (read and changed), and the pair's activated-vs-deactivated comparison (kept in the
read cache while its data is unchanged)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from pydantic import AwareDatetime
from sqlalchemy import select

from trainclimate.service import exports
from trainclimate.service.api.deps import AUTH, CONFLICT, DB, NOT_FOUND, Operator, Viewer
from trainclimate.service.api.schemas.base import DIGITS_ONLY
from trainclimate.service.api.schemas.savings import Comparison
from trainclimate.service.api.schemas.trains import (
    GuardOut,
    GuardReset,
    PlanIn,
    TrainOut,
    TrainPlanOut,
)
from trainclimate.service.store import commands, comparison, guard, plans, queries
from trainclimate.service.store.models import Train

router = APIRouter()
#: The comparison's window, whole minutes: at least the controller's period (a shorter one has
#: no setpoint of its own and multiplies the work), at most a day. [min]
WINDOW_MIN = (5, 24 * 60)


@router.get("/trains", response_model=list[TrainOut], tags=["trains"], responses=AUTH)
def list_trains(s: DB, _: Viewer) -> list:
    """Every train with its activated and deactivated coaches and its trial plan."""
    trains = s.scalars(select(Train).order_by(Train.id)).all()
    names = plans.names_in_force(s, trains)
    return [_train(t, names[t.id]) for t in trains]


@router.get(
    "/trains/{train_id}",
    response_model=TrainOut,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND},
)
def get_train(train_id: str, s: DB, _: Viewer) -> dict:
    """One train with its activated and deactivated coaches and its trial plan."""
    train = queries.train_or_404(s, train_id)
    return _train(train, plans.names_in_force(s, [train])[train.id])


def _train(t: Train, plan: str) -> dict:
    return {
        "id": t.id,
        "name": t.name,
        "coaches": [c.id for c in t.coaches],
        "activated": [c.id for c in t.coaches if c.ddpc_active],
        "deactivated": [c.id for c in t.coaches if not c.ddpc_active],
        "plan": plan,
    }


@router.get(
    "/trains/{train_id}/plan",
    response_model=TrainPlanOut,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND},
)
def get_plan(train_id: str, s: DB, _: Viewer) -> dict:
    """The train's trial plan: the one in force at its fleet clock (fixed when none was set), a
    change pending, the coach running the layer today, when the next service day starts, and
    the recent changes."""
    return plans.view(s, queries.train_or_404(s, train_id))


@router.put(
    "/trains/{train_id}/plan",
    response_model=TrainPlanOut,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND, **CONFLICT},
)
def set_plan(train_id: str, body: PlanIn, s: DB, who: Operator) -> dict:
    """Change the train's trial plan; audited. On a train that reports telemetry it takes effect
    at the next switch hour of its fleet clock, never mid-day (``pending`` and ``message`` say
    when); on one that has reported nothing yet, at once. It replaces a change still pending.
    409 for a plan other than fixed on a train without a pair of two coaches."""
    return commands.set_plan(s, who, train_id, body.plan, body.switch_hour, body.seed, body.reason)


@router.get(
    "/trains/{train_id}/guard",
    response_model=GuardOut,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND},
)
def get_guard(train_id: str, s: DB, _: Viewer) -> dict:
    """The train's guard: once per service day it reads the pair's trial estimate, and after
    ``guard_days`` consecutive days with its 95 % interval entirely below 0 it hands every
    coach of the train back to T_rule (reason ``costing_energy``) until an operator
    re-enables the layer."""
    return guard.view(s, queries.train_or_404(s, train_id).id)


@router.post(
    "/trains/{train_id}/guard/reset",
    response_model=GuardOut,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND, **CONFLICT},
)
def reset_guard(train_id: str, body: GuardReset, s: DB, who: Operator) -> dict:
    """Re-enable the layer on a train whose guard handed it back; audited. The guard watches
    again from the next tick, its estimate counting only windows from now on. 409 when the
    guard has not handed the layer back."""
    return commands.reset_guard(s, who, train_id, body.reason)


#: The comparison's window, whole minutes within :data:`WINDOW_MIN`.
WindowMin = Annotated[
    int,
    Query(ge=WINDOW_MIN[0], le=WINDOW_MIN[1], description="the window, whole minutes"),
    DIGITS_ONLY,
]


@router.get(
    "/trains/{train_id}/comparison",
    response_model=Comparison,
    tags=["trains"],
    responses={**AUTH, **NOT_FOUND},
)
def train_comparison(
    train_id: str,
    request: Request,
    s: DB,
    _: Viewer,
    start: AwareDatetime | None = None,
    end: AwareDatetime | None = None,
    window_min: WindowMin = 30,
) -> dict:
    """The train's pair: per window (30 min by default; whole minutes, 5 … 1440) the coach that
    ran the layer, the energies and the saving, or why the window does not count; the totals
    over the counted windows; the trial estimate over the range's service days — crossover when
    each coach had activated days (the coaches' own difference cancels), corrected by reference
    days, or the naive figure labelled as confounded — with its 95 % bootstrap interval, the days
    still needed for ±2 points and ASHRAE Guideline 14's criterion."""
    train = queries.train_or_404(s, train_id)
    c0, _c1 = queries.pair_or_422(train)
    start, end = queries.time_range(s, c0, start, end)
    return request.app.state.read_cache.get(
        ("comparison", train.id, start, end, window_min),
        comparison.comparison_state(s, train, start, end, window_min),
        lambda: comparison.comparison(s, train, start, end, window_min),
    )


@router.get(
    "/trains/{train_id}/comparison.csv",
    response_class=Response,
    tags=["trains"],
    responses={**exports.CSV_RESPONSE, **AUTH, **NOT_FOUND},
)
def train_comparison_csv(
    train_id: str,
    request: Request,
    s: DB,
    who: Viewer,
    start: AwareDatetime | None = None,
    end: AwareDatetime | None = None,
    window_min: WindowMin = 30,
) -> Response:
    """The pair comparison's windows as CSV (``text/csv``), the same figures as
    ``GET /trains/{train_id}/comparison`` over the same range: per window its start and end
    (UTC, fleet clock), the coach under the layer, each coach's energy, the saving and why the
    window is excluded."""
    cmp = train_comparison(train_id, request, s, who, start, end, window_min)
    return exports.response(exports.comparison_csv(cmp), "comparison", train_id)
