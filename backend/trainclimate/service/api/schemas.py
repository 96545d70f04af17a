"""Request and response bodies of the HTTP API (pydantic), with the examples OpenAPI shows."""

from __future__ import annotations

import math
from datetime import UTC, date, datetime
from typing import Annotated, Literal

from pydantic import (
    AwareDatetime,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    field_validator,
    model_validator,
)

from trainclimate.service.store.attention import KINDS
from trainclimate.service.store.queries import STATUSES
from trainclimate.service.store.tokens import USER_NAME_MAX

Role = Literal["metrics", "gateway", "viewer", "operator", "admin"]
Source = Literal["ddpc", "rule", "override", "fallback"]
Mode = Literal["regular", "slumber", "off"]
#: A coach's status (:data:`trainclimate.service.store.queries.STATUSES`).
CoachStatus = Literal[STATUSES]
STATUS_HELP = (
    "ok (the DDPC step solved), warm-up (collecting the first hour of samples), stale (no "
    "telemetry in time), disconnected (the newest telemetry says the link to the HVAC is "
    "down: it holds T_rule, not the T_ref issued; reason connection_lost), fallback (T_rule; "
    "the reason says why), override (an operator's T_ref), inactive (the layer is off), "
    "not-regular (slumber or off), preparing (no predictor model yet) or no-data"
)

#: The trial plans (:data:`trainclimate.analysis.trial.PLANS`).
Plan = Literal["fixed", "alternate", "randomized", "reference"]
PLAN_DESCRIPTION = (
    "fixed (the layer stays on the coach operators activated), alternate (coach 0 and 1 by id on "
    "alternate service days), randomized (each coach one day of every two, the order drawn from "
    "the seed) or reference (neither: both on T_rule)"
)


#: The most rows in one telemetry batch (``POST /api/v1/telemetry``, an MQTT message).
MAX_BATCH_ROWS = 10_000
EARLIEST_ROW = datetime(2000, 1, 1, tzinfo=UTC)
#: The shortest life of an expiring token (a minute): one that expires before it can be used is
#: a mistake. [days]
MIN_EXPIRES_DAYS = 1 / 1440
#: The shortest override: a shorter one would start and end at once, and still cancel the
#: override in force. [min]
MIN_OVERRIDE_MIN = 1.0


