"""An onboard gateway emulator (``trainclimate gateway``): a separate process that speaks only the
live feed's protocols, HTTP or MQTT.

It simulates its coaches (one train: the coaches share place, weather and operation, like a pair)
with the thermal simulator, on a clock ``speedup`` times faster than real time, and every minute
of that clock it

- sends each coach's telemetry that the service has not yet confirmed, oldest first, in batches
  that fit the server's body limit and the API's row maximum (:func:`first_batch`; a batch
  answered 413 halves the size for the next) — over HTTP a POST to ``/api/v1/telemetry``, whose
  answer confirms it; over MQTT (``--mqtt URL``) a QoS 1 message on the coach's telemetry topic,
  one at a time, confirmed when the service has stored it (:class:`MqttLink`). A row leaves the
  buffer only once confirmed (the server skips rows it already has, so sending one again is
  harmless): an outage of the server, of the broker or of both, however long, loses no row and
  is caught up after it;
- takes each coach's setpoint — over HTTP a GET of ``/api/v1/coaches/{id}/setpoint`` (a pull),
  over MQTT the newest message on the coach's retained setpoint topic — and applies it while it
  is valid; without one — none issued, expired, or the server unreachable — the HVAC falls back
  to its own T_rule, as a real coach does.

At start it registers its coaches over HTTP (``POST /api/v1/coaches``; an existing coach is left
as it is); while the server cannot be reached it runs on, keeps its telemetry and tries again every
minute; at the end it keeps trying for a minute more to have what is left confirmed. A refusal (a
bad token, a coach of another train, a coach its gateway token is not scoped to) stops it with the
server's answer. Those are all the calls it makes: a ``gateway`` token scoped to its coaches
(``trainclimate token create --role gateway --coaches …``) is all it needs.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import threading
import time
import uuid
from dataclasses import dataclass, field
from datetime import datetime

import httpx
import numpy as np
import pandas as pd

from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.coach.setpoint import apply_setpoint
from trainclimate.service.adapters.mqtt import Broker
from trainclimate.service.api.schemas.telemetry import MAX_BATCH_ROWS
from trainclimate.service.store.records import TelemetryRecord
from trainclimate.service.store.telemetry import rows_from_simulation, to_wire
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.simulator import FleetSimulator

log = logging.getLogger(__name__)


@dataclass
class GatewayStats:
    """What the gateway did (printed as JSON when it stops): ``rows_sent`` the rows the service
    confirmed, ``failed_posts`` the batches not sent (refused or unreachable), ``rows_unsent``
    the rows never confirmed."""

    minutes: int = 0
    rows_sent: int = 0
    failed_posts: int = 0
    rows_unsent: int = 0
    setpoints_applied: int = 0
    fallbacks_to_rule: int = 0
    sources: dict[str, int] = field(default_factory=dict)


#: Waits between attempts to reach the server while it is unreachable: from the first to the
#: longest (doubling), in wall time. [s]
BACKOFF_S = (1.0, 60.0)
#: The header of a JSON body sent as text.
JSON = {"Content-Type": "application/json"}
#: What a setpoint message must hold for the gateway to apply it.
SETPOINT_KEYS = {"t_ref_c", "valid_until", "source"}
#: The bytes of rows in a batch at first: half the server's default body limit (2 MiB). A batch
#: the server refuses as too large (413) halves it.
BATCH_BYTES = 1024 * 1024
#: Over MQTT, how long to wait for the service's confirmation of a batch before sending its oldest
#: row alone again (a probe: the broker may have lost the batch), doubling: the first and the
#: longest wait, in wall time. [s]
CONFIRM_WAIT_S = (5.0, 300.0)


class LinkError(RuntimeError):
    """Telemetry that could not be sent (kept for the next batch)."""


class TooLargeError(LinkError):
    """The server refused a batch as too large (413)."""


@dataclass(frozen=True)
class Batch:
    """A coach's oldest unconfirmed rows as sent: their JSON and the newest row's time."""

    rows: list[str]
    through: datetime


def first_batch(rows: list[TelemetryRecord], max_bytes: int, max_rows: int) -> Batch:
    """The oldest of ``rows`` (sorted by time) whose JSON fits in ``max_bytes`` and
    ``max_rows``, at least one."""
    texts: list[str] = []
    size = 0
    for row in rows[:max_rows]:
        text = json.dumps(to_wire(row))
        size += len(text) + 1
        if texts and size > max_bytes:
            break
        texts.append(text)
    return Batch(texts, rows[len(texts) - 1]["time"])


class HttpLink:
    """Telemetry and setpoints over the HTTP API (``client``: authenticated, at ``/api/v1``): a
    batch is confirmed by the answer to its POST."""

    def __init__(self, client: httpx.Client):
        self.client = client
        self.through: dict[str, datetime] = {}

    def send(self, coach_id: str, batch: Batch) -> None:
        """POST the batch; :class:`TooLargeError` (413) or :class:`LinkError` if it was not
        stored."""
        body = f'{{"coach_id": {json.dumps(coach_id)}, "rows": [{",".join(batch.rows)}]}}'
        try:
            reply = self.client.post("/telemetry", content=body, headers=JSON)
            reply.raise_for_status()
        except httpx.HTTPStatusError as exc:
            if exc.response.status_code == 413:
                raise TooLargeError(str(exc)) from None
            raise LinkError(str(exc)) from None
        except httpx.HTTPError as exc:
            raise LinkError(str(exc)) from None
        self.through[coach_id] = batch.through

    def confirmed(self, coach_id: str) -> datetime | None:
        """The newest row time up to which the coach's rows are stored (None: none yet)."""
        return self.through.get(coach_id)

    def room(self, _coach_id: str) -> int | None:
        """How many rows the link takes now: any (a batch is confirmed as it is sent)."""
        return None

    def setpoint(self, coach_id: str) -> dict | None:
        """The coach's setpoint now (None if it cannot be had)."""
        try:
            reply = self.client.get(f"/coaches/{coach_id}/setpoint")
            reply.raise_for_status()
            return reply.json()
        except httpx.HTTPError as exc:
            log.warning("no setpoint for %s (keeping the last while valid): %s", coach_id, exc)
            return None

    def close(self) -> None:
        """Nothing to close (the HTTP client is the gateway's)."""


