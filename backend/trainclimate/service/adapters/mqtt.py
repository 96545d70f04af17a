"""The MQTT live feed: the broker and its topics, and the service's side of the feed
(:class:`MqttBridge`, started by ``serve --mqtt URL``). The gateway's side is
:class:`trainclimate.service.adapters.gateway.MqttLink`; the broker's own client for each gateway
token, with Mosquitto's dynamic security plugin, is :mod:`.dynsec`.

Topics, under a prefix (``trainclimate/v1`` unless ``--mqtt-prefix`` says otherwise):

- ``{prefix}/coaches/{coach_id}/telemetry`` — a gateway publishes its coach's 1-minute rows, QoS 1,
  as a batch object ``{"token": "tc_…", "id": "…", "rows": [...]}``: its gateway token, an
  optional batch id (1–64 characters) and the rows in the wire format of
  ``POST /api/v1/telemetry`` (an optional ``coach_id`` must be the topic's).
- ``{prefix}/coaches/{coach_id}/stored`` — the service confirms each batch with an ``id`` once its
  rows are committed, QoS 1, not retained: ``{"coach_id", "id", "through", "rows", "stored",
  "duplicates"}`` (``through`` the batch's newest row time). A gateway that sends its unconfirmed
  rows oldest first, each batch starting at its oldest unconfirmed row, may drop every row up to
  ``through`` when the confirmation of one of its own batches arrives: those were in that batch.
- ``{prefix}/coaches/{coach_id}/setpoint`` — the service publishes every setpoint it issues to a
  live coach, **retained**, QoS 1, as the JSON of ``GET /api/v1/coaches/{id}/setpoint``
  (``coach_id``, ``tick``, ``t_ref_c``, ``t_rule_c``, ``source``, ``reason``, ``valid_until``). A
  gateway that (re)connects gets its coaches' newest setpoint at once. A setpoint whose validity
  has run out on its coach's clock (its newest row at or after ``valid_until``) is never
  published: a replica paused after deciding it publishes nothing stale when it resumes.

**Who sent it.** A subscriber never learns which broker user published a message, so the message
carries its gateway's token, checked in the transaction that stores its rows as the HTTP API
checks a bearer token: a token unknown, revoked or expired (``revoked``) or not for the topic's
coach (``forbidden``: a gateway token of other coaches, a viewer's) drops the message. The token
travels inside the message, so only the service may read the telemetry topics (the broker's ACL)
and the broker should be reached over TLS.

**Exactly once into the database.** The bridge's session with the broker is persistent (a fixed
client id, clean session off) and it acknowledges a message only once its rows are committed
(paho's manual acknowledgement). A message not yet stored when the service, its connection or the
broker went away is delivered again, and rows already stored (same coach and time) are skipped,
so a resent message changes nothing. While the database is unavailable the bridge retries the
message with back-off and acknowledges nothing, so the broker keeps the rest (Mosquitto holds up
to ``max_queued_messages`` per client, 1 000 by default: raise it for a large fleet). What the
broker holds only in memory is lost if it crashes: a gateway keeps its rows until the service
confirms them (``…/stored``) and sends again what was never confirmed.

**Bad messages** — a topic that names no coach, malformed JSON, no token, a token refused, rows the
HTTP API would refuse (422; a row older than the backfill horizon among them, reason
``outside_horizon``, or more than ``max_ahead_min`` ahead of the server's clock, reason
``ahead_of_clock``, their rows counted with the HTTP API's in
:class:`~trainclimate.service.store.commands.Backfill`), a coach not registered, a coach of the
simulated demo fleet — are counted by reason in :attr:`MqttBridge.status` (shown by ``GET
/api/v1/health``), logged with the reason, acknowledged and dropped (never confirmed); they never
stop the feed. A broker that goes away is reconnected with back-off (1 s doubling to 60 s) while the
HTTP API keeps serving.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from urllib.parse import unquote, urlsplit

import paho.mqtt.client as paho
from pydantic import BaseModel, Field, ValidationError
from sqlalchemy import select
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from trainclimate.service.adapters import MQTT_PREFIX
from trainclimate.service.api.schemas.telemetry import MAX_BATCH_ROWS, TelemetryRow
from trainclimate.service.store import commands, liveness
from trainclimate.service.store.commands import (
    AheadOfClockError,
    Backfill,
    ConflictError,
    OutsideHorizonError,
)
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import Coach
from trainclimate.service.store.queries import (
    NotFoundError,
    expired,
    newest_setpoint,
    setpoint_view,
)
from trainclimate.service.store.records import SetpointView, TelemetryRecord
from trainclimate.service.store.telemetry import from_wire
from trainclimate.service.store.tokens import COACH_ID, authenticate

log = logging.getLogger(__name__)

#: Reconnection back-off, s: from the first to the longest wait.
BACKOFF_S = (1, 60)


class _Envelope(BaseModel):
    """A telemetry message's batch id and rows (the token and coach are checked apart)."""

    id: str | None = Field(default=None, min_length=1, max_length=64)
    rows: list[TelemetryRow] = Field(min_length=1, max_length=MAX_BATCH_ROWS)


