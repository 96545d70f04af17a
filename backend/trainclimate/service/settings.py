"""The service's settings, in one place: environment variables (``TRAINCLIMATE_*``) and the
``trainclimate serve`` options, validated by pydantic-settings."""

from __future__ import annotations

import ipaddress
import os
import socket
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from trainclimate import resources
from trainclimate.analysis.guard import GUARD_DAYS, MIN_GUARD_DAYS
from trainclimate.control.controller import STALE_PERIODS
from trainclimate.paths import home
from trainclimate.service.store.db import IDLE_IN_TRANSACTION_S, LOCK_TIMEOUT_S, WORKER_THREADS

#: The MQTT topics' prefix (see :mod:`trainclimate.service.adapters.mqtt`).
MQTT_PREFIX = "trainclimate/v1"


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
    """``database_url`` (``--db``; env ``TRAINCLIMATE_DATABASE_URL``; default a SQLite file);
    ``fleet`` ``demo`` to add the simulated demo fleet (``demo_coach_params``: a coach parameter
    file for all its coaches, e.g. a calibrated twin); ``speedup`` how many times faster than
    real time the demo fleet's clock runs; ``sampling_min`` the controller's period;
    ``stale_periods`` after how many periods without telemetry a coach is stale;
    ``drift_factor`` how many times its validation MAE the active model's online MAE may reach
    before the model health flags drift;
    ``cors_origins`` other origins allowed to call the API (default none: the dashboard is served
    by the same origin); ``predictor_path`` a model file (default: the cached default model);
    ``max_body_bytes`` the largest request body accepted (larger: 413; the default fits the
    largest valid telemetry batch, :data:`MAX_BODY_BYTES`); ``backfill_horizon_days`` how far
    back the live feed's rows are taken: a row older than its coach's newest less this many
    days is refused (:class:`~trainclimate.service.store.commands.Backfill`); after
    ``auth_failures_burst`` failed authentications within ``auth_failures_window_s`` seconds,
    a client address's requests whose token fails answer 429 (see
    :mod:`trainclimate.service.api.hardening`); ``forwarded_allow_ips``
    (``--forwarded-allow-ips``; env ``TRAINCLIMATE_FORWARDED_ALLOW_IPS``, comma-separated;
    default none) the reverse proxies whose ``X-Forwarded-For`` names the client
    (:func:`trusted_proxies`): the address the throttle counts; from any other peer the header
    is ignored; ``worker_threads`` the threads running the API's requests (anyio's limit), as
    many requests admitted at once, and the database pool
    sized to them (:mod:`trainclimate.service.store.db`); a request beyond them waits up to
    ``overload_wait_s`` seconds for its turn, else answers 503; ``read_cache_size`` the answers
    kept, a view per coach, a comparison per train and range, the fleet summary's figures per
    train and range (least recently used go first; :mod:`trainclimate.service.store.cache`; at least
    the fleet's coaches and trains; 0: none);
    ``mqtt_url`` (``--mqtt``) a broker to take
    telemetry from and publish setpoints to, with its ``mqtt_username``, ``mqtt_password``
    (env ``TRAINCLIMATE_MQTT_PASSWORD``), ``mqtt_ca_file``, topic ``mqtt_prefix`` and the
    service's ``mqtt_client_id`` (its persistent session: see
    :mod:`trainclimate.service.adapters.mqtt`); ``mqtt_dynsec`` (``--mqtt-dynsec``) gives each
    gateway token a broker client of its own through Mosquitto's dynamic security plugin, as its
    admin ``mqtt_dynsec_username`` with ``mqtt_dynsec_password`` (env
    ``TRAINCLIMATE_MQTT_DYNSEC_USERNAME``, ``…_PASSWORD``; see
    :mod:`trainclimate.service.adapters.dynsec`); ``replica_name`` (``--replica-name``,
    default ``host:pid``) names this process in the setpoints it decides (replicas sharing one
    PostgreSQL database split the coaches); ``loop_ready_s`` how long after its last completed
    iteration a loop of this replica still counts as running for ``/api/v1/ready`` (default: two
    periods of its fleet's clock in wall time, at least :data:`LOOP_READY_MIN_S`);
    ``guard_days`` (``--guard-days``) on how many consecutive service days a pair's trial must
    say the layer costs energy (95 % interval below 0) before its guard hands the pair back to
    T_rule (:mod:`trainclimate.service.store.guard`; at least 1); ``metrics_refresh_s`` how often
    at most the metrics' figures that need a query (the model's online MAE, the live coaches) are
    refreshed (:mod:`trainclimate.service.metrics`); ``max_ahead_min``
    (``--max-ahead-min``) how far ahead of the server's clock a live row may be stamped
    (further: refused, reason ``ahead_of_clock``; default :data:`MAX_AHEAD_MIN`);
    ``db_lock_timeout_s`` and ``db_idle_in_transaction_s`` the PostgreSQL sessions'
    ``lock_timeout`` and ``idle_in_transaction_session_timeout`` (0: none; see
    :mod:`trainclimate.service.store.db`); ``ready_timeout_s`` how long ``/api/v1/ready`` waits
    for its database check before it answers 503."""

    model_config = SettingsConfigDict(env_prefix="TRAINCLIMATE_", extra="ignore")

    database_url: str = Field(default_factory=default_database_url)
    fleet: str | None = None
    speedup: float = 1.0
    demo_coach_params: Path | None = None
    sampling_min: float = 5.0
    stale_periods: int = STALE_PERIODS
    drift_factor: float = Field(default=1.5, gt=1.0)
    cors_origins: list[str] = Field(default_factory=list)
    predictor_path: Path | None = None
    scheduler_interval_s: float = 0.5
    frontend_dir: Path = Field(default_factory=resources.frontend_dir)
    max_body_bytes: int = Field(default=MAX_BODY_BYTES, gt=0)
    backfill_horizon_days: float = Field(
        default=BACKFILL_HORIZON_DAYS, gt=0, le=MAX_BACKFILL_HORIZON_DAYS
    )
    auth_failures_burst: int = Field(default=20, gt=0)
    auth_failures_window_s: float = Field(default=60.0, gt=0)
    forwarded_allow_ips: Annotated[list[str], NoDecode] = Field(default_factory=list)
    worker_threads: int = Field(default=WORKER_THREADS, gt=0)
    overload_wait_s: float = Field(default=1.0, ge=0)
    read_cache_size: int = Field(default=8192, ge=0)
    mqtt_url: str | None = None
    mqtt_username: str | None = None
    mqtt_password: str | None = None
    mqtt_ca_file: Path | None = None
    mqtt_prefix: str = MQTT_PREFIX
    mqtt_client_id: str = "trainclimate-service"
    mqtt_dynsec: bool = False
    mqtt_dynsec_username: str | None = None
    mqtt_dynsec_password: str | None = None
    replica_name: str = Field(
        default_factory=default_replica_name, min_length=1, max_length=REPLICA_NAME_MAX
    )
    loop_ready_s: float | None = Field(default=None, gt=0)
    guard_days: int = Field(default=GUARD_DAYS, ge=MIN_GUARD_DAYS)
    metrics_refresh_s: float = Field(default=60.0, gt=0)
    max_ahead_min: float = Field(default=MAX_AHEAD_MIN, gt=0, le=MAX_AHEAD_LIMIT_MIN)
    db_lock_timeout_s: float = Field(default=LOCK_TIMEOUT_S, ge=0)
    db_idle_in_transaction_s: float = Field(default=IDLE_IN_TRANSACTION_S, ge=0)
    ready_timeout_s: float = Field(default=READY_TIMEOUT_S, gt=0)

    @field_validator("fleet")
    @classmethod
    def _fleet(cls, value: str | None) -> str | None:
        if value not in (None, "demo"):
            raise ValueError("fleet must be 'demo' or empty")
        return value

    @field_validator("forwarded_allow_ips", mode="before")
    @classmethod
    def _proxies(cls, value: str | list[str]) -> list[str]:
        return trusted_proxies(value)

    @field_validator("speedup", "sampling_min", "scheduler_interval_s")
    @classmethod
    def _positive(cls, value: float) -> float:
        if not value > 0:
            raise ValueError("must be positive")
        return value
