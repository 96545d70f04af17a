"""What the service stores (SQLAlchemy 2.0 models; the schema itself comes from ``migrations/``).

- trains and coaches (the pairing: coaches of one train; which has the layer activated), with each
  coach's fleet (``demo`` or ``live``) and the last tick issued to it (the scheduler's claim);
- fleet clocks (the demo fleet's simulated time and the simulator's state, saved with its data);
- telemetry: per coach and time, the deck temperatures, the applied T_ref, T_rule, weather,
  occupancy, speed, HVAC power, mode and whether the link was up;
- setpoints: per coach and tick (unique), T_rule, T_ref, source and reason, solve time and the
  predicted trajectory;
- overrides with their expiry; predictor models (versions, parameters, validation, which is
  active); users, their hashed tokens (a gateway's scoped to its coaches) and roles; the audit
  log of every write;
- trial plans: each train's plan changes (``train_plans``) and each service day's assignment as
  the scheduler first applied it (``trial_days``);
- each train's guard (``pair_guards``): whether its pair's own outcome handed the layer back;
- per coach and 30-minute window, its telemetry summed as it arrives (``window_rollups``), and
  each coach's newest row, newest row within comfort and late rows (``coach_feed``);
- per coach and 30-minute window, its setpoints counted as they are issued (``setpoint_rollups``).

Every timestamp is stored in UTC and read back timezone-aware (:class:`UTCDateTime`).
"""

from __future__ import annotations

from datetime import UTC, date, datetime

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    Date,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

#: The roles, lowest first: a metrics token (a Prometheus scraper: ``GET /api/v1/metrics`` and
#: nothing else) ranks below a gateway (its token scoped to coaches), which ranks below a viewer.
ROLES = ("metrics", "gateway", "viewer", "operator", "admin")
SOURCES = ("ddpc", "rule", "override", "fallback")
MODES = ("regular", "slumber", "off")
#: The trial plans the database accepts: :data:`trainclimate.analysis.trial_plan.PLANS`, named
#: here so the models do not import the analysis (and scipy) — a test holds the two equal.
PLANS = ("fixed", "alternate", "randomized", "reference")
#: An autoincrementing 64-bit key (SQLite only autoincrements INTEGER PRIMARY KEY).
BigKey = BigInteger().with_variant(Integer, "sqlite")


def utcnow() -> datetime:
    """The current time, timezone-aware in UTC."""
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator):
    """A timestamp stored in UTC and returned timezone-aware, on SQLite as on PostgreSQL."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value, dialect):
        """To the database: in UTC (naive on SQLite); a naive timestamp is refused."""
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("timestamps must be timezone-aware")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value, dialect):
        """From the database: timezone-aware in UTC."""
        if value is None or value.tzinfo is UTC:
            return value
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class Base(DeclarativeBase):
    """The models' declarative base (its metadata is what the migrations are compared with)."""


class Train(Base):
    """A train: the coaches that run together (its comparison pairs an activated coach with a
    deactivated one)."""

    __tablename__ = "trains"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(100), default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    coaches: Mapped[list[Coach]] = relationship(back_populates="train", order_by="Coach.id")


class Coach(Base):
    """A coach: its train, fleet (``demo`` or ``live``), whether the DDPC layer is on for it,
    and the last tick issued to it (the scheduler's claim)."""

    __tablename__ = "coaches"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    train_id: Mapped[str] = mapped_column(ForeignKey("trains.id"), index=True)
    fleet: Mapped[str] = mapped_column(String(16), default="live")
    ddpc_active: Mapped[bool] = mapped_column(Boolean, default=False)
    last_tick: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    #: The replica that issued its last tick (``--replica-name``): replicas claim their own
    #: coaches first.
    held_by: Mapped[str | None] = mapped_column(String(64), nullable=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    train: Mapped[Train] = relationship(back_populates="coaches")


class CoachLiveness(Base):
    """A live coach's own clock, ``time`` (the newest time of its telemetry), when its
    telemetry last arrived (``last_seen_at``, wall time) and the anchor its clock's pace is
    measured from (:mod:`trainclimate.service.store.liveness`). Kept apart from ``coaches``,
    whose rows the scheduler's ticks lock: storing telemetry never waits for a tick."""

    __tablename__ = "coach_liveness"
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"), primary_key=True)
    time: Mapped[datetime] = mapped_column(UTCDateTime)
    last_seen_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    anchor_time: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    anchor_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)


