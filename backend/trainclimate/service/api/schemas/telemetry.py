"""The live feed: a gateway's telemetry rows and batches (over HTTP and MQTT) and the
setpoint it pulls."""

from __future__ import annotations

import math
from datetime import UTC, datetime
from typing import Literal

from pydantic import AwareDatetime, BaseModel, Field, StrictBool, field_validator, model_validator

from trainclimate.service.api.schemas.base import Strict

Source = Literal["ddpc", "rule", "override", "fallback"]
Mode = Literal["regular", "slumber", "off"]

#: The most rows in one telemetry batch (``POST /api/v1/telemetry``, an MQTT message).
MAX_BATCH_ROWS = 10_000
EARLIEST_ROW = datetime(2000, 1, 1, tzinfo=UTC)


class TelemetryRow(Strict):
    """One minute of a coach's telemetry: the minute up to ``time``."""

    time: AwareDatetime = Field(examples=["2024-11-28T06:05:00Z"])
    t_room_c: list[float] = Field(min_length=3, max_length=3, examples=[[21.2, 21.0, 20.8]])
    t_ref_c: float = Field(ge=5, le=40, examples=[22.0])
    t_rule_c: float = Field(ge=5, le=40, examples=[22.0])
    t_amb_c: float = Field(ge=-50, le=60, examples=[1.5])
    ghi_w_m2: float | None = Field(default=None, ge=0, le=1500, examples=[120.0])
    q_gt_w_m2: float = Field(default=0.0, ge=0, le=1500, examples=[60.0])
    q_gs_w_m2: float = Field(default=0.0, ge=0, le=1500, examples=[40.0])
    occupancy_pct: float = Field(default=0.0, ge=0, le=300, examples=[35.0])
    speed_kmh: float = Field(default=0.0, ge=0, le=250, examples=[80.0])
    power_kw: float | None = Field(
        default=None,
        ge=0,
        le=200,
        examples=[9.5],
        description="the HVAC's electrical power, floor and wall heating included",
    )
    floor_power_kw: float | None = Field(
        default=None,
        ge=0,
        le=200,
        examples=[2.4],
        description="the floor and wall heating's share of power_kw, when the feed reports it: "
        "the HVAC units alone (the meter the savings headline uses) are the difference",
    )
    mode: Mode = Field(default="regular")
    connected: StrictBool = True

    @model_validator(mode="after")
    def _floor_within_power(self) -> TelemetryRow:
        if self.floor_power_kw is not None and (
            self.power_kw is None or self.floor_power_kw > self.power_kw + 1e-9
        ):
            raise ValueError("floor_power_kw is a share of power_kw: give both, floor ≤ total")
        return self

    @field_validator("time")
    @classmethod
    def _time(cls, v: datetime) -> datetime:
        try:
            v = v.astimezone(UTC)
        except OverflowError:
            raise ValueError("time out of range") from None
        if v < EARLIEST_ROW:
            raise ValueError("time before 2000")
        # a row ahead of the server's clock is refused when stored, and counted
        # (store.commands.Backfill: ahead_of_clock)
        return v

    @field_validator("t_room_c")
    @classmethod
    def _temps(cls, v: list[float]) -> list[float]:
        if any(not math.isfinite(x) or not -40 <= x <= 70 for x in v):
            raise ValueError("deck temperatures must be finite and within −40…70 °C")
        return v


class TelemetryBatch(Strict):
    """A gateway's batch for one coach (resending a batch changes nothing)."""

    coach_id: str = Field(examples=["124-A"])
    rows: list[TelemetryRow] = Field(min_length=1, max_length=MAX_BATCH_ROWS)


class TelemetryAccepted(BaseModel):
    received: int = Field(examples=[5])
    stored: int = Field(examples=[5])
    duplicates: int = Field(examples=[0])


class SetpointOut(BaseModel):
    """The setpoint a coach's gateway applies (the pull of the live feed)."""

    coach_id: str
    tick: datetime | None
    t_ref_c: float | None = Field(description="null: none issued; keep the HVAC's own T_rule")
    t_rule_c: float | None
    source: Source | None
    reason: str | None
    valid_until: datetime | None = Field(
        description="after this, without a newer setpoint, fall back to T_rule"
    )
