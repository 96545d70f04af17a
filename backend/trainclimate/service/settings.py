"""The service's settings, in one place: environment variables (``TRAINCLIMATE_*``) and the
``trainclimate serve`` options, validated by pydantic-settings."""

from __future__ import annotations

import ipaddress
import math
import os
import re
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from pydantic import Field, ValidationInfo, field_validator
from pydantic_core import ErrorDetails
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from trainclimate import resources
from trainclimate.analysis.guard import GUARD_DAYS, MIN_GUARD_DAYS
from trainclimate.control.controller import STALE_PERIODS
from trainclimate.paths import home
from trainclimate.service.adapters import MQTT_PREFIX
from trainclimate.service.store.db import IDLE_IN_TRANSACTION_S, LOCK_TIMEOUT_S, WORKER_THREADS

if TYPE_CHECKING:
    from trainclimate.service.adapters.mqtt import Broker


#: A loop of the service counts as running for at least this long after its last completed
#: iteration (``/api/v1/ready``), however fast its clock. [s]
LOOP_READY_MIN_S = 10.0
#: How long ``/api/v1/ready`` waits for its database check by default. [s]
READY_TIMEOUT_S = 3.0
#: The longest replica name (the ``setpoints.replica`` column).
REPLICA_NAME_MAX = 64
#: The default limit of a request body: above the largest valid telemetry batch (10 000 rows,
#: every field at its longest: 5 500 058 bytes as ``json.dumps`` writes it, 5 200 056 compact;
#: ``tests/service/api/test_hardening.py`` measures it). [bytes]
MAX_BODY_BYTES = 6 * 1024 * 1024
#: How far back the live feed's telemetry is taken by default, before its coach's newest row
#: (a week: a gateway's 10 000-row batch spans 6.9 days). [days]
BACKFILL_HORIZON_DAYS = 7.0
#: The longest backfill horizon that can be set (ten years). [days]
MAX_BACKFILL_HORIZON_DAYS = 3650.0
#: How far ahead of the server's clock a live telemetry row may be stamped by default (clock
#: skew). [min]
MAX_AHEAD_MIN = 5.0
#: The most that ``max_ahead_min`` can be set to (a day). [min]
MAX_AHEAD_LIMIT_MIN = 24 * 60.0


def default_replica_name() -> str:
    """``host:pid``: this process on this machine."""
    return f"{socket.gethostname()}:{os.getpid()}"[:REPLICA_NAME_MAX]


def trusted_proxies(value: str | list[str]) -> list[str]:
    """The trusted proxies' addresses of ``value`` (a comma-separated list, or a list): each an IP
    address (``10.0.0.5``, ``::1``) or a network (``10.0.0.0/24``), blanks dropped; anything else
    is a :class:`ValueError` naming it (uvicorn would silently compare it as text)."""
    items = value.split(",") if isinstance(value, str) else value
    proxies = [item.strip() for item in items if item.strip()]
    for item in proxies:
        try:
            ipaddress.ip_network(item, strict=False)
        except ValueError:
            raise ValueError(f"{item!r} is not an IP address or network") from None
    return proxies


def default_database_url() -> str:
    """The embedded default: a SQLite file under ``$TRAINCLIMATE_HOME``."""
    return f"sqlite:///{home() / 'trainclimate.db'}"


