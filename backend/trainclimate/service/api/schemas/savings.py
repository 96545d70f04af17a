"""The savings figures: a train's pair comparison (windows, totals, trial estimate) and
the fleet summary."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

from trainclimate.service.api.schemas.coaches import CoachStatus
from trainclimate.service.api.schemas.trains import PLAN_DESCRIPTION, GuardFigures, Plan
from trainclimate.service.store.attention import KINDS

#: The meters energy is counted on: the HVAC units alone (heater, compressor, fans; what the
#: paper's loggers metered) and the whole coach (with the floor and wall heating).
Meter = Literal["hvac", "hvac_and_floor"]
METER_DESCRIPTION = (
    "the meter of the energies and savings: hvac (the HVAC units alone, when every counted "
    "minute splits the floor and wall heating off) or hvac_and_floor (the whole coach)"
)
BY_METER_DESCRIPTION = (
    "the savings on each meter; hvac is null when a counted minute does not split the floor "
    "heating off"
)


#: Why a window does not count towards the savings.
ExclusionReason = Literal[
    "disconnected",
    "override",
    "missing_data",
    "no_setpoint",
    "preparing",
    "fallback",
    "not_regular",
    "mixed_roles",
    "plan_switch",
    "reference",
]
Estimator = Literal["crossover", "fixed_reference", "fixed_naive"]


class WindowSavings(BaseModel):
    start: datetime
    activated: str | None = Field(
        description="the coach that ran under the layer (every tick a DDPC setpoint) while the "
        "other ran on T_rule; null when neither did"
    )
    energy_kwh: dict[str, float] = Field(description="each coach's energy in the window, kWh")
    energy_activated_kwh: float
    energy_deactivated_kwh: float
    savings_pct: float | None = Field(description="null where the window is excluded")
    excluded: bool
    excluded_reason: ExclusionReason | None = Field(
        description="why the window does not count: a coach disconnected, an override, data "
        "missing, no setpoint, the model being prepared, a DDPC fallback, the HVAC not in regular "
        "mode, roles mixed within the window, the lead-in after the activated coach changed, or a "
        "reference window (both coaches on T_rule: the coaches' own ratio)"
    )


class TrialDaysOut(BaseModel):
    coach_0: int = Field(description="service days with the pair's first coach activated")
    coach_1: int = Field(description="service days with the pair's second coach activated")
    reference: int = Field(description="service days with both coaches on T_rule")
    dropped: dict[str, int] = Field(description="days not used, by reason")


class TrialFigures(BaseModel):
    """A pair's saving with its uncertainty, from its service days."""

    estimator: Estimator | None = Field(
        description="crossover (each coach activated on some days: the coaches' difference "
        "cancels), fixed_reference (one coach activated, corrected by reference days) or "
        "fixed_naive (one coach activated: confounded with the coaches' difference, no interval)"
    )
    savings_pct: float | None = Field(
        description="the estimator's saving, %; null until a window counts"
    )
    savings_ci95_pct: list[float] | None = Field(
        description="[low, high], 95 % bootstrap-t interval over service days, %; null with "
        "savings_ci95_reason"
    )
    savings_ci95_reason: str | None
    naive_savings_pct: float | None = Field(
        description="100 (1 − E_act / E_deact) over the counted windows, the coaches' own "
        "difference included, %"
    )
    days: TrialDaysOut
    standard_error_pct: float | None = Field(description="the estimate's standard error, points")
    days_to_target: int | None = Field(
        description="further service days for the interval's half-width to reach ±2 points"
    )
    meets_guideline_14: bool | None = Field(
        description="ASHRAE Guideline 14: the savings' uncertainty at 68 % below 50 % of them"
    )
    distinguishable_from_zero: bool | None = Field(description="the interval excludes 0")