def _storable(text: str, where: str) -> None:
    """ValueError unless ``text`` can be stored: no NUL character (PostgreSQL refuses it in
    text) and no lone surrogate (not UTF-8)."""
    if "\x00" in text:
        raise ValueError(f"{where}: must not contain a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError(f"{where}: must be valid Unicode (a lone surrogate is not)") from None


class Strict(BaseModel):
    """A request body: unknown fields are an error (a typo must not be silently ignored), and no
    string in it — a field's, or an item of a field's list — may hold a NUL character or a lone
    surrogate (422 on SQLite and PostgreSQL alike; a nested body checks its own). Its booleans
    are :class:`~pydantic.StrictBool` (``"yes"`` or ``0`` is no boolean)."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _storable_text(cls, data):
        if isinstance(data, dict):
            for key, value in data.items():
                if isinstance(value, str):
                    _storable(value, key)
                elif isinstance(value, list):
                    for item in value:
                        if isinstance(item, str):
                            _storable(item, key)
        return data


def _whole(value):
    """A path or query value as a whole number: digits only (``1.0``, ``+1``, ``1_0`` are not)."""
    if isinstance(value, str) and not (value.isascii() and value.isdigit()):
        raise ValueError("must be a whole number, digits only")
    return value


#: An integer path or query parameter is written in digits only (``/tokens/1.0`` is no token id):
#: ``Annotated[int, Path(ge=1), DIGITS_ONLY]`` — after the ``Path`` or ``Query``, whose bounds
#: then stay in the schema as its minimum and maximum.
DIGITS_ONLY = BeforeValidator(_whole)


def _finite(value: float | None) -> float | None:
    if value is not None and not math.isfinite(value):
        raise ValueError("must be a finite number")
    return value


class Preparing(BaseModel):
    """Work the service does in the background before it is fully itself."""

    task: str = Field(examples=["predictor model"])
    state: str = Field(examples=["running"], description="running, done or failed")
    stage: str = Field(examples=["fitting the predictor model"])
    percent: float = Field(examples=[40.0], description="0–100")
    detail: str = Field(examples=[""])


class MqttFeed(BaseModel):
    """The MQTT feed since the service started (``serve --mqtt``)."""

    broker: str = Field(examples=["mqtt://127.0.0.1:1883"])
    connected: bool
    connections: int = Field(description="successful connections (more than 1: reconnected)")
    messages: int = Field(description="telemetry messages handled (stored or dropped)")
    rows_stored: int
    duplicates: int = Field(description="rows already stored (a message delivered again)")
    dropped: dict[str, int] = Field(
        description="messages dropped, by reason: bad_topic, malformed_json, no_token, "
        "invalid_rows, coach_mismatch, revoked (the token unknown, revoked or expired), "
        "forbidden (the token not for the coach), unknown_coach, not_live, outside_horizon, "
        "ahead_of_clock",
        examples=[{"unknown_coach": 2}],
    )
    setpoints_published: int
    setpoints_expired: int = Field(
        default=0, description="setpoints not published: expired on their coach's clock"
    )
    confirmations_published: int = Field(description="batches confirmed to their gateway")
    database_retries: int
    last_error: str | None


class Storage(BaseModel):
    """Whether the database takes writes: ``error`` from the first write that failed for lack
    of storage (a full disk, an I/O error, a read-only file) until a write commits again."""

    state: Literal["ok", "error"] = Field(examples=["error"])
    detail: str | None = Field(default=None, examples=["database or disk is full"])
    since: datetime | None = Field(default=None, description="when the error first happened")


class Health(BaseModel):
    status: str = Field(examples=["ok"])
    version: str = Field(examples=["0.1.0"])
    database: str = Field(examples=["sqlite"])
    preparing: list[Preparing] = Field(
        description="background work still running or failed (empty when all is done); until "
        "the predictor model is ready the coaches run under T_rule"
    )
    telemetry_refused: dict[str, int] = Field(
        description="telemetry rows refused since start (HTTP and MQTT), by reason: "
        "outside_horizon (older than the coach's newest row less the backfill horizon), "
        "ahead_of_clock (more than max_ahead_min ahead of the server's clock)",
        examples=[{"outside_horizon": 1}],
    )
    mqtt: MqttFeed | None = Field(default=None, description="null without --mqtt")
    storage: Storage


class Ready(BaseModel):
    status: str = Field(examples=["ready"])
    replica: str = Field(examples=["backend-1:7"], description="this process (--replica-name)")
    migrations: str = Field(examples=["0003"])
    model_version: int | None = Field(examples=[1])
    under_rule: bool = Field(
        description="no model yet: the first one is being prepared and the coaches run under "
        "T_rule meanwhile"
    )
    loops_s: dict[str, float] = Field(
        description="seconds since each loop of this replica completed an iteration",
        examples=[{"live": 0.4, "demo": 0.1}],
    )
    storage: Storage


class NotReady(BaseModel):
    detail: str = Field(examples=["not ready: the live loop completed no iteration for 700 s"])
    reasons: list[str]
    storage: Storage | None = None


class ReplicaOut(BaseModel):
    replica: str = Field(examples=["backend-1:7"])
    this: bool = Field(description="the replica answering this request")
    coaches: list[str] = Field(description="the coaches it issued ticks to")
    ticks: int
    first_seen: datetime
    last_seen: datetime


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


class ModelOut(BaseModel):
    id: int
    version: int
    method: str
    rho: int
    horizon: int
    sampling_min: float | None
    state: str = Field(description="active (the controllers use it), candidate (predicting in "
                       "its shadow) or retired")  # fmt: skip
    active: bool = Field(description="state is active")
    created_at: datetime
    validation_mae_per_step_c: list[float] | None = Field(
        description="the validation MAE per step recorded with the model, °C"
    )
    online_mae_per_step_c: list[float | None] = Field(
        description="the active model's and a candidate's: its predictions' MAE per step over "
        "the 24 h up to its newest (GET /models/{version}/health), °C; empty without predictions "
        "and for a retired model (ask its health)"
    )
    info: dict = Field(description="training window and data hash, validation …")


class AuditOut(BaseModel):
    id: int
    time: datetime
    user: str
    role: str
    action: str
    target: str
    reason: str
    detail: dict


CoachIds = list[Annotated[str, Field(min_length=1, max_length=32, pattern=r"^[A-Za-z0-9_.-]+$")]]


class TokenIn(Strict):
    role: Role = Field(
        description="a new user's role; for an existing user, its own (another role is 409)"
    )
    name: str | None = Field(
        default=None,
        min_length=1,
        max_length=USER_NAME_MAX,
        description="the token's user, created if new (default: a new user named after the role)",
        examples=["alice"],
    )
    coaches: CoachIds | None = Field(
        default=None,
        min_length=1,
        max_length=1000,
        description="the coaches a gateway token is for: required with gateway, else refused",
        examples=[["124-A", "124-B"]],
    )

    @model_validator(mode="after")
    def _scope(self) -> TokenIn:
        if self.role == "gateway" and not self.coaches:
            raise ValueError("a gateway token needs coaches: the coach ids it is for")
        if self.role != "gateway" and self.coaches is not None:
            raise ValueError("coaches are for gateway tokens only")
        return self

    expires_in_days: float | None = Field(
        default=None,
        ge=MIN_EXPIRES_DAYS,
        le=3650,
        description="the token stops authenticating this many days after its creation, at "
        "least a minute (default: valid until revoked)",
        examples=[90],
    )


class TokenOut(BaseModel):
    token: str = Field(description="shown once; only its hash is stored")
    name: str = Field(description="the token's user")
    role: Role
    coaches: list[str] | None = Field(description="a gateway token's coaches; else null")
    expires_at: datetime | None = Field(description="null: it does not expire")
    mqtt_username: str | None = Field(
        default=None,
        description="with serve --mqtt-dynsec, a gateway token's own broker user (its password "
        "is the token); else null",
    )


class Me(BaseModel):
    name: str = Field(examples=["alice"])
    role: Role


class TokenInfo(BaseModel):
    id: int
    user: str = Field(description="the token's user")
    role: Role = Field(description="the role the token acts with")
    prefix: str
    coaches: list[str] | None = Field(description="a gateway token's coaches; else null")
    created_at: datetime
    expires_at: datetime | None = Field(description="null: it does not expire")
    revoked_at: datetime | None


class RoleChange(Strict):
    """A user's new role, for every token it holds."""

    role: Role = Field(
        examples=["operator"],
        description="viewer, operator or admin: a user neither becomes a gateway nor stops being "
        "one (409)",
    )
    reason: str = Field(min_length=1, max_length=500, examples=["runs the night shift now"])


class UserOut(BaseModel):
    name: str = Field(examples=["alice"])
    role: Role
    tokens: int = Field(description="its tokens not revoked: each acts with this role")


class Message(BaseModel):
    detail: str


class CoachHealth(BaseModel):
    coach_id: str
    first_step_mae_c: float | None = Field(
        description="°C, over its predictions and decks at step 1; null without a sample"
    )
    samples: int = Field(description="its (prediction, step, deck) triples with an actual")


class RetrainIn(Strict):
    reason: str = Field(min_length=1, max_length=500, examples=["the winter's first month"])
    days: float | None = Field(
        default=None,
        gt=0,
        le=366,
        description="the last N days (default: 28 without since; the window is at most 366)",
    )
    since: datetime | None = Field(default=None, description="telemetry from this time")
    coaches: CoachIds | None = Field(default=None, max_length=10_000)
    force: StrictBool = Field(
        default=False, description="register even a fit worse than the active"
    )


class RetrainStatus(BaseModel):
    state: str = Field(description="idle, running, done or failed")
    stage: str
    percent: float
    detail: str = Field(description="done: what was registered; failed: why nothing was")
    result: dict | None = Field(description="done: version, state, validation_mae_per_step_c …")
    requested_by: str | None
    reason: str | None


class ShadowBeside(BaseModel):
    mae_per_step_c: list[float | None] = Field(description="per step 1 … T, °C")
    samples: int
    predictions: int


class ModelHealth(BaseModel):
    """A predictor model's stored predictions against the telemetry that followed them: the
    predictions issued in (start, end], the ``hours`` up to the model's newest prediction tick
    (the data's clock); an actual is the row stamped t + k·Δ, left out when missing, not
    connected or not in regular mode."""

    version: int
    start: datetime | None = Field(description="null: the model never predicted")
    end: datetime | None = Field(description="the model's newest prediction tick")
    step_min: float = Field(examples=[5.0], description="Δ, the prediction step")
    bound_c: float = Field(examples=[0.25], description="the paper's bound on the predictor's MAE")
    predictions: int = Field(description="stored predictions in the window")
    samples: int = Field(description="the sum of samples_per_step")
    samples_per_step: list[int] = Field(
        description="per step 1 … T: the (prediction, deck) pairs with an actual"
    )
    mae_per_step_c: list[float | None] = Field(
        examples=[[0.12, 0.13, 0.13, 0.14, 0.14, 0.14]],
        description="per step 1 … T: the mean absolute error over every coach, prediction and "
        "deck with an actual, °C; null for a step without a sample; empty without predictions",
    )
    coaches: list[CoachHealth]
    exceeds_bound: bool = Field(description="the first-step MAE over all coaches exceeds bound_c")
    state: str = Field(description="active, candidate or retired")
    beside: ShadowBeside | None = Field(
        description="a candidate's: the issued setpoints' own predictions on the same coaches "
        "and ticks (the active model's at the time)"
    )
    validation_mae_per_step_c: list[float] | None = Field(
        description="the validation MAE per step recorded with the model, °C"
    )
    drift_factor: float = Field(description="the setting drift_factor")
    drift: bool = Field(
        description="the online MAE (mean over the steps) exceeds drift_factor × the validation "
        "MAE, or bound_c"
    )
    drift_reason: str | None = Field(description="why drift is flagged, in words")