class FleetClock(Base):
    """A simulated fleet's clock: the demo fleet's simulated time with the simulator's state
    (each live coach has a clock of its own, :class:`CoachLiveness`)."""

    __tablename__ = "fleet_clocks"
    name: Mapped[str] = mapped_column(String(16), primary_key=True)
    time: Mapped[datetime] = mapped_column(UTCDateTime)
    state: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow, onupdate=utcnow)


class Telemetry(Base):
    """One coach's 1-minute row stamped ``time`` (the minute up to it): deck temperatures,
    applied T_ref and T_rule (°C), ambient temperature (°C), irradiance (W/m²), occupancy (%),
    speed (km/h), HVAC power (kW; the whole coach's, floor and wall heating included) and the
    floor and wall heating's share of it (kW, if the feed reports it), mode and whether the link
    was up; unique (coach, time). On PostgreSQL the table is partitioned by calendar month
    (:mod:`trainclimate.service.store.partitions`) and its primary key there is (id, time): the
    partition key must be in it; ``id`` alone stays the ORM's identity, unique all the same (one
    sequence gives it)."""

    __tablename__ = "telemetry"
    __table_args__ = (UniqueConstraint("coach_id", "time", name="uq_telemetry_coach_time"),)
    id: Mapped[int] = mapped_column(BigKey, primary_key=True, autoincrement=True)
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"))
    time: Mapped[datetime] = mapped_column(UTCDateTime)
    t_room_up_c: Mapped[float | None] = mapped_column(Float)
    t_room_mid_c: Mapped[float | None] = mapped_column(Float)
    t_room_low_c: Mapped[float | None] = mapped_column(Float)
    t_ref_c: Mapped[float | None] = mapped_column(Float)
    t_rule_c: Mapped[float | None] = mapped_column(Float)
    t_amb_c: Mapped[float | None] = mapped_column(Float)
    ghi_w_m2: Mapped[float | None] = mapped_column(Float)
    q_gt_w_m2: Mapped[float | None] = mapped_column(Float)
    q_gs_w_m2: Mapped[float | None] = mapped_column(Float)
    occupancy_pct: Mapped[float | None] = mapped_column(Float)
    speed_kmh: Mapped[float | None] = mapped_column(Float)
    power_kw: Mapped[float | None] = mapped_column(Float)
    floor_power_kw: Mapped[float | None] = mapped_column(Float)
    mode: Mapped[str] = mapped_column(String(16), default="regular")
    connected: Mapped[bool] = mapped_column(Boolean, default=True)


class WindowRollup(Base):
    """One coach's telemetry in one 30-minute window, summed as it arrives
    (:mod:`trainclimate.service.store.rollups`): bit i of each mask is the row stamped
    ``window start + (i + 1) min`` — ``present`` (a row on the minute grid), ``connected``,
    ``powered`` (HVAC power reported), ``regular`` (regular mode), ``split`` (the floor heating's
    share reported); the energy on both meters [kWh] over the present minutes and the discomfort
    per deck [K·h] over the minutes that are present, connected, powered and regular. ``window``
    counts windows since 1970-01-01 UTC."""

    __tablename__ = "window_rollups"
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"), primary_key=True)
    window: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    present: Mapped[int] = mapped_column(BigInteger, default=0)
    connected: Mapped[int] = mapped_column(BigInteger, default=0)
    powered: Mapped[int] = mapped_column(BigInteger, default=0)
    regular: Mapped[int] = mapped_column(BigInteger, default=0)
    split: Mapped[int] = mapped_column(BigInteger, default=0)
    energy_kwh: Mapped[float] = mapped_column(Float, default=0.0)
    hvac_kwh: Mapped[float] = mapped_column(Float, default=0.0)
    discomfort_up_kh: Mapped[float] = mapped_column(Float, default=0.0)
    discomfort_mid_kh: Mapped[float] = mapped_column(Float, default=0.0)
    discomfort_low_kh: Mapped[float] = mapped_column(Float, default=0.0)