class SavingsFigures(BaseModel):
    """Savings and comfort of activated against deactivated coaches over the counted windows."""

    meter: Meter = Field(description=METER_DESCRIPTION)
    savings_by_meter_pct: dict[Meter, float | None] = Field(
        description=BY_METER_DESCRIPTION + "; energy over energy over the counted windows"
    )
    energy_activated_kwh: float
    energy_deactivated_kwh: float
    avg_hourly_violation_activated_k: float
    avg_hourly_violation_deactivated_k: float
    excluded_minutes: float = Field(description="the windows that do not count")
    counted_windows: int = Field(description="windows counted towards the savings")
    counted_hours: float = Field(description="the hours violation is averaged over")


class PairFigures(SavingsFigures, TrialFigures):
    """A pair's totals over its counted windows and its trial estimate."""

    excluded_minutes_by_reason: dict[ExclusionReason, float] = Field(
        description="the excluded windows' minutes by reason"
    )


class Comparison(PairFigures):
    """A train's pair over a range: windows, totals and the trial estimate."""

    train_id: str
    plan: Plan = Field(
        description="the trial plan in force at the range's end: " + PLAN_DESCRIPTION
    )
    coaches: list[str] = Field(description="the pair, ordered by id (coach 0, coach 1)")
    activated: str | None = Field(description="the coach activated now")
    deactivated: str | None = Field(description="the coach deactivated now")
    start: datetime
    end: datetime
    window_min: float
    windows: list[WindowSavings]
    avg_hourly_violation_k: float = Field(description="the activated coaches' (as above)")
    baseline_violation_k: float = Field(description="the deactivated coaches' (as above)")


class TrainSavings(PairFigures):
    """One train's pair over its window (as its pair comparison gives it)."""

    id: str
    name: str
    plan: Plan = Field(
        description="the trial plan in force at the range's end: " + PLAN_DESCRIPTION
    )
    coaches: list[str] = Field(description="the pair, ordered by id (coach 0, coach 1)")
    activated: str | None = Field(description="the coach activated now")
    deactivated: str | None = Field(description="the coach deactivated now")
    start: datetime = Field(description="the first counted window's start")
    end: datetime


class Attention(BaseModel):
    """A coach that needs an operator's attention, and why."""

    coach_id: str
    train_id: str
    kind: Literal[KINDS] = Field(
        description="the list is in this order; comfort: outside the comfort band for more "
        "than 30 min without a break"
    )
    status: CoachStatus
    reason: str | None = Field(
        description="the setpoint's reason code, or connection_lost (disconnected)"
    )
    detail: str
    figures: GuardFigures | None = Field(
        default=None, description="costing_energy: what the guard tripped on; else null"
    )


class FleetWindow(BaseModel):
    """One window's energy over the trains that count it (not excluded for them)."""

    start: datetime
    energy_activated_kwh: float
    energy_deactivated_kwh: float
    trains: int


class FleetSummary(SavingsFigures):
    """The fleet at a glance: its trains' figures pooled, per train, per window, by status,
    attention."""

    savings_pct: float | None = Field(
        description="the trains' trial estimates pooled (random effects), else the naive figure; "
        "null until a window counts, %"
    )
    savings_ci95_pct: list[float] | None = Field(
        description="[low, high], 95 % interval of the pooled estimate, %"
    )
    savings_ci95_reason: str | None
    estimator: Literal["random_effects", "naive"]
    standard_error_pct: float | None
    trains_pooled: int = Field(description="trains with an interval, pooled")
    trains_confounded: int = Field(description="trains on a fixed plan without reference days")
    naive_savings_pct: float | None = Field(
        description="100 (1 − ΣE_act / ΣE_deact) over every train's counted windows, %"
    )
    hours: float
    window_min: float
    trains: list[TrainSavings]
    windows: list[FleetWindow]
    coaches_by_status: dict[str, int] = Field(
        description="status → how many coaches have it (as the coaches list shows them)",
        examples=[{"ok": 18, "disconnected": 1, "inactive": 1}],
    )
    attention: list[Attention]