class BrokerError(ValueError):
    """A broker URL or option that cannot be used (the message says why)."""


@dataclass(frozen=True)
class Broker:
    """Where the broker is and how to reach it: ``mqtt://[USER[:PASSWORD]@]HOST[:PORT]`` (port 1883)
    or ``mqtts://…`` (TLS, port 8883; ``ca_file`` a CA bundle, else the system's); ``prefix`` the
    topics' prefix."""

    host: str
    port: int
    tls: bool = False
    username: str | None = None
    password: str | None = None
    ca_file: Path | None = None
    prefix: str = MQTT_PREFIX

    @classmethod
    def from_url(
        cls,
        url: str,
        *,
        username: str | None = None,
        password: str | None = None,
        ca_file: str | Path | None = None,
        prefix: str = MQTT_PREFIX,
    ) -> Broker:
        """The broker of ``url``; ``username`` and ``password`` win over those in the URL."""
        parts = urlsplit(url)
        if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
            raise BrokerError(f"not an MQTT broker URL (mqtt://HOST[:PORT] or mqtts://…): {url!r}")
        try:
            port = parts.port or (8883 if parts.scheme == "mqtts" else 1883)
        except ValueError:
            raise BrokerError(f"bad port in {url!r}") from None
        if parts.path not in ("", "/") or parts.query:
            raise BrokerError(f"an MQTT broker URL has no path or query: {url!r}")
        prefix = prefix.strip("/")
        if not prefix or any(c in prefix for c in "+#"):
            raise BrokerError(f"the topic prefix must be non-empty, without + or #: {prefix!r}")
        ca = Path(ca_file) if ca_file else None
        if ca is not None and not ca.is_file():
            raise BrokerError(f"no CA file {ca}")
        return cls(
            host=parts.hostname,
            port=port,
            tls=parts.scheme == "mqtts" or ca is not None,
            username=username or (unquote(parts.username) if parts.username else None),
            password=password or (unquote(parts.password) if parts.password else None),
            ca_file=ca,
            prefix=prefix,
        )

    @property
    def address(self) -> str:
        """``mqtt[s]://HOST:PORT`` (without credentials: safe to log and show)."""
        return f"mqtt{'s' if self.tls else ''}://{self.host}:{self.port}"

    def topic(self, coach_id: str, kind: str) -> str:
        """The coach's ``telemetry`` or ``setpoint`` topic."""
        return f"{self.prefix}/coaches/{coach_id}/{kind}"

    def coach_of(self, topic: str, kind: str) -> str | None:
        """The coach id a ``kind`` topic names, None if it names none (or no valid coach id)."""
        head, tail = f"{self.prefix}/coaches/", f"/{kind}"
        if not (topic.startswith(head) and topic.endswith(tail)):
            return None
        coach_id = topic[len(head) : -len(tail)]
        return coach_id if COACH_ID.match(coach_id) else None

    def client(self, client_id: str, *, persistent: bool = False, manual_ack: bool = False):
        """A paho client for this broker (not yet connected): credentials, TLS, and reconnection
        with back-off (:data:`BACKOFF_S`); ``persistent`` keeps the session (and the broker's
        queue of QoS 1 messages for it) across disconnections."""
        c = paho.Client(
            paho.CallbackAPIVersion.VERSION2,
            client_id=client_id,
            clean_session=not persistent,
            manual_ack=manual_ack,
        )
        if self.username:
            c.username_pw_set(self.username, self.password)
        if self.tls:
            c.tls_set(ca_certs=str(self.ca_file) if self.ca_file else None)
            c.tls_insecure_set(False)
        c.reconnect_delay_set(*BACKOFF_S)
        return c