class Settings(BaseSettings):
    """The service's settings: each field's ``description`` says what it does (the ``serve``
    options that set some take their help from it); its environment variable is
    ``TRAINCLIMATE_<NAME>`` (:func:`env_var`). They act in :mod:`.store.db` (the pool, the
    PostgreSQL timeouts), :mod:`.api.hardening` (the body limit, the throttle, the trusted
    proxies, the overload wait), :mod:`.store.cache`, :mod:`.store.commands` (the live feed's
    horizons), :mod:`.store.guard`, :mod:`.metrics`, :mod:`.adapters.mqtt` (:meth:`broker`) and
    :mod:`.adapters.dynsec`."""

    model_config = SettingsConfigDict(env_prefix="TRAINCLIMATE_", extra="ignore")

    database_url: str = Field(
        default_factory=default_database_url,
        description="the database URL, sqlite:///FILE or postgresql://USER@HOST:PORT/NAME "
        "(default: a SQLite file under $TRAINCLIMATE_HOME)",
    )
    fleet: str | None = Field(
        default=None, description="'demo' adds the simulated demo fleet (default: none)"
    )
    speedup: float = Field(
        default=1.0,
        description="how many times faster than real time the demo fleet's clock runs",
    )
    demo_coach_params: Path | None = Field(
        default=None,
        description="a coach parameter file (coach-params, calibrate --out) for every coach of "
        "the demo fleet, e.g. a calibrated twin (default: each scenario's coach)",
    )
    sampling_min: float = Field(default=5.0, description="the controller's period [min]")
    stale_periods: int = Field(
        default=STALE_PERIODS,
        description="after how many of the controller's periods without telemetry a coach is stale",
    )
    drift_factor: float = Field(
        default=1.5,
        gt=1.0,
        description="how many times its validation MAE the active model's online MAE may reach "
        "before the model health flags drift",
    )
    cors_origins: list[str] = Field(
        default_factory=list,
        description="other origins allowed to call the API (default none: the dashboard is "
        "served by the same origin)",
    )
    predictor_path: Path | None = Field(
        default=None,
        description="a model file (predictor fit) registered if the database has none "
        "(default: the cached model, else one prepared at start)",
    )
    scheduler_interval_s: float = Field(
        default=0.5, description="the pause between two iterations of the live fleet's loop [s]"
    )
    frontend_dir: Path = Field(
        default_factory=resources.frontend_dir,
        description="the dashboard's built files (default: those of the package)",
    )
    max_body_bytes: int = Field(
        default=MAX_BODY_BYTES,
        gt=0,
        description="the largest request body accepted (larger: 413; the default fits the "
        "largest valid telemetry batch) [bytes]",
    )
    backfill_horizon_days: float = Field(
        default=BACKFILL_HORIZON_DAYS,
        gt=0,
        le=MAX_BACKFILL_HORIZON_DAYS,
        description="how far back the live feed's rows are taken: a row older than its coach's "
        "newest row less this many days is refused [days]",
    )
    auth_failures_burst: int = Field(
        default=20,
        gt=0,
        description="after this many failed authentications from one client address within "
        "auth_failures_window_s, its requests whose token fails answer 429",
    )
    auth_failures_window_s: float = Field(
        default=60.0, gt=0, description="the window of auth_failures_burst [s]"
    )
    forwarded_allow_ips: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="the reverse proxies whose X-Forwarded-For names the client (the address "
        "the authentication throttle counts), comma-separated IP addresses or networks "
        "(default none: the header is ignored)",
    )
    worker_threads: int = Field(
        default=WORKER_THREADS,
        gt=0,
        description="the threads running the API's requests, as many requests admitted at once, "
        "and the database pool sized to them",
    )
    overload_wait_s: float = Field(
        default=1.0,
        ge=0,
        description="how long a request beyond worker_threads waits for its turn before it "
        "answers 503 [s]",
    )
    read_cache_size: int = Field(
        default=8192,
        ge=0,
        description="the read answers kept (a view per coach, a comparison and the fleet "
        "summary's figures per train and range; least recently used go first; at least the "
        "fleet's coaches and trains; 0: none)",
    )
    mqtt_username: str | None = Field(
        default=None, description="the broker's user name (default: the URL's)"
    )
    mqtt_password: str | None = Field(
        default=None, description="the broker's password (default: the URL's)"
    )
    mqtt_ca_file: Path | None = Field(
        default=None, description="a CA bundle for a TLS broker (implies TLS)"
    )
    mqtt_prefix: str = Field(default=MQTT_PREFIX, description="the MQTT topics' prefix")
    # after the CA file and the prefix, which its check reads
    mqtt_url: str | None = Field(
        default=None,
        description="a broker to take telemetry from and publish setpoints to, "
        "mqtt[s]://[USER[:PASSWORD]@]HOST[:PORT] (default: none)",
    )
    mqtt_client_id: str = Field(
        default="trainclimate-service",
        description="the service's client id: its persistent session on the broker",
    )
    mqtt_dynsec: bool = Field(
        default=False,
        description="give each gateway token its own broker client (Mosquitto's dynamic "
        "security plugin), deleted when the token is revoked",
    )
    mqtt_dynsec_username: str | None = Field(
        default=None, description="the dynamic security plugin's admin user (with mqtt_dynsec)"
    )
    mqtt_dynsec_password: str | None = Field(
        default=None, description="the dynamic security plugin admin's password"
    )
    replica_name: str = Field(
        default_factory=default_replica_name,
        min_length=1,
        max_length=REPLICA_NAME_MAX,
        description="this process's name in the setpoints it decides (default: HOST:PID); "
        "replicas sharing one PostgreSQL database split the coaches",
    )
    loop_ready_s: float | None = Field(
        default=None,
        gt=0,
        description="how long after its last completed iteration a loop of this replica still "
        "counts as running for /api/v1/ready (default: two periods of its fleet's clock in "
        f"wall time, at least {LOOP_READY_MIN_S:g} s) [s]",
    )
    guard_days: int = Field(
        default=GUARD_DAYS,
        ge=MIN_GUARD_DAYS,
        description="hand a pair back to T_rule once its trial's 95 % interval says the layer "
        "costs energy on this many consecutive service days",
    )
    metrics_refresh_s: float = Field(
        default=60.0,
        gt=0,
        description="how often at most the metrics' figures that need a query (the model's "
        "online MAE, the live coaches) are refreshed [s]",
    )
    max_ahead_min: float = Field(
        default=MAX_AHEAD_MIN,
        gt=0,
        le=MAX_AHEAD_LIMIT_MIN,
        description="refuse live telemetry rows stamped further than this ahead of the server's "
        "clock (reason ahead_of_clock) [min]",
    )
    db_lock_timeout_s: float = Field(
        default=LOCK_TIMEOUT_S,
        ge=0,
        description="the PostgreSQL sessions' lock_timeout (0: none) [s]",
    )
    db_idle_in_transaction_s: float = Field(
        default=IDLE_IN_TRANSACTION_S,
        ge=0,
        description="the PostgreSQL sessions' idle_in_transaction_session_timeout (0: none) [s]",
    )
    ready_timeout_s: float = Field(
        default=READY_TIMEOUT_S,
        gt=0,
        description="how long /api/v1/ready waits for its database check before it answers 503 [s]",
    )

    @field_validator("fleet")
    @classmethod
    def _fleet(cls, value: str | None) -> str | None:
        if value not in (None, "demo"):
            raise ValueError("must be 'demo' or empty")
        return value

    @field_validator("forwarded_allow_ips", mode="before")
    @classmethod
    def _proxies(cls, value: str | list[str]) -> list[str]:
        return trusted_proxies(value)

    @field_validator("speedup", "sampling_min", "scheduler_interval_s")
    @classmethod
    def _positive(cls, value: float) -> float:
        if not (math.isfinite(value) and value > 0):
            raise ValueError("must be positive")
        return value

    @field_validator("replica_name", mode="before")
    @classmethod
    def _replica_name(cls, value: object) -> object:
        if isinstance(value, str) and not (
            0 < len(value) <= REPLICA_NAME_MAX and value.isprintable()
        ):
            raise ValueError(f"must be 1 to {REPLICA_NAME_MAX} printable characters")
        return value

    @field_validator("mqtt_url")
    @classmethod
    def _mqtt_url(cls, value: str | None, info: ValidationInfo) -> str | None:
        """A broker URL that :class:`~trainclimate.service.adapters.mqtt.Broker` takes, with the
        CA file and the topics' prefix (a :class:`~.adapters.mqtt.BrokerError` names the fault)."""
        if value is not None:
            from trainclimate.service.adapters.mqtt import Broker

            prefix = info.data.get("mqtt_prefix", MQTT_PREFIX)
            Broker.from_url(value, ca_file=info.data.get("mqtt_ca_file"), prefix=prefix)
        return value

    def broker(self, username: str | None, password: str | None) -> Broker:
        """The broker of ``mqtt_url`` (with ``mqtt_ca_file`` and ``mqtt_prefix``), as
        ``username`` with ``password`` (None: the URL's); a :class:`ValueError` without
        ``mqtt_url``."""
        from trainclimate.service.adapters.mqtt import Broker

        if self.mqtt_url is None:
            raise ValueError("no MQTT broker: mqtt_url is not set")
        return Broker.from_url(
            self.mqtt_url,
            username=username,
            password=password,
            ca_file=self.mqtt_ca_file,
            prefix=self.mqtt_prefix,
        )


