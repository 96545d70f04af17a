"""The service's Prometheus metrics (``GET /api/v1/metrics``, the text format of
``prometheus-client``), every series labelled with the ``replica`` that serves it.

Cheap by construction: a scrape runs no database query. What the service counts as it goes is
kept here (:class:`Metrics`: the ticks, their durations and skips, the setpoints by source, the
coaches by their latest decision — updated by each tick, so a scrape only reads a small table
of counts —, the HTTP answers by status, the requests' latency, the telemetry rows the HTTP feed
stored); what the rest of the service already holds in memory is read at the scrape
(:class:`StateCollector`: the MQTT feed's state and counts, the backfill refusals, the admission
line, the database pool, the loops' heartbeats, the model preparation, the disk of the service's
home). The two figures that need a query — the active model's online MAE per step and drift, and
how many live coaches are registered — are refreshed in the background at most every
:data:`REFRESH_S` (:class:`Refresher`), never inside a scrape.

Series (all with ``replica``; ``_total`` counters):

- ``trainclimate_ticks_total{fleet}``, ``trainclimate_tick_duration_seconds{fleet}`` (histogram:
  one tick issued to a fleet's due coaches, every batch), ``trainclimate_ticks_skipped_total
  {fleet,cause}`` (``behind``: coach periods left out because the service was down or behind the
  live clock; ``database_unavailable``, ``error``: live-loop iterations that failed),
  ``trainclimate_setpoints_total{fleet,source}``, ``trainclimate_coaches{fleet,source,reason}``
  (each coach by the latest decision this replica made for it),
  ``trainclimate_last_tick_timestamp_seconds{fleet}`` (the newest tick issued here) and
  ``trainclimate_fleet_clock_timestamp_seconds{fleet}`` (the live clock as the loop last read it:
  the newest telemetry; Unix time of the data's clock, s);
- ``trainclimate_telemetry_rows_total{transport,outcome}`` (``stored``, ``duplicate``),
  ``trainclimate_telemetry_refused_total{transport,reason}`` (HTTP batches by the status
  refusing them, MQTT messages by the drop reason), ``trainclimate_telemetry_refused_rows_total
  {reason}`` (rows outside the backfill horizon, both transports, as ``/health`` counts them),
  ``trainclimate_telemetry_last_row_timestamp_seconds`` (wall time, s: the last batch stored, or
  the start if live coaches are registered and none has arrived since),
  ``trainclimate_live_coaches``;
- ``trainclimate_mqtt_connected``, ``trainclimate_mqtt_messages_total{outcome,reason}``,
  ``trainclimate_mqtt_connections_total``, ``trainclimate_mqtt_setpoints_published_total``;
- ``trainclimate_http_responses_total{code}``, ``trainclimate_http_request_duration_seconds``
  (histogram), ``trainclimate_auth_failures_total`` (401 to a request with a token),
  ``trainclimate_auth_throttled_total`` (429), ``trainclimate_admission_rejected_total`` (503s
  of the admission), ``trainclimate_requests_in_progress``, ``trainclimate_requests_waiting``,
  ``trainclimate_db_pool_size``, ``trainclimate_db_pool_in_use``, ``trainclimate_database_up``
  (the live loop's last iteration reached the database);
- ``trainclimate_model_active_version``, ``trainclimate_model_online_mae_celsius{version,step}``,
  ``trainclimate_model_drift{version}``, ``trainclimate_preparation{task,state}``,
  ``trainclimate_preparation_percent``, ``trainclimate_loop_age_seconds{loop}``,
  ``trainclimate_loop_limit_seconds{loop}``, ``trainclimate_disk_free_bytes{path}``,
  ``trainclimate_disk_size_bytes{path}``, ``trainclimate_info{version,database}``.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from collections import Counter as Tally
from collections.abc import Iterable, Sequence

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Histogram,
    disable_created_metrics,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from trainclimate import __version__

log = logging.getLogger(__name__)
# no ``_created`` series beside every counter (the process's start says as much)
disable_created_metrics()

#: The model's online MAE and the count of live coaches are refreshed at most this often by
#: default (the setting ``metrics_refresh_s``). [s]
REFRESH_S = 60.0
#: The window of the online MAE in the metrics (the data's clock). [h]
MAE_WINDOW_H = 1.0
#: The tick duration's histogram buckets. [s]
TICK_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)
#: The request latency's histogram buckets. [s]
REQUEST_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0)
#: An HTTP refusal of a telemetry batch, by status: its reason in the metrics.
REFUSAL_REASONS = {
    401: "unauthenticated",
    403: "forbidden",
    404: "unknown_coach",
    409: "conflict",
    413: "too_large",
    422: "invalid",
    429: "throttled",
    503: "unavailable",
}
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
#: The HTTP live feed's push, whose refusals are counted by reason.
TELEMETRY_PATH = "/api/v1/telemetry"


class Metrics:
    """What the service counts as it goes, for ``replica`` (see the module docstring). Every
    method is safe from any thread and costs microseconds."""

    def __init__(self, replica: str):
        self.replica = replica
        self.registry = CollectorRegistry()
        r, labels = self.registry, ["replica"]
        self._ticks = Counter("trainclimate_ticks", "Ticks issued", [*labels, "fleet"], registry=r)
        self._tick_seconds = Histogram(
            "trainclimate_tick_duration_seconds",
            "Wall time of issuing one tick to a fleet's due coaches",
            [*labels, "fleet"],
            buckets=TICK_BUCKETS,
            registry=r,
        )
        self._skipped = Counter(
            "trainclimate_ticks_skipped", "Ticks skipped", [*labels, "fleet", "cause"], registry=r
        )
        self._setpoints = Counter(
            "trainclimate_setpoints",
            "Setpoints decided",
            [*labels, "fleet", "source"],
            registry=r,
        )
        self._request_seconds = Histogram(
            "trainclimate_http_request_duration_seconds",
            "Wall time of an HTTP request, from its start to its answer's last byte",
            labels,
            buckets=REQUEST_BUCKETS,
            registry=r,
        )
        self._lock = threading.Lock()
        #: fleet → coach → (source, reason) of the latest decision, and their tallies
        self._latest: dict[str, dict[str, tuple[str, str]]] = {}
        self._coaches: Tally = Tally()
        self._responses: Tally = Tally()
        self._auth_failures = 0
        self._telemetry_rows: Tally = Tally()
        self._refused: Tally = Tally()
        #: wall time of the last telemetry batch stored (Unix time, s), over any transport
        self.last_row_at: float | None = None
        #: whether the live loop's last iteration reached the database (None: not yet run)
        self.database_up: bool | None = None
        #: fleet → its newest tick issued here, and → its clock as the loop last read it (Unix
        #: time of the data's clock, s)
        self.last_tick: dict[str, float] = {}
        self.clock: dict[str, float] = {}

    # --- the ticks (the scheduler) ---------------------------------------------------------
    def tick(self, fleet: str, seconds: float, at: float | None = None) -> None:
        """One tick issued to ``fleet`` (to at least one coach) in ``seconds`` (s, wall time);
        ``at`` the tick (Unix time of the data's clock, s)."""
        if at is not None:
            self.last_tick[fleet] = max(at, self.last_tick.get(fleet, at))
        self._ticks.labels(self.replica, fleet).inc()
        self._tick_seconds.labels(self.replica, fleet).observe(seconds)

    def decided(self, fleet: str, rows: Iterable[dict]) -> None:
        """The setpoint ``rows`` (``coach_id``, ``source``, ``reason``) of a batch of ``fleet``,
        committed: counted by source, and each coach's latest decision kept."""
        with self._lock:
            latest = self._latest.setdefault(fleet, {})
            for row in rows:
                self._setpoints.labels(self.replica, fleet, row["source"]).inc()
                now = (row["source"], row["reason"])
                before = latest.get(row["coach_id"])
                if before == now:
                    continue
                if before is not None:
                    self._coaches[(fleet, *before)] -= 1
                latest[row["coach_id"]] = now
                self._coaches[(fleet, *now)] += 1

    def skipped(self, fleet: str, cause: str, n: int = 1) -> None:
        """``n`` ticks of ``fleet`` skipped for ``cause``."""
        if n > 0:
            self._skipped.labels(self.replica, fleet, cause).inc(n)

    def coaches(self) -> dict[tuple[str, str, str], int]:
        """(fleet, source, reason) → coaches whose latest decision here it is."""
        with self._lock:
            return {k: v for k, v in self._coaches.items() if v > 0}

    # --- the HTTP side -----------------------------------------------------------------------
    def answered(self, status: int, seconds: float, *, had_token: bool, path: str) -> None:
        """An HTTP answer: its ``status``, the request's ``seconds`` (s), whether it carried an
        ``Authorization`` header, and its ``path`` (a refused telemetry batch counts)."""
        self._request_seconds.labels(self.replica).observe(seconds)
        with self._lock:
            self._responses[status] += 1
            if status == 401 and had_token:
                self._auth_failures += 1
            if path == TELEMETRY_PATH and status in REFUSAL_REASONS:
                self._refused[("http", REFUSAL_REASONS[status])] += 1

    def telemetry_stored(self, transport: str, stored: int, duplicates: int) -> None:
        """A telemetry batch stored over ``transport``: ``stored`` new rows, ``duplicates``."""
        with self._lock:
            self._telemetry_rows[(transport, "stored")] += stored
            self._telemetry_rows[(transport, "duplicate")] += duplicates
            self.last_row_at = time.time()

    def snapshot(self) -> dict:
        """The HTTP and telemetry tallies (copies)."""
        with self._lock:
            return {
                "responses": dict(self._responses),
                "auth_failures": self._auth_failures,
                "telemetry_rows": dict(self._telemetry_rows),
                "refused": dict(self._refused),
            }

    def request_seconds(self) -> Histogram:
        return self._request_seconds


class Refresher:
    """The figures that need a query, refreshed in a background thread at most every
    ``every_s`` seconds, started by a scrape that finds them older (the scrape itself reads the
    last figures): the active model's version, online MAE per step (°C, over
    :data:`MAE_WINDOW_H` of the data's clock) and drift, and the live coaches registered."""

    def __init__(self, every_s: float = REFRESH_S):
        self.every_s = every_s
        self.at = -float("inf")
        self.model: dict | None = None
        self.live_coaches: int | None = None
        self._running = threading.Lock()

    def due(self, db, settings) -> None:
        """Start a refresh in the background if the figures are older than ``every_s``."""
        if time.monotonic() - self.at < self.every_s or not self._running.acquire(False):
            return

        def run() -> None:
            try:
                self.refresh(db, settings)
            except Exception:  # the next scrape tries again; the metrics keep the last figures
                log.warning("the metrics' model figures could not be refreshed", exc_info=True)
            finally:
                self.at = time.monotonic()
                self._running.release()

        threading.Thread(target=run, name="metrics-refresh", daemon=True).start()

    def refresh(self, db, settings) -> None:
        """Read the figures now (two to five queries; :mod:`.store.model_health`)."""
        from sqlalchemy import func, select

        from trainclimate.service.store import model_health
        from trainclimate.service.store.models import Coach, PredictorModel

        with db.sessions() as s:
            live = s.scalar(select(func.count()).select_from(Coach).where(Coach.fleet == "live"))
            active = s.scalar(select(PredictorModel).where(PredictorModel.state == "active"))
            health = None
            if active is not None:
                health = model_health.model_health(
                    s, active, MAE_WINDOW_H, settings.sampling_min, settings.drift_factor
                )
        self.live_coaches = int(live)
        self.model = health
        self.at = time.monotonic()


class StateCollector:
    """The series read at the scrape from the application's state (``app.state``: see the
    module docstring), with :class:`Metrics`' tallies."""

    def __init__(self, metrics: Metrics, state, refresher: Refresher, started_at: float):
        self.metrics, self.state, self.refresher = metrics, state, refresher
        self.started_at = started_at

    def _gauge(self, name: str, doc: str, labels: Sequence[str] = ()) -> GaugeMetricFamily:
        return GaugeMetricFamily(name, doc, labels=["replica", *labels])

    def _counter(self, name: str, doc: str, labels: Sequence[str] = ()) -> CounterMetricFamily:
        return CounterMetricFamily(name, doc, labels=["replica", *labels])

    def collect(self):
        state, replica = self.state, self.metrics.replica
        db = getattr(state, "db", None)
        if db is not None:
            self.refresher.due(db, state.settings)
        info = self._gauge("trainclimate_info", "The service's version", ["version", "database"])
        info.add_metric([replica, __version__, db.dialect if db else ""], 1)
        yield info
        yield from self._ticks()
        yield from self._http()
        yield from self._telemetry()
        yield from self._mqtt()
        yield from self._capacity(db)
        yield from self._model()
        yield from self._loops()

    def _ticks(self):
        coaches = self._gauge(
            "trainclimate_coaches",
            "Coaches by the latest decision this replica made for them",
            ["fleet", "source", "reason"],
        )
        for (fleet, source, reason), n in sorted(self.metrics.coaches().items()):
            coaches.add_metric([self.metrics.replica, fleet, source, reason], n)
        yield coaches
        for name, doc, values in (
            ("last_tick", "The newest tick issued here (data clock)", self.metrics.last_tick),
            ("fleet_clock", "The fleet's clock as the loop last read it", self.metrics.clock),
        ):
            family = self._gauge(f"trainclimate_{name}_timestamp_seconds", doc, ["fleet"])
            for fleet, at in sorted(dict(values).items()):
                family.add_metric([self.metrics.replica, fleet], at)
            yield family

    def _http(self):
        replica, tallies = self.metrics.replica, self.metrics.snapshot()
        responses = self._counter(
            "trainclimate_http_responses", "HTTP answers by status code", ["code"]
        )
        for code, n in sorted(tallies["responses"].items()):
            responses.add_metric([replica, str(code)], n)
        yield responses
        failures = self._counter(
            "trainclimate_auth_failures", "401 answers to requests carrying a token"
        )
        failures.add_metric([replica], tallies["auth_failures"])
        yield failures
        throttled = self._counter(
            "trainclimate_auth_throttled", "429 answers (too many failed authentications)"
        )
        throttled.add_metric([replica], tallies["responses"].get(429, 0))
        yield throttled

    def _telemetry(self):
        replica, tallies, state = self.metrics.replica, self.metrics.snapshot(), self.state
        mqtt = getattr(state, "mqtt", None)
        rows = dict(tallies["telemetry_rows"])
        if mqtt is not None:
            rows[("mqtt", "stored")] = mqtt.status.rows_stored
            rows[("mqtt", "duplicate")] = mqtt.status.duplicates
        family = self._counter(
            "trainclimate_telemetry_rows", "Telemetry rows taken", ["transport", "outcome"]
        )
        for (transport, outcome), n in sorted(rows.items()):
            family.add_metric([replica, transport, outcome], n)
        yield family
        refused = dict(tallies["refused"])
        if mqtt is not None:
            for reason, n in mqtt.status.dropped.items():
                refused[("mqtt", reason)] = n
        family = self._counter(
            "trainclimate_telemetry_refused",
            "Telemetry batches refused (HTTP) or messages dropped (MQTT)",
            ["transport", "reason"],
        )
        for (transport, reason), n in sorted(refused.items()):
            family.add_metric([replica, transport, reason], n)
        yield family
        backfill = getattr(state, "backfill", None)
        family = self._counter(
            "trainclimate_telemetry_refused_rows",
            "Telemetry rows refused outside the backfill horizon",
            ["reason"],
        )
        for reason, n in sorted((backfill.refused if backfill else {}).items()):
            family.add_metric([replica, reason], n)
        yield family
        last = self._last_row(mqtt)
        if last is not None:
            family = self._gauge(
                "trainclimate_telemetry_last_row_timestamp_seconds",
                "When the last telemetry batch was stored (or the start, if live coaches wait)",
            )
            family.add_metric([replica], last)
            yield family
        if self.refresher.live_coaches is not None:
            family = self._gauge("trainclimate_live_coaches", "Live coaches registered")
            family.add_metric([replica], self.refresher.live_coaches)
            yield family

    def _last_row(self, mqtt) -> float | None:
        """The wall time of the last batch stored (HTTP: as stored; MQTT: when a scrape first
        saw its count grow), the start if live coaches are registered and none came since."""
        if mqtt is not None:
            seen = mqtt.status.rows_stored + mqtt.status.duplicates
            if seen != getattr(self, "_mqtt_seen", 0):
                self._mqtt_seen, self._mqtt_at = seen, time.time()
        times = [t for t in (self.metrics.last_row_at, getattr(self, "_mqtt_at", None)) if t]
        if times:
            return max(times)
        return self.started_at if self.refresher.live_coaches else None

    def _mqtt(self):
        mqtt = getattr(self.state, "mqtt", None)
        if mqtt is None:
            return
        replica, status = self.metrics.replica, mqtt.status
        connected = self._gauge("trainclimate_mqtt_connected", "Subscribed to the broker")
        connected.add_metric([replica], 1 if status.connected else 0)
        yield connected
        messages = self._counter(
            "trainclimate_mqtt_messages", "MQTT telemetry messages", ["outcome", "reason"]
        )
        dropped = sum(status.dropped.values())
        messages.add_metric([replica, "stored", ""], status.messages - dropped)
        for reason, n in sorted(status.dropped.items()):
            messages.add_metric([replica, "dropped", reason], n)
        yield messages
        for name, doc, value in (
            ("connections", "Connections to the broker", status.connections),
            ("setpoints_published", "Setpoints published", status.setpoints_published),
            ("database_retries", "Messages retried on the database", status.database_retries),
        ):
            family = self._counter(f"trainclimate_mqtt_{name}", doc)
            family.add_metric([replica], value)
            yield family

    def _capacity(self, db):
        replica, state = self.metrics.replica, self.state
        slots = getattr(state, "admission", None)
        if slots is not None:
            for name, doc, value, kind in (
                ("admission_rejected", "503 answers of the admission", slots.rejected, "c"),
                ("requests_in_progress", "Requests holding a slot", slots.busy, "g"),
                ("requests_waiting", "Requests in line for a slot", slots.waiting, "g"),
            ):
                family = (self._counter if kind == "c" else self._gauge)(
                    f"trainclimate_{name}", doc
                )
                family.add_metric([replica], value)
                yield family
        pool = getattr(getattr(db, "engine", None), "pool", None)
        if pool is not None and hasattr(pool, "checkedout"):
            for name, doc, value in (
                ("db_pool_size", "Connections the pool keeps", pool.size()),
                ("db_pool_in_use", "Connections checked out", pool.checkedout()),
            ):
                family = self._gauge(f"trainclimate_{name}", doc)
                family.add_metric([replica], value)
                yield family
        if self.metrics.database_up is not None:
            up = self._gauge("trainclimate_database_up", "The live loop reached the database")
            up.add_metric([replica], 1 if self.metrics.database_up else 0)
            yield up
        yield from self._disk()

    def _disk(self):
        from trainclimate.paths import home, sqlite_file

        settings = getattr(self.state, "settings", None)
        paths = {home()}
        if settings is not None and (db_file := sqlite_file(settings.database_url)) is not None:
            paths.add(db_file.parent)
        free = self._gauge("trainclimate_disk_free_bytes", "Free space", ["path"])
        size = self._gauge("trainclimate_disk_size_bytes", "Size of the file system", ["path"])
        for path in sorted(paths):
            try:
                usage = shutil.disk_usage(path)
            except OSError:
                continue
            free.add_metric([self.metrics.replica, str(path)], usage.free)
            size.add_metric([self.metrics.replica, str(path)], usage.total)
        yield free
        yield size

    def _model(self):
        replica, state = self.metrics.replica, self.state
        preparation = getattr(state, "preparation", None)
        if preparation is not None:
            status = preparation.status
            family = self._gauge("trainclimate_preparation", "What is prepared", ["task", "state"])
            for each in ("running", "done", "failed"):
                family.add_metric([replica, status.task, each], 1 if status.state == each else 0)
            yield family
            percent = self._gauge("trainclimate_preparation_percent", "How far it is (0–100)")
            percent.add_metric([replica], status.percent)
            yield percent
        model = self.refresher.model
        if model is None:
            return
        version = str(model["version"])
        active = self._gauge("trainclimate_model_active_version", "The active model's version")
        active.add_metric([replica], model["version"])
        yield active
        mae = self._gauge(
            "trainclimate_model_online_mae_celsius",
            f"Online MAE of the active model per prediction step, last {MAE_WINDOW_H:g} h (°C)",
            ["version", "step"],
        )
        for step, value in enumerate(model["mae_per_step_c"], start=1):
            if value is not None:
                mae.add_metric([replica, version, str(step)], value)
        yield mae
        drift = self._gauge("trainclimate_model_drift", "The model health flags drift", ["version"])
        drift.add_metric([replica, version], 1 if model["drift"] else 0)
        yield drift

    def _loops(self):
        scheduler = getattr(self.state, "scheduler", None)
        if scheduler is None:
            return
        now = time.monotonic()
        age = self._gauge("trainclimate_loop_age_seconds", "Since the last iteration", ["loop"])
        limit = self._gauge("trainclimate_loop_limit_seconds", "Longest silence", ["loop"])
        for loop, (at, allowed) in sorted(dict(scheduler.heartbeats).items()):
            age.add_metric([self.metrics.replica, loop], now - at)
            limit.add_metric([self.metrics.replica, loop], allowed)
        yield age
        yield limit


def exposition(metrics: Metrics) -> bytes:
    """The metrics in the Prometheus text format."""
    return generate_latest(metrics.registry)


def install(metrics: Metrics, state, refresher: Refresher | None = None) -> StateCollector:
    """Register the collector of ``state`` (``app.state``) with ``metrics``' registry."""
    collector = StateCollector(metrics, state, refresher or Refresher(), time.time())
    metrics.registry.register(collector)
    return collector
