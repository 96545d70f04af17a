"""A train: its coaches, its trial plan and its guard."""

from __future__ import annotations

from datetime import date, datetime
from typing import Literal

from pydantic import BaseModel, Field

from trainclimate.service.api.schemas.base import Strict

#: The trial plans (:data:`trainclimate.analysis.trial_plan.PLANS`).
Plan = Literal["fixed", "alternate", "randomized", "reference"]
PLAN_DESCRIPTION = (
    "fixed (the layer stays on the coach operators activated), alternate (coach 0 and 1 by id on "
    "alternate service days), randomized (each coach one day of every two, the order drawn from "
    "the seed) or reference (neither: both on T_rule)"
)


class TrainOut(BaseModel):
    id: str = Field(examples=["D1"])
    name: str = Field(examples=["parked outdoors in Zug"])
    coaches: list[str] = Field(examples=[["D1-A", "D1-B"]])
    activated: list[str] = Field(examples=[["D1-A"]])
    deactivated: list[str] = Field(examples=[["D1-B"]])
    plan: Plan = Field(description="the trial plan in force (GET /trains/{id}/plan)")


class PlanIn(Strict):
    """A train's new trial plan: in force from the next switch hour of its fleet clock (at once
    on a train that has reported no telemetry yet)."""

    plan: Plan = Field(examples=["alternate"], description=PLAN_DESCRIPTION)
    switch_hour: int = Field(
        default=3,
        ge=0,
        le=23,
        description="the local hour (Europe/Zurich) a service day starts at, when the trains "
        "stand in the depot",
    )
    seed: int = Field(default=0, ge=0, le=2**31 - 1, description="the randomized plan's seed")
    reason: str = Field(min_length=1, max_length=500, examples=["a crossover trial for a month"])


class PlanChange(BaseModel):
    """A trial plan as set: what, from when, who and why."""

    plan: Plan
    switch_hour: int = Field(description="local hour a service day starts at, 0–23")
    seed: int
    reason: str | None = Field(description="null: no plan set (fixed)")
    effective_from: datetime | None = Field(description="null: no plan set (fixed)")
    created_by: str | None
    created_at: datetime | None = Field(description="when it was set (wall time)")


class TrainPlanOut(PlanChange):
    """A train's trial plan: the one in force at its fleet clock, the change pending, today's
    activated coach and the recent changes."""

    train_id: str
    pending: PlanChange | None = Field(description="a change not in force yet, or null")
    service_day: date = Field(description="today's service day (the local date it started on)")
    activated_today: str | None = Field(
        description="the coach running the layer today (as stored once the scheduler applied "
        "the day); null: neither (reference), or not exactly one under fixed"
    )
    clock: datetime = Field(description="the train's fleet clock")
    next_switch: datetime = Field(description="when the next service day starts")
    history: list[PlanChange] = Field(description="the changes, newest first (at most 20)")
    message: str = Field(description="the plan in words; after a change, what it does and when")


class GuardFigures(BaseModel):
    """A guard's daily evaluation: the pair's trial estimate over the range it covered."""

    savings_pct: float | None = Field(description="the trial estimate (negative: costs energy)")
    savings_ci95_pct: list[float] | None = Field(description="[low, high], or null")
    savings_ci95_reason: str | None
    estimator: str | None
    days: int = Field(description="the service days the estimate used")
    start: datetime
    end: datetime


class GuardOut(BaseModel):
    """A train's guard: whether its pair's own trial has handed the layer back to T_rule."""

    train_id: str
    state: Literal["watching", "tripped"] = Field(
        description="tripped: every coach of the train whose layer is on runs T_rule "
        "(reason costing_energy) until an operator re-enables it"
    )
    checked_day: date | None = Field(description="the service day last evaluated")
    below_days: int = Field(description="consecutive evaluations with the interval below 0")
    figures: GuardFigures | None = Field(description="the last evaluation, or null")
    tripped_at: datetime | None
    coach_id: str | None = Field(description="the coach the layer was on when it tripped")
    counts_from: datetime | None = Field(description="the estimate counts windows from here")
    reset_by: str | None
    reset_at: datetime | None


class GuardReset(Strict):
    """Re-enable the layer on a train whose guard handed it back."""

    reason: str = Field(min_length=1, max_length=500, examples=["the HVAC unit was repaired"])