@dataclass
class _Awaited:
    """The newest batch of a coach sent over MQTT and not yet confirmed: its id, and when to
    send again after ``wait_s`` without a confirmation (monotonic, s)."""

    id: str
    due: float
    wait_s: float


class MqttLink:
    """Telemetry and setpoints over an MQTT broker (:class:`~.mqtt.Broker`): publishes batches
    QoS 1 on the coaches' telemetry topics, carrying the gateway's ``token`` and an id of their
    own; keeps the newest message of their retained setpoint topics; and takes the service's
    confirmations (``…/stored``) of its own batches.

    One batch per coach awaits its confirmation at a time, and every batch starts at the coach's
    oldest unconfirmed row, so a confirmed batch confirms every row up to its newest. Without a
    confirmation within :data:`CONFIRM_WAIT_S` the oldest row goes again alone (a probe, so a
    broker queueing for a service that is away holds little); after a reconnection the next
    batch goes at once: the broker may have lost what it held."""

    def __init__(
        self, broker: Broker, coach_ids: list[str], client_id: str, timeout_s: float, token: str
    ):
        self.broker = broker
        self.ids = list(coach_ids)
        self.timeout_s = timeout_s
        self.token = token
        self.setpoints: dict[str, dict] = {}
        self.through: dict[str, datetime] = {}
        #: per coach, the batches sent and not yet confirmed: id → newest row time
        self.pending: dict[str, dict[str, datetime]] = {cid: {} for cid in self.ids}
        self.awaited: dict[str, _Awaited] = {}
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._session = uuid.uuid4().hex[:8]
        self.client = broker.client(client_id)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.connect_async(broker.host, broker.port, keepalive=30)
        self.client.loop_start()

    def _on_connect(self, client, _userdata, _flags, reason, _properties) -> None:
        if reason.is_failure:
            log.error("MQTT broker %s refused the gateway: %s", self.broker.address, reason)
            return
        with self._lock:
            self.awaited.clear()  # what the broker held may be lost: send again at once
        kinds = ("setpoint", "stored")
        client.subscribe([(self.broker.topic(c, kind), 1) for c in self.ids for kind in kinds])

    def _on_message(self, _client, _userdata, msg) -> None:
        coach_id = self.broker.coach_of(msg.topic, "setpoint")
        if coach_id is None:
            self._on_stored(self.broker.coach_of(msg.topic, "stored"), msg.payload)
            return
        try:
            setpoint = json.loads(msg.payload)
            if not isinstance(setpoint, dict) or not setpoint.keys() >= SETPOINT_KEYS:
                raise ValueError(f"expected an object with {sorted(SETPOINT_KEYS)}")
        except ValueError as exc:
            log.warning("unreadable setpoint on %s, ignored: %s", msg.topic, exc)
            return
        if coach_id in self.ids:
            self.setpoints[coach_id] = setpoint

    def _on_stored(self, coach_id: str | None, payload: bytes) -> None:
        """A confirmation: if of one of this link's batches, its rows and all older are stored."""
        try:
            batch_id = json.loads(payload).get("id")
        except (ValueError, AttributeError):
            return
        with self._lock:
            through = self.pending.get(coach_id, {}).get(batch_id)
            if through is None:
                return  # another gateway's, or a batch already confirmed
            through = max(through, self.through.get(coach_id, through))
            self.through[coach_id] = through
            self.pending[coach_id] = {
                i: t for i, t in self.pending[coach_id].items() if t > through
            }
            if coach_id in self.awaited and self.awaited[coach_id].id == batch_id:
                del self.awaited[coach_id]

    def send(self, coach_id: str, batch: Batch) -> None:
        """Publish the batch and wait for the broker's acknowledgement; :class:`LinkError` if
        there was none (not connected, or no answer within the time-out)."""
        batch_id = f"{self._session}-{next(self._ids)}"
        rows = ",".join(batch.rows)
        payload = f'{{"token": {json.dumps(self.token)}, "id": "{batch_id}", "rows": [{rows}]}}'
        info = self.client.publish(self.broker.topic(coach_id, "telemetry"), payload, qos=1)
        try:
            info.wait_for_publish(self.timeout_s)
        except (RuntimeError, ValueError) as exc:  # not queued: not connected, queue full
            raise LinkError(f"not published: {exc}") from None
        if not info.is_published():
            raise LinkError(f"no acknowledgement from {self.broker.address}")
        with self._lock:
            self.pending[coach_id][batch_id] = batch.through
            last = self.awaited.get(coach_id)
            wait_s = CONFIRM_WAIT_S[0] if last is None else min(2 * last.wait_s, CONFIRM_WAIT_S[1])
            self.awaited[coach_id] = _Awaited(batch_id, time.monotonic() + wait_s, wait_s)

    def confirmed(self, coach_id: str) -> datetime | None:
        """The newest row time up to which the service confirmed the coach's rows."""
        with self._lock:
            return self.through.get(coach_id)

    def room(self, coach_id: str) -> int | None:
        """How many rows the link takes now: any when no batch awaits its confirmation, none
        while one does, the oldest alone once the wait is over."""
        with self._lock:
            awaited = self.awaited.get(coach_id)
        if awaited is None:
            return None
        return 0 if time.monotonic() < awaited.due else 1

    def setpoint(self, coach_id: str) -> dict | None:
        """The newest setpoint received for the coach (None before any)."""
        return self.setpoints.get(coach_id)

    def close(self) -> None:
        """Disconnect from the broker."""
        self.client.disconnect()
        self.client.loop_stop()


