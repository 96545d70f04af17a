"""The service's own state: health, readiness, background preparation, the MQTT feed,
storage and the replicas."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field


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