@dataclass
class MqttStatus:
    """The bridge's state and counts since the service started: ``connected`` to ``broker``
    (the telemetry subscription confirmed; ``connections`` how many times); ``messages`` handled
    (stored or dropped), ``rows_stored``, ``duplicates`` (rows already stored), ``dropped`` by
    reason, ``setpoints_published``, ``setpoints_expired`` (not published: their validity had
    run out on their coach's clock), ``confirmations_published`` (batches confirmed on
    ``…/stored``), ``database_retries`` (a message retried while the database was unavailable)
    and the ``last_error``."""

    broker: str
    connected: bool = False
    connections: int = 0
    messages: int = 0
    rows_stored: int = 0
    duplicates: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    setpoints_published: int = 0
    setpoints_expired: int = 0
    confirmations_published: int = 0
    database_retries: int = 0
    last_error: str | None = None


class MessageError(Exception):
    """A message that cannot be stored: ``reason`` (a short key) and the detail."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


@dataclass(frozen=True)
class Batch:
    """A telemetry message as the service takes it: the sender's ``token``, the batch ``id``
    (None: the sender wants no confirmation) and its rows as stored."""

    token: str
    id: str | None
    rows: list[TelemetryRecord]

    @property
    def through(self) -> datetime:
        """The newest row's time."""
        return max(r["time"] for r in self.rows)


def parse_batch(payload: bytes, coach_id: str) -> Batch:
    """The batch a telemetry message for ``coach_id`` holds (see the module docstring);
    :class:`MessageError` if it is not JSON, carries no token, names another coach, or its id
    or a row is out of range."""
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise MessageError("malformed_json", f"not JSON: {exc}") from None
    token = data.get("token") if isinstance(data, dict) else None
    if not isinstance(token, str) or not token:
        raise MessageError("no_token", 'expected {"token": …, "rows": [...]}: no token')
    if data.get("coach_id", coach_id) != coach_id:
        raise MessageError("coach_mismatch", f"coach_id {data['coach_id']!r} is not the topic's")
    try:
        envelope = _Envelope.model_validate({k: data.get(k) for k in ("id", "rows")})
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        detail = f"{len(exc.errors())} error(s), first {where}: {first['msg']}"
        raise MessageError("invalid_rows", detail) from None
    rows = [from_wire(r.model_dump()) for r in envelope.rows]
    return Batch(token=token, id=envelope.id, rows=rows)


def authorize(session: Session, token: str, coach_id: str) -> None:
    """As ``POST /api/v1/telemetry`` checks its bearer token: the token must be valid (else
    ``revoked``: unknown, revoked or expired) and a gateway token scoped to ``coach_id`` or an
    operator's or above (else ``forbidden``); :class:`MessageError` if not."""
    who = authenticate(session, token)
    if who is None:
        raise MessageError("revoked", "the token is unknown, revoked or expired")
    if not (who.serves(coach_id) or who.can("operator")):
        raise MessageError("forbidden", f"the token is not for coach {coach_id!r}")