def env_var(name: str) -> str:
    """The environment variable of setting ``name``: ``TRAINCLIMATE_<NAME>``."""
    return f"TRAINCLIMATE_{name.upper()}"


def allowed(name: str) -> str:
    """What the bounds of setting ``name`` allow, in words, with its unit: ``in (0, 3650]
    [days]``, ``at least 1``, ``positive [bytes]``; empty without bounds."""
    field = Settings.model_fields[name]
    bounds = {
        key: getattr(item, key)
        for item in field.metadata
        for key in ("gt", "ge", "le")
        if hasattr(item, key)
    }
    if "gt" in bounds:
        low = f"({bounds['gt']:g}"
        text = "positive" if bounds["gt"] == 0 else f"above {bounds['gt']:g}"
    elif "ge" in bounds:
        low = f"[{bounds['ge']:g}"
        text = f"at least {bounds['ge']:g}"
    else:
        return ""
    if "le" in bounds:
        text = f"in {low}, {bounds['le']:g}]"
    unit = re.search(r"\[[^\]]+\]$", field.description or "")
    return f"{text} {unit.group()}" if unit else text


#: pydantic's errors of a field's bounds (``gt``, ``ge``, ``le``).
BOUND_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than_equal"})


def problem(error: ErrorDetails) -> str:
    """One of a :class:`Settings` validation error's ``errors()`` in a line, without the
    setting's name: a validator's own words (``must be positive``), what the field's constraints
    allow (``must be in (0, 3650] [days]``), else pydantic's message."""
    name = error["loc"][0] if error["loc"] else None
    if error["type"] == "value_error" and "error" in error.get("ctx", {}):
        return str(error["ctx"]["error"])
    if error["type"] in BOUND_ERRORS and name in Settings.model_fields and allowed(str(name)):
        return f"must be {allowed(str(name))}"
    return error["msg"]