class PairDay(Base):
    """A pair's figures over one whole service day (:mod:`trainclimate.service.store.pair_days`):
    the pair (``coach_0`` < ``coach_1``), its train's ``switch_hour`` [h] and the ``day`` (an
    ordinal); its windows [``first_window``, ``first_window`` + ``windows``) (windows since
    1970); the lead-in state it was computed from and the one it leaves (the last labelled
    window's label, and how many windows back the last change was, capped at the lead-in's);
    ``fields`` (float64 per :data:`~.pair_trial.FIELDS`), ``chart`` (per counted window its
    offset from ``first_window`` and its energies per meter and role, float64 × 5),
    ``chart_digest`` (a 63-bit hash of the day's key and chart, :func:`.pair_days.digest`: what
    the fleet days check their members by) and ``minutes`` (each window's sums, float64 ×
    len(SUMS), label and own code, int8)."""

    __tablename__ = "pair_days"
    day: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    coach_0: Mapped[str] = mapped_column(ForeignKey("coaches.id"), primary_key=True)
    coach_1: Mapped[str] = mapped_column(ForeignKey("coaches.id"), primary_key=True)
    switch_hour: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    first_window: Mapped[int] = mapped_column(BigInteger)
    windows: Mapped[int] = mapped_column(Integer)
    entering_label: Mapped[int] = mapped_column(Integer)
    entering_age: Mapped[int] = mapped_column(Integer)
    exiting_label: Mapped[int] = mapped_column(Integer)
    exiting_age: Mapped[int] = mapped_column(Integer)
    fields: Mapped[bytes] = mapped_column(LargeBinary)
    chart: Mapped[bytes] = mapped_column(LargeBinary)
    chart_digest: Mapped[int] = mapped_column(BigInteger)
    minutes: Mapped[bytes] = mapped_column(LargeBinary)
    __table_args__ = (
        Index("ix_pair_days_coach_0", "coach_0", "day"),
        Index("ix_pair_days_coach_1", "coach_1", "day"),
    )


class FleetDay(Base):
    """The fleet chart of one service ``day`` (an ordinal) at ``switch_hour`` [h]
    (:mod:`trainclimate.service.store.fleet_days`): the charts of every pair day stored for it
    pooled per window — ``chart``, per window of [``first_window``, ``first_window`` +
    ``windows``) the pairs that count it and their energies per meter and role, float64 × 5 —
    with how many pair days it pools (``pairs``) and the sum of their chart digests modulo
    2⁶³ (``digest``), by which a summary checks that it pools exactly the pair days it read;
    and those pair days as a summary reads them: ``members``, their coaches (``coach_0 coach_1``
    per line, in order), ``member_rows``, their lead-in states, chart digests and figures
    packed (:data:`.fleet_days.MEMBER`), and ``version``, a random 63-bit number drawn when the
    fleet day is made, by which a reader knows the members it keeps are the day's still."""

    __tablename__ = "fleet_days"
    day: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    switch_hour: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    first_window: Mapped[int] = mapped_column(BigInteger)
    windows: Mapped[int] = mapped_column(Integer)
    pairs: Mapped[int] = mapped_column(Integer)
    digest: Mapped[int] = mapped_column(BigInteger)
    chart: Mapped[bytes] = mapped_column(LargeBinary)
    version: Mapped[int] = mapped_column(BigInteger)
    members: Mapped[str] = mapped_column(Text)
    member_rows: Mapped[bytes] = mapped_column(LargeBinary)


class CoachFeed(Base):
    """A coach's telemetry as it stands, kept as rows arrive (:mod:`.rollups`): the time of its
    newest row, of its newest row within comfort (every deck within T_rule ± T_max, or not in
    regular mode) — so the attention list reads two times per coach instead of its last hours
    of rows — ``late_rows``, the rows stored in batches that reached back to or before its
    newest row (rows arriving late: what can change a range already summed), and ``first``, the
    time of its oldest row stored (None once a retention has dropped them all): where its data
    begins, read by the fleet summary without probing every partition of the telemetry."""

    __tablename__ = "coach_feed"
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"), primary_key=True)
    newest: Mapped[datetime] = mapped_column(UTCDateTime)
    first: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    last_ok: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    late_rows: Mapped[int] = mapped_column(BigInteger, default=0)


