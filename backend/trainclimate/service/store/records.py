"""The records the store hands across its seams, as typed dicts: a telemetry row as ingest stores
it, and the views the API reads (:mod:`.queries`, :mod:`.comfort`), which the API's schemas
(:mod:`trainclimate.service.api.schemas`) validate into JSON.

Typed dicts, not classes: the very dicts the code passes go into the database, the JSON and the
CSV exports; only the type checker reads the types. The module imports nothing of the package, so
any module of the service may name them. Its annotations are evaluated (no postponed
annotations), so the classes know at run time which keys are required, as the type checker does.
"""

from datetime import datetime
from typing import Required, TypedDict


class TelemetryRecord(TypedDict, total=False):
    """One coach's telemetry row as ingest stores it (a :class:`~.models.Telemetry` row without
    its coach): the minute (time − 1 min, time] as an onboard logger's 1-minute averages
    (:mod:`.telemetry`). ``time`` and the decks are always there; a field the feed does not
    report may be left out (a feed without the floor heating's share), a value not measured is
    None. The same row on the wire (``POST /api/v1/telemetry``, MQTT) is
    :class:`~trainclimate.service.api.schemas.telemetry.TelemetryRow`:
    :func:`.telemetry.from_wire` and :func:`.telemetry.to_wire` convert."""

    # The minute's end (timezone-aware).
    time: Required[datetime]
    # The decks' mean temperatures, up, mid and low. [°C]
    t_room_up_c: Required[float | None]
    t_room_mid_c: Required[float | None]
    t_room_low_c: Required[float | None]
    # The T_ref applied and the rule-based setpoint T_rule. [°C]
    t_ref_c: float | None
    t_rule_c: float | None
    # The ambient temperature. [°C]
    t_amb_c: float | None
    # The global horizontal irradiance and the roof's and the sides' irradiance Q_Gt, Q_Gs.
    # [W/m²]
    ghi_w_m2: float | None
    q_gt_w_m2: float | None
    q_gs_w_m2: float | None
    # Occupancy [%] and speed [km/h].
    occupancy_pct: float | None
    speed_kmh: float | None
    # The HVAC's power, the floor and wall heating included, and the floor and wall heating's
    # share of it. [kW]
    power_kw: float | None
    floor_power_kw: float | None
    # The HVAC mode, of :data:`.models.MODES` (left out: ``regular``).
    mode: str
    # Whether the link to the HVAC was up (left out: True).
    connected: bool


class ComfortNow(TypedDict):
    """Whether a coach's decks are within the comfort band now (:func:`.comfort.comfort_now`)."""

    # Every deck with a reading within T_rule ± T_max.
    in_band: bool
    # How far the worst deck lies outside the band (0 when all are within). [K]
    worst_excess_k: float
    # The decks outside, of :data:`.comfort.DECK_NAMES`.
    decks_out: list[str]


class CoachView(TypedDict):
    """A coach as the fleet list shows it (:func:`.queries.coach_view`, a live coach's silence
    judged by :func:`.queries.with_liveness`): the fields of the API's ``CoachOut``."""

    id: str
    train_id: str
    # ``demo`` or ``live``.
    fleet: str
    ddpc_active: bool
    # The HVAC mode of the newest telemetry row (None: no row).
    mode: str | None
    # One of :data:`.queries.STATUSES`.
    status: str
    # The newest setpoint's reason, or :data:`.queries.CONNECTION_LOST` (None: no setpoint).
    reason: str | None
    # T_rule: the newest setpoint's, else the newest row's. [°C]
    t_rule_c: float | None
    # The T_ref issued at the newest tick. [°C]
    t_ref_c: float | None
    # Whether the coach's HVAC receives that T_ref (None: unknown).
    t_ref_applied: bool | None
    # The comfort band's half-width T_max and the setpoint band's, around T_rule. [K]
    comfort_band_k: float
    setpoint_band_k: float
    # The newest row's decks, up, mid and low (None: no row). [°C]
    t_room_c: list[float | None] | None
    # The decks against the comfort band now (None: unknown).
    comfort: ComfortNow | None
    # The newest tick and its solve time [ms].
    last_tick: datetime | None
    last_solve_ms: float | None
    # When the override in force ends (None: none in force).
    override_until: datetime | None
    # The coach's clock: its fleet's simulated time, or a live coach's newest row time.
    clock: datetime | None
    # When a live coach's telemetry last arrived (wall time; None: never, or not live).
    last_seen_at: datetime | None


class SetpointView(TypedDict):
    """What a coach's gateway is told of a setpoint issued to it (:func:`.queries.setpoint_view`:
    ``GET /coaches/{id}/setpoint`` and the coach's MQTT setpoint topic)."""

    coach_id: str
    tick: datetime
    # The T_ref to apply and the T_rule it was decided against. [°C]
    t_ref_c: float | None
    t_rule_c: float | None
    # Of :data:`.models.SOURCES`, and why.
    source: str
    reason: str
    # The setpoint holds until then on the coach's clock.
    valid_until: datetime


class NoSetpoint(TypedDict):
    """What a coach's gateway is told while no setpoint is valid (none issued yet, or the newest
    expired: :func:`.queries.current_setpoint`): nothing but its coach, so it keeps its HVAC's
    T_rule."""

    coach_id: str
    tick: None
    t_ref_c: None
    t_rule_c: None
    source: None
    reason: None
    valid_until: None


class TimeSeries(TypedDict):
    """A coach's telemetry over a range, one list per field, a value per row (oldest first;
    None where not measured): :func:`.queries.timeseries`."""

    # Each row's minute end.
    time: list[datetime]
    # n × 3 deck temperatures: up, mid, low. [°C]
    t_room_c: list[list[float | None]]
    # T_ref applied, T_rule and the ambient temperature. [°C]
    t_ref_c: list[float | None]
    t_rule_c: list[float | None]
    t_amb_c: list[float | None]
    # Global horizontal irradiance. [W/m²]
    ghi_w_m2: list[float | None]
    # HVAC power and the floor and wall heating's share of it. [kW]
    power_kw: list[float | None]
    floor_power_kw: list[float | None]
    # Occupancy [%] and speed [km/h].
    occupancy_pct: list[float | None]
    speed_kmh: list[float | None]
    mode: list[str]
    connected: list[bool]
    # The source of the setpoint in force (None: none).
    source: list[str | None]


class SetpointHistory(TypedDict):
    """A coach's setpoints over a range, one list per field, oldest first:
    :func:`.queries.setpoint_history`."""

    tick: list[datetime]
    # T_ref issued and T_rule. [°C]
    t_ref_c: list[float | None]
    t_rule_c: list[float | None]
    source: list[str]
    reason: list[str]
    # The solver's time. [ms]
    solve_time_ms: list[float | None]
    # T_opt, the planned u and the predicted y (None: no prediction).
    predicted: list[dict | None]


class Replica(TypedDict):
    """A service replica as its setpoints show it (:func:`.queries.replicas`)."""

    # Its name (``--replica-name``; ``unknown`` for setpoints from before replicas were
    # recorded).
    replica: str
    # The coaches it issued ticks to, sorted.
    coaches: list[str]
    ticks: int
    # When it first and last decided a setpoint in the range (wall time).
    first_seen: datetime
    last_seen: datetime
