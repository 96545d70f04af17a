"""A coach: what its layer does now, its registration, time series, setpoint history,
controller switch and overrides."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field, StrictBool, field_validator

from trainclimate.service.api.schemas.base import Strict
from trainclimate.service.api.schemas.telemetry import Source
from trainclimate.service.store.queries import STATUSES

#: A coach's status (:data:`trainclimate.service.store.queries.STATUSES`).
CoachStatus = Literal[STATUSES]
STATUS_HELP = (
    "ok (the DDPC step solved), warm-up (collecting the first hour of samples), stale (no "
    "telemetry in time), disconnected (the newest telemetry says the link to the HVAC is "
    "down: it holds T_rule, not the T_ref issued; reason connection_lost), fallback (T_rule; "
    "the reason says why), override (an operator's T_ref), inactive (the layer is off), "
    "not-regular (slumber or off), preparing (no predictor model yet) or no-data"
)

#: The shortest override: a shorter one would start and end at once, and still cancel the
#: override in force. [min]
MIN_OVERRIDE_MIN = 1.0


def _finite(value: float | None) -> float | None:
    if value is not None and not math.isfinite(value):
        raise ValueError("must be a finite number")
    return value


class ComfortNow(BaseModel):
    """A coach's decks against the comfort band T_rule ± comfort_band_k in its newest telemetry
    row (regular mode)."""

    in_band: bool = Field(description="every deck with a reading within the band")
    worst_excess_k: float = Field(
        ge=0,
        examples=[0.3],
        description="how far the worst deck lies outside the band (K); 0 within it",
    )
    decks_out: list[Literal["up", "mid", "low"]] = Field(
        examples=[["up"]], description="the decks outside the band"
    )


class CoachOut(BaseModel):
    """A coach and what its layer does now."""

    id: str = Field(examples=["D1-A"])
    train_id: str = Field(examples=["D1"])
    fleet: str = Field(examples=["demo"])
    ddpc_active: bool
    mode: str | None = Field(examples=["regular"], description="HVAC mode in the newest telemetry")
    status: CoachStatus = Field(examples=["ok"], description=STATUS_HELP)
    reason: str | None = Field(
        examples=["ok"],
        description="the newest setpoint's reason code; connection_lost when the newest "
        "telemetry says the link to the HVAC is down (status disconnected, or stale once "
        "nothing arrives since)",
    )
    t_rule_c: float | None = Field(examples=[22.0])
    t_ref_c: float | None = Field(
        examples=[21.0], description="the T_ref issued at the newest tick"
    )
    t_ref_applied: bool | None = Field(
        examples=[True],
        description="whether the coach's HVAC receives t_ref_c: false when the newest telemetry "
        "says the link is down (it holds T_rule, t_rule_c, instead); null when unknown (no "
        "T_ref issued, or no telemetry in time)",
    )
    t_room_c: list[float | None] | None = Field(
        examples=[[21.1, 21.0, 20.9]], description="deck temperatures up, mid, low (newest)"
    )
    comfort: ComfortNow | None = Field(
        description="the decks against the comfort band now (the newest telemetry row); null "
        "when unknown: no telemetry in time, no T_rule, no deck reading, or not in regular mode"
    )
    last_tick: datetime | None
    last_solve_ms: float | None = Field(examples=[0.09])
    override_until: datetime | None = None
    clock: datetime | None = Field(description="the coach's fleet clock")
    last_seen_at: datetime | None = Field(
        default=None,
        description="when its telemetry last arrived (wall time; live coaches: stale after two "
        "periods of the fleet clock's pace without)",
    )
    comfort_band_k: float = Field(
        examples=[1.0], description="the decks are to stay within T_rule ± this (K)"
    )
    setpoint_band_k: float = Field(
        examples=[2.0], description="T_ref and overrides stay within T_rule ± this (K)"
    )


class CoachCreate(Strict):
    """Register a coach (a gateway does it for its coaches; an existing one is left as it is)."""

    id: str = Field(min_length=1, max_length=32, pattern=r"^[A-Za-z0-9_.-]+$", examples=["124-A"])
    train_id: str = Field(
        min_length=1,
        max_length=32,
        pattern=r"^[A-Za-z0-9_.-]+$",
        description="fixed once the coach is registered; a gateway's: a new train or one of its "
        "coaches only",
        examples=["124"],
    )
    ddpc_active: StrictBool = Field(default=False, examples=[True])


class TimeSeries(BaseModel):
    """Equal-length arrays, oldest first."""

    time: list[datetime]
    t_room_c: list[list[float | None]] = Field(description="n × 3: up, mid, low")
    t_ref_c: list[float | None]
    t_rule_c: list[float | None]
    t_amb_c: list[float | None]
    ghi_w_m2: list[float | None]
    power_kw: list[float | None]
    floor_power_kw: list[float | None]
    occupancy_pct: list[float | None]
    speed_kmh: list[float | None]
    mode: list[str]
    connected: list[bool]
    source: list[Source | None] = Field(description="the source of the setpoint in force")


class SetpointHistory(BaseModel):
    tick: list[datetime]
    t_ref_c: list[float | None]
    t_rule_c: list[float | None]
    source: list[str]
    reason: list[str]
    solve_time_ms: list[float | None]
    predicted: list[dict | None] = Field(description="T_opt, the planned u and predicted y")


class OverrideIn(Strict):
    t_ref_c: float = Field(examples=[21.5], description="°C, within T_rule ± 2 K")
    duration_min: float = Field(ge=MIN_OVERRIDE_MIN, le=24 * 60, examples=[60], description="min")
    reason: str = Field(min_length=1, max_length=500, examples=["passengers report it is cold"])

    _check = field_validator("t_ref_c")(_finite)


class OverrideOut(BaseModel):
    id: int
    coach_id: str
    t_ref_c: float
    starts_at: datetime
    ends_at: datetime
    reason: str
    created_by: str
    cancelled_at: datetime | None
    cancelled_by: str | None
    active: bool


class ControllerChange(Strict):
    """Switch the DDPC layer on or off for a coach."""

    active: StrictBool = Field(examples=[False])
    reason: str = Field(min_length=1, max_length=500, examples=["maintenance of the HVAC"])