class Setpoint(Base):
    """The setpoint issued to one coach at one tick (unique): T_rule, T_ref (°C), source,
    reason, solve and step time (ms), the predicted trajectory, the model it came from and the
    service replica that decided it (``--replica-name``, default ``host:pid``)."""

    __tablename__ = "setpoints"
    __table_args__ = (
        UniqueConstraint("coach_id", "tick", name="uq_setpoint_coach_tick"),
        Index("ix_setpoints_created_at", "created_at"),
        Index("ix_setpoints_model_tick", "model_id", "tick"),  # a model's health
    )
    id: Mapped[int] = mapped_column(BigKey, primary_key=True, autoincrement=True)
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"))
    tick: Mapped[datetime] = mapped_column(UTCDateTime)
    t_rule_c: Mapped[float | None] = mapped_column(Float)
    t_ref_c: Mapped[float | None] = mapped_column(Float)
    source: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str] = mapped_column(String(32))
    detail: Mapped[str] = mapped_column(Text, default="")
    solve_time_ms: Mapped[float | None] = mapped_column(Float)
    step_time_ms: Mapped[float | None] = mapped_column(Float)
    predicted: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    model_id: Mapped[int | None] = mapped_column(ForeignKey("predictor_models.id"), nullable=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    replica: Mapped[str | None] = mapped_column(String(64), nullable=True)


class SetpointRollup(Base):
    """One coach's setpoints in one 30-minute window, counted as they are issued
    (:mod:`trainclimate.service.store.setpoint_rollups`): every tick, and those that issued a
    DDPC setpoint, T_rule with the layer off, no model yet, an override, a fallback, or not in
    regular mode. ``window`` counts windows since 1970-01-01 UTC."""

    __tablename__ = "setpoint_rollups"
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"), primary_key=True)
    window: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    ticks: Mapped[int] = mapped_column(Integer, default=0)
    ddpc: Mapped[int] = mapped_column(Integer, default=0)
    inactive: Mapped[int] = mapped_column(Integer, default=0)
    no_model: Mapped[int] = mapped_column(Integer, default=0)
    override: Mapped[int] = mapped_column(Integer, default=0)
    fallback: Mapped[int] = mapped_column(Integer, default=0)
    not_regular: Mapped[int] = mapped_column(Integer, default=0)


class Override(Base):
    """An operator's T_ref (°C) for a coach from ``starts_at`` until ``ends_at`` (or until
    cancelled), with who set it and why."""

    __tablename__ = "overrides"
    __table_args__ = (Index("ix_overrides_coach_ends", "coach_id", "ends_at"),)
    id: Mapped[int] = mapped_column(BigKey, primary_key=True, autoincrement=True)
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"))
    t_ref_c: Mapped[float] = mapped_column(Float)
    starts_at: Mapped[datetime] = mapped_column(UTCDateTime)
    ends_at: Mapped[datetime] = mapped_column(UTCDateTime)
    reason: Mapped[str] = mapped_column(Text)
    created_by: Mapped[str] = mapped_column(String(100))
    cancelled_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    cancelled_by: Mapped[str | None] = mapped_column(String(100), nullable=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


#: A model version's states: the one the controllers use, one predicting in its shadow, one
#: withdrawn.
MODEL_STATES = ("active", "candidate", "retired")


class PredictorModel(Base):
    """A predictor model version: its method, ρ, horizon, sampling period (min), the model
    file's bytes, training and validation info, and its state (:data:`MODEL_STATES`; at most one
    ``active``, which a unique partial index enforces)."""

    __tablename__ = "predictor_models"
    __table_args__ = (
        Index(
            "ix_predictor_models_one_active",
            "state",
            unique=True,
            postgresql_where=text("state = 'active'"),
            sqlite_where=text("state = 'active'"),
        ),
    )
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    version: Mapped[int] = mapped_column(Integer, unique=True)
    method: Mapped[str] = mapped_column(String(32))
    rho: Mapped[int] = mapped_column(Integer)
    horizon: Mapped[int] = mapped_column(Integer)
    sampling_min: Mapped[float | None] = mapped_column(Float)
    artifact: Mapped[bytes] = mapped_column(LargeBinary)
    info: Mapped[dict] = mapped_column(JSON, default=dict)
    state: Mapped[str] = mapped_column(String(16), default="retired", server_default="retired")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)

    @property
    def active(self) -> bool:
        """Whether the controllers use this version."""
        return self.state == "active"


class ShadowPrediction(Base):
    """A candidate model's prediction at one coach's tick, made beside the active model from the
    same samples and the active model's planned setpoints: y(1|t) … y(T|t), T × 3 (up, mid, low
    deck, °C). It never sets a setpoint."""

    __tablename__ = "shadow_predictions"
    __table_args__ = (
        UniqueConstraint("model_id", "coach_id", "tick", name="uq_shadow_model_coach_tick"),
        Index("ix_shadow_model_tick", "model_id", "tick"),
    )
    id: Mapped[int] = mapped_column(BigKey, primary_key=True, autoincrement=True)
    model_id: Mapped[int] = mapped_column(ForeignKey("predictor_models.id"))
    coach_id: Mapped[str] = mapped_column(ForeignKey("coaches.id"))
    tick: Mapped[datetime] = mapped_column(UTCDateTime)
    y_pred_c: Mapped[list] = mapped_column(JSON)


class User(Base):
    """A user of the API with a role (metrics, gateway, viewer, operator or admin)."""

    __tablename__ = "users"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    tokens: Mapped[list[ApiToken]] = relationship(back_populates="user")


class ApiToken(Base):
    """A user's bearer token: its SHA-256 and first characters (never the token itself), the
    coaches it is scoped to (a gateway token's; None for the other roles), when it expires (None:
    never) and when it was revoked."""

    __tablename__ = "api_tokens"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    prefix: Mapped[str] = mapped_column(String(12))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    coaches: Mapped[list[str] | None] = mapped_column(JSON(none_as_null=True), nullable=True)
    expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    user: Mapped[User] = relationship(back_populates="tokens")


class AuditLog(Base):
    """One audited write: who (name and role), when, the action, its target, why and details."""

    __tablename__ = "audit_log"
    __table_args__ = (Index("ix_audit_time", "time"),)
    id: Mapped[int] = mapped_column(BigKey, primary_key=True, autoincrement=True)
    time: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    user_name: Mapped[str] = mapped_column(String(100))
    role: Mapped[str] = mapped_column(String(16))
    action: Mapped[str] = mapped_column(String(64))
    target: Mapped[str] = mapped_column(String(64), default="")
    reason: Mapped[str] = mapped_column(Text, default="")
    detail: Mapped[dict] = mapped_column(JSON, default=dict)


class TrainPlan(Base):
    """A change of a train's trial plan: the plan (:data:`PLANS`), the local hour its
    service days start at (0–23), the ``randomized`` plan's seed, why, from when it is in force
    (UTC), who made it and when (wall time). The plan in force at t is the row with the latest
    ``effective_from`` ≤ t (the newest of equals); a train without one runs ``fixed``."""

    __tablename__ = "train_plans"
    __table_args__ = (
        Index("ix_train_plans_train_effective", "train_id", "effective_from"),
        CheckConstraint("switch_hour >= 0 AND switch_hour <= 23", name="ck_train_plans_hour"),
        CheckConstraint(
            "plan IN (" + ", ".join(f"'{p}'" for p in PLANS) + ")", name="ck_train_plans_plan"
        ),
    )
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    train_id: Mapped[str] = mapped_column(ForeignKey("trains.id"))
    plan: Mapped[str] = mapped_column(String(16))
    switch_hour: Mapped[int] = mapped_column(Integer)
    seed: Mapped[int] = mapped_column(Integer, default=0)
    reason: Mapped[str] = mapped_column(Text)
    effective_from: Mapped[datetime] = mapped_column(UTCDateTime)
    created_by: Mapped[str] = mapped_column(String(100))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class TrialDay(Base):
    """A train's service day as the scheduler first applied it (never rewritten): the plan in
    force, its switch hour, and the coach with the layer activated — None on a ``reference``
    day, or on a ``fixed`` day without exactly one of the two coaches activated."""

    __tablename__ = "trial_days"
    train_id: Mapped[str] = mapped_column(ForeignKey("trains.id"), primary_key=True)
    day: Mapped[date] = mapped_column(Date, primary_key=True)
    plan: Mapped[str] = mapped_column(String(16))
    switch_hour: Mapped[int] = mapped_column(Integer)
    activated_coach_id: Mapped[str | None] = mapped_column(ForeignKey("coaches.id"), nullable=True)


class PairGuard(Base):
    """A train's guard (:mod:`trainclimate.service.store.guard`): the service day it last
    evaluated the pair's trial estimate on, on how many consecutive evaluations the estimate's
    95 % interval lay entirely below 0, the figures of the last evaluation, when it handed the
    layer back to T_rule (None: it has not) and the coach activated then, and the operator's
    last re-enabling (who, when, from when the estimate counts again)."""

    __tablename__ = "pair_guards"
    train_id: Mapped[str] = mapped_column(ForeignKey("trains.id"), primary_key=True)
    checked_day: Mapped[date | None] = mapped_column(Date, nullable=True)
    below_days: Mapped[int] = mapped_column(Integer, default=0)
    figures: Mapped[dict | None] = mapped_column(JSON(none_as_null=True), nullable=True)
    tripped_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    coach_id: Mapped[str | None] = mapped_column(ForeignKey("coaches.id"), nullable=True)
    counts_from: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    reset_by: Mapped[str | None] = mapped_column(String(100), nullable=True)
    reset_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