class MqttBridge:
    """The service's side of the MQTT feed (see the module docstring): a paho network thread
    receives, a worker thread stores, and :meth:`publish_setpoints` (a scheduler listener)
    publishes."""

    def __init__(
        self,
        db: Database,
        broker: Broker,
        *,
        client_id: str,
        valid_for: timedelta,
        backfill: Backfill,
    ):
        self.db = db
        self.broker = broker
        self.valid_for = valid_for
        self.backfill = backfill
        self.status = MqttStatus(broker=broker.address)
        self._inbox: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._work, name="mqtt-store", daemon=True)
        self.client = broker.client(client_id, persistent=True, manual_ack=True)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_subscribe = self._on_subscribe
        self.client.on_message = lambda _c, _u, msg: self._inbox.put(msg)

    # --- connection ----------------------------------------------------------------------------
    def start(self) -> None:
        """Connect in the background (retrying with back-off until the broker answers)."""
        self._worker.start()
        self.client.connect_async(self.broker.host, self.broker.port, keepalive=30)
        self.client.loop_start()

    def stop(self) -> None:
        """Disconnect and stop the threads (messages not yet stored stay with the broker)."""
        self._stop.set()
        self.client.disconnect()
        self.client.loop_stop()
        self._inbox.put(None)
        self._worker.join(timeout=10)

    def _on_connect(self, client, _userdata, _flags, reason, _properties) -> None:
        if reason.is_failure:
            self.status.last_error = f"connection refused: {reason}"
            log.error("MQTT broker %s refused the connection: %s", self.broker.address, reason)
            return
        client.subscribe(self.broker.topic("+", "telemetry"), qos=1)
        self._republish()

    def _on_subscribe(self, _client, _userdata, _mid, reasons, _properties) -> None:
        if any(r.is_failure for r in reasons):
            self.status.last_error = f"subscription refused: {reasons[0]}"
            log.error("MQTT broker %s refused the subscription: %s", self.broker.address, reasons)
            return
        self.status.connected = True  # the feed is live once the broker confirms the subscription
        self.status.connections += 1
        log.info("MQTT: connected to %s", self.broker.address)

    def _on_disconnect(self, _client, _userdata, _flags, reason, _properties) -> None:
        self.status.connected = False
        if not self._stop.is_set():
            self.status.last_error = f"disconnected: {reason}"
            log.warning("MQTT: lost %s (%s); reconnecting", self.broker.address, reason)

    # --- telemetry in --------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            msg = self._inbox.get()
            if msg is None:
                return
            delay = BACKOFF_S[0]
            while not self._stop.is_set():
                try:
                    self.handle(msg.topic, msg.payload)
                    break
                except OperationalError as exc:
                    self.status.database_retries += 1
                    self.status.last_error = f"database unavailable: {str(exc).splitlines()[0]}"
                    log.warning("MQTT: database unavailable, retrying in %d s", delay)
                    self._stop.wait(delay)
                    delay = min(2 * delay, BACKOFF_S[1])
            else:
                return  # stopping: not acknowledged, the broker delivers it again
            self.status.messages += 1
            if msg.qos > 0:
                self.client.ack(msg.mid, msg.qos)

    def handle(self, topic: str, payload: bytes) -> None:
        """Store one telemetry message and confirm it (counted; a bad one dropped with its
        reason). Raises only :class:`~sqlalchemy.exc.OperationalError` (the database is
        unavailable)."""
        try:
            coach_id = self.broker.coach_of(topic, "telemetry")
            if coach_id is None:
                raise MessageError("bad_topic", f"topic {topic!r} names no coach")
            batch = parse_batch(payload, coach_id)
            try:
                with self.db.transaction() as session:
                    authorize(session, batch.token, coach_id)
                    stored, duplicates = commands.ingest(
                        session, coach_id, batch.rows, self.backfill
                    )
            except OutsideHorizonError as exc:
                raise MessageError(Backfill.REASON, str(exc)) from None
            except AheadOfClockError as exc:
                raise MessageError(Backfill.AHEAD, str(exc)) from None
            except NotFoundError as exc:
                raise MessageError("unknown_coach", str(exc)) from None
            except ConflictError as exc:
                raise MessageError("not_live", str(exc)) from None
        except MessageError as exc:
            self.status.dropped[exc.reason] = self.status.dropped.get(exc.reason, 0) + 1
            log.warning("MQTT: dropped a message on %s (%s): %s", topic, exc.reason, exc)
            return
        self.status.rows_stored += stored
        self.status.duplicates += duplicates
        if batch.id is not None:
            self._confirm(coach_id, batch, stored, duplicates)

    def _confirm(self, coach_id: str, batch: Batch, stored: int, duplicates: int) -> None:
        """Tell the gateway its batch is stored (``…/stored``). Not connected: lost, and the
        gateway sends the batch again, which is then confirmed."""
        payload = {
            "coach_id": coach_id,
            "id": batch.id,
            "through": batch.through.isoformat(),
            "rows": len(batch.rows),
            "stored": stored,
            "duplicates": duplicates,
        }
        topic = self.broker.topic(coach_id, "stored")
        info = self.client.publish(topic, json.dumps(payload), qos=1)
        if info.rc == paho.MQTT_ERR_SUCCESS:
            self.status.confirmations_published += 1

    # --- setpoints out ------------------------------------------------------------------------
    def publish_setpoints(self, fleet: str, rows: list[dict]) -> None:
        """Publish the setpoints just issued to live coaches (a scheduler listener), retained —
        those still valid on their coach's clock: a replica paused between deciding and
        publishing (SIGSTOP, a VM migration) publishes nothing it decided before the pause
        that has expired since (counted in ``setpoints_expired``)."""
        if fleet != "live" or not rows:
            return
        views = [setpoint_view(row["coach_id"], row, self.valid_for) for row in rows]
        try:
            with self.db.transaction() as session:
                clocks = liveness.clocks(session, [v["coach_id"] for v in views])
        except OperationalError as exc:  # the clocks unknown: nothing published that may be stale
            log.warning("MQTT: setpoints not published (database unavailable): %s", exc)
            return
        for view in views:
            clock = clocks.get(view["coach_id"])
            if expired(view, clock.time if clock is not None else None):
                self.status.setpoints_expired += 1
                log.warning(
                    "MQTT: setpoint of %s at %s not published: expired on its clock (%s)",
                    view["coach_id"],
                    view["tick"],
                    clock.time,
                )
                continue
            self._publish(view)

    def _republish(self) -> None:
        """On (re)connection: every live coach's newest setpoint still valid on its clock, in
        case one was issued while the broker was away."""
        try:
            with self.db.transaction() as session:
                views = []
                clocks = liveness.clocks(session)
                for coach in session.scalars(select(Coach).where(Coach.fleet == "live")):
                    sp = newest_setpoint(session, coach)
                    if sp is None:
                        continue
                    view = setpoint_view(coach.id, sp, self.valid_for)
                    clock = clocks.get(coach.id)
                    if not expired(view, clock.time if clock is not None else None):
                        views.append(view)
        except OperationalError as exc:
            log.warning("MQTT: setpoints not republished (database unavailable): %s", exc)
            return
        for view in views:
            self._publish(view)

    def _publish(self, view: SetpointView) -> None:
        payload = json.dumps(view, default=lambda t: t.isoformat())
        info = self.client.publish(
            self.broker.topic(view["coach_id"], "setpoint"), payload, qos=1, retain=True
        )
        if info.rc == paho.MQTT_ERR_SUCCESS:
            self.status.setpoints_published += 1
        # else: not connected; the newest is republished on reconnection (_republish)