class Gateway:
    """The emulator for ``coach_ids`` of train ``train_id`` (see the module docstring); telemetry
    and setpoints over HTTP, or over MQTT with ``mqtt`` (the broker)."""

    def __init__(
        self,
        server: str,
        token: str,
        coach_ids: list[str],
        *,
        train_id: str,
        active: list[str],
        scenario: str = "parked-heating-nov",
        speedup: float = 60.0,
        hours: float | None = None,
        timeout_s: float = 2.0,
        mqtt: Broker | None = None,
    ):
        self.client = httpx.Client(
            base_url=server.rstrip("/") + "/api/v1",
            headers={"Authorization": f"Bearer {token}"},
            timeout=timeout_s,
        )
        self.ids = list(coach_ids)
        if mqtt is None:
            self.link: HttpLink | MqttLink = HttpLink(self.client)
        else:
            client_id = f"trainclimate-gateway-{train_id}-{os.getpid()}"
            self.link = MqttLink(mqtt, self.ids, client_id, timeout_s, token)
        self.train_id = train_id
        self.active = set(active)
        self.speedup = float(speedup)
        sc = scenarios.get(scenario)
        env1, params = scenarios.build(sc, n_coaches=1, hours=hours)
        env = Environment.side_by_side([env1] * len(self.ids))  # one train: shared conditions
        self.sim = FleetSimulator([params[0]] * len(self.ids), env, seed=sc.seed)
        self.t_ref = np.full(len(self.ids), np.nan)
        self.valid_until: list[pd.Timestamp | None] = [None] * len(self.ids)
        self.buffer: dict[str, list[TelemetryRecord]] = {cid: [] for cid in self.ids}
        self.batch_bytes = BATCH_BYTES
        self.registered = False
        self.stats = GatewayStats()
        #: no attempt to reach the server before this (monotonic, s), and the next wait
        self._retry_at, self._backoff_s = 0.0, BACKOFF_S[0]

    def _unreachable(self) -> None:
        """An attempt failed: wait before the next one, twice as long as last time (capped)."""
        self._retry_at = time.monotonic() + self._backoff_s
        log.warning("server unreachable; next attempt in %.0f s", self._backoff_s)
        self._backoff_s = min(2 * self._backoff_s, BACKOFF_S[1])

    def _reachable(self) -> None:
        self._retry_at, self._backoff_s = 0.0, BACKOFF_S[0]

    def register(self) -> bool:
        """Register the coaches; False while the server is unreachable or unavailable (5xx).
        A refusal (4xx) raises :class:`httpx.HTTPStatusError`."""
        try:
            for cid in self.ids:
                body = {"id": cid, "train_id": self.train_id, "ddpc_active": cid in self.active}
                self.client.post("/coaches", json=body).raise_for_status()
        except httpx.HTTPStatusError as exc:
            if exc.response.status_code < 500:
                raise
            log.warning("coaches not registered (server unavailable): %s", exc)
            self._unreachable()
            return False
        except httpx.TransportError as exc:
            log.warning("coaches not registered (server unreachable): %s", exc)
            self._unreachable()
            return False
        self.registered = True
        self._reachable()
        return True

    def _policy(self, k: int, sim: FleetSimulator) -> np.ndarray:
        now = sim.env.time[k]
        valid = np.array([v is not None and now < v for v in self.valid_until])
        return apply_setpoint(self.t_ref, sim.t_rule(k), valid & (sim.env.mode[k] == MODE_REGULAR))

    def _send(self) -> int:
        """Send what the buffer keeps; returns the rows confirmed. The first failure stops this
        attempt (the rest stays kept) and backs off (:meth:`_unreachable`)."""
        confirmed = 0
        for cid in self.ids:
            try:
                confirmed += self._send_coach(cid)
            except LinkError as exc:
                self.stats.failed_posts += 1
                log.warning("telemetry for %s not sent (kept for the next batch): %s", cid, exc)
                self._unreachable()
                break
        else:
            self._reachable()
        return confirmed

    def _send_coach(self, cid: str) -> int:
        """Send the coach's unconfirmed rows oldest first, a batch at a time while the link
        takes one; returns the rows confirmed. A batch too large for the server halves the
        batches (and raises)."""
        confirmed = self._drop_confirmed(cid)
        while self.buffer[cid] and (room := self.link.room(cid)) != 0:
            batch = first_batch(self.buffer[cid], self.batch_bytes, room or MAX_BATCH_ROWS)
            try:
                self.link.send(cid, batch)
            except TooLargeError:
                self.batch_bytes //= 2
                log.warning(
                    "batch too large for the server: %d bytes from now on", self.batch_bytes
                )
                raise
            confirmed += self._drop_confirmed(cid)
        return confirmed

    def _drop_confirmed(self, cid: str) -> int:
        """Drop the coach's rows the service confirmed (up to the link's confirmed time)."""
        through = self.link.confirmed(cid)
        rows = self.buffer[cid]
        if through is None or not rows:
            return 0
        n = next((i for i, row in enumerate(rows) if row["time"] > through), len(rows))
        self.buffer[cid] = rows[n:]
        self.stats.rows_sent += n
        return n

    def _pull(self) -> None:
        for c, cid in enumerate(self.ids):
            sp = self.link.setpoint(cid)
            if sp is None:
                continue
            if sp["t_ref_c"] is None or sp["valid_until"] is None:
                self.valid_until[c] = None
                continue
            self.t_ref[c] = sp["t_ref_c"]
            self.valid_until[c] = pd.Timestamp(sp["valid_until"])
            self.stats.sources[sp["source"]] = self.stats.sources.get(sp["source"], 0) + 1

    def minute(self) -> None:
        """One minute of the coaches' life: simulate, report, pull the setpoints."""
        k0 = self.sim.k
        steps = round(60.0 / self.sim.dt_s)
        self.sim.run(self._policy, steps=steps)
        now = self.sim.env.time[self.sim.k - 1] + pd.Timedelta(seconds=self.sim.dt_s)
        applied = [v is not None and now <= v for v in self.valid_until]
        self.stats.setpoints_applied += sum(applied)
        self.stats.fallbacks_to_rule += len(applied) - sum(applied)
        for cid, rows in rows_from_simulation(self.sim, k0, self.sim.k, self.ids).items():
            self.buffer[cid].extend(rows)
        sent = 0
        if time.monotonic() >= self._retry_at and (self.registered or self.register()):
            sent = self._send()
            self._pull()
        self.stats.minutes += 1
        kept = sum(len(rows) for rows in self.buffer.values())
        t_ref = ", ".join(
            f"{cid} {t:.1f} °C" if np.isfinite(t) and valid else f"{cid} T_rule"
            for cid, t, valid in zip(self.ids, self.t_ref, applied, strict=True)
        )
        log.info("%s: %d rows sent, %d kept; T_ref %s", now.strftime("%Y-%m-%d %H:%M"), sent,
                 kept, t_ref)  # fmt: skip

    def run(self) -> GatewayStats:
        """Run to the end of the scenario's span, ``speedup`` times faster than real time."""
        self.register()
        wall0 = time.monotonic()
        while self.sim.k + round(60.0 / self.sim.dt_s) <= self.sim.n_steps:
            self.minute()
            ahead = self.stats.minutes * 60.0 / self.speedup - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        try:
            self._flush()
        finally:
            self.link.close()
        return self.stats

    def _flush(self, patience_s: float = 60.0) -> None:
        """At the end: send what is still kept, retrying every second for ``patience_s`` s (wall
        time) while the server is unreachable or has not confirmed it; what is left then is
        counted in ``rows_unsent``."""
        deadline = time.monotonic() + patience_s
        while any(self.buffer.values()) and time.monotonic() < deadline:
            if self.registered or self.register():
                self._send()
            if any(self.buffer.values()):
                time.sleep(1.0)
        self.stats.rows_unsent = sum(len(rows) for rows in self.buffer.values())
        if self.stats.rows_unsent:
            log.error("%d telemetry rows were never confirmed", self.stats.rows_unsent)
