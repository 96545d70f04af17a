"""Gateways publishing over MQTT while a benchmark runs (``bench load``): live coaches in pairs,
one MQTT client per train as its gateway, registered with a gateway token over HTTP and then
publishing a telemetry row per coach per minute of a fast clock, QoS 1; and what the service made
of it (rows stored exactly once, the live loop's ticks, the broker's acknowledgement latency)."""

from __future__ import annotations

import json
import random
import socket
import threading
import time
import uuid
from datetime import datetime, timedelta

import httpx

from trainclimate.bench.common import latency_ms

#: How long a request to the service may take. [s]
TIMEOUT_S = 60.0


class MqttFeed:
    """Gateways feeding the service over MQTT while the HTTP clients ask: ``coaches`` live
    coaches (pairs, one MQTT client per train as its gateway) each publish one telemetry row
    per minute of a clock running ``speedup`` times faster than real time, QoS 1, on their
    topics under ``broker``'s prefix, with the gateway ``token`` for them (no batch id: no
    confirmation asked). The service (``serve --mqtt``) stores them and its live loop ticks on
    them.

    ``publish_s`` holds each message's time from publishing to the broker's acknowledgement
    (PUBACK) [s]; ``published`` counts the rows sent, ``unacknowledged`` those the broker never
    acknowledged; ``minutes`` the clock minutes fed."""

    def __init__(
        self,
        broker,
        token: str,
        coach_ids: list[str],
        start: datetime,
        speedup: float,
        seed: int = 0,
    ):
        self.broker = broker
        self.token = token
        self.speedup = speedup
        self.ids = coach_ids
        self.start_time = start
        self.rng = random.Random(seed)
        self.publish_s: list[float] = []
        self.published = self.minutes = 0
        # (client, message id) → when published / when acknowledged (perf_counter, s), apart:
        # the acknowledgement may come before publish() returns, and paho calls on_publish in
        # its network thread holding its own locks, so no lock of ours may be held around either
        self._sent: dict[tuple[int, int], float] = {}
        self._acked: dict[tuple[int, int], float] = {}
        self._stop = threading.Event()
        self.clients = []
        for i in range(0, len(coach_ids), 2):
            c = broker.client(f"bench-gateway-{uuid.uuid4().hex[:10]}")
            c.on_publish = self._on_publish
            c.connect(broker.host, broker.port)
            c.loop_start()
            self.clients.append((c, coach_ids[i : i + 2]))
        self._thread = threading.Thread(target=self._run, name="bench-mqtt", daemon=True)

    def _on_publish(self, client, _userdata, mid, _reason, _properties) -> None:
        self._acked[(id(client), mid)] = time.perf_counter()

    def _row(self, t, coach: str) -> dict:
        from trainclimate.service.store.records import TelemetryRecord
        from trainclimate.service.store.telemetry import to_wire

        deck = 21.5 + self.rng.uniform(-0.3, 0.3)
        row: TelemetryRecord = {
            "time": t,
            "t_room_up_c": deck + 0.2,
            "t_room_mid_c": deck,
            "t_room_low_c": deck - 0.2,
            "t_ref_c": 22.0,
            "t_rule_c": 22.0,
            "t_amb_c": 2.0,
            "ghi_w_m2": 0.0,
            "q_gt_w_m2": 0.0,
            "q_gs_w_m2": 0.0,
            "occupancy_pct": 0.0,
            "speed_kmh": 0.0,
            "power_kw": 9.0 + self.rng.uniform(-1, 1),
            "mode": "regular",
            "connected": True,
        }
        return to_wire(row)

    def _run(self) -> None:
        period = 60.0 / self.speedup
        t0 = time.perf_counter()
        while not self._stop.is_set():
            t = self.start_time + timedelta(minutes=self.minutes + 1)
            for client, coaches in self.clients:
                for coach in coaches:
                    payload = json.dumps({"token": self.token, "rows": [self._row(t, coach)]})
                    sent = time.perf_counter()
                    info = client.publish(self.broker.topic(coach, "telemetry"), payload, qos=1)
                    self._sent[(id(client), info.mid)] = sent
                    self.published += 1
            self.minutes += 1
            self._stop.wait(max(0.0, t0 + self.minutes * period - time.perf_counter()))

    def start(self) -> None:
        """Start publishing (a minute of the clock every ``60 / speedup`` s)."""
        self._thread.start()

    def stop(self) -> None:
        """Stop publishing, wait up to 10 s for the broker's last acknowledgements, disconnect."""
        self._stop.set()
        self._thread.join(timeout=10)
        deadline = time.monotonic() + 10
        while len(self._acked) < len(self._sent) and time.monotonic() < deadline:
            time.sleep(0.05)
        self.publish_s = [self._acked[k] - t for k, t in self._sent.items() if k in self._acked]
        self.unacknowledged = len(self._sent) - len(self.publish_s)
        for client, _ in self.clients:
            client.disconnect()
            client.loop_stop()


def broker_at(url: str | None, error: type[Exception]):
    """The broker of ``url`` under a prefix of this run's own, or None if none answers there; a
    bad URL raises ``error``."""
    from trainclimate.service.adapters.mqtt import Broker, BrokerError

    if url is None:
        return None
    try:
        broker = Broker.from_url(url, prefix=f"bench-{uuid.uuid4().hex[:10]}/trainclimate/v1")
    except BrokerError as exc:
        raise error(f"--mqtt: {exc}") from None
    try:
        socket.create_connection((broker.host, broker.port), timeout=2).close()
    except OSError:
        return None
    return broker


def register_live(base: str, token: str, coach_ids: list[str]) -> None:
    """Register the live coaches with their gateway token (``POST /api/v1/coaches``): pairs, the
    first of each activated."""
    headers = {"Authorization": f"Bearer {token}"}
    for i, coach in enumerate(coach_ids):
        body = {"id": coach, "train_id": coach.split("-")[0], "ddpc_active": i % 2 == 0}
        reply = httpx.post(f"{base}/api/v1/coaches", json=body, headers=headers, timeout=10)
        if reply.status_code not in (200, 201):
            raise RuntimeError(f"registering {coach} failed: {reply.text}")


def mqtt_result(
    base: str, headers: dict, feed: MqttFeed, sampling_min: float, tolerance: int
) -> dict:
    """What the feed sent and what the service made of it, once its counts stop changing (at
    most 15 s): rows stored (``rows_stored`` of ``/api/v1/health``: exactly once means equal to
    ``published``), dropped, the live coaches' ticks against the clock's 5-min periods, and the
    publish-to-acknowledgement latency."""
    deadline = time.monotonic() + 15
    while True:
        mqtt = httpx.get(f"{base}/api/v1/health", timeout=TIMEOUT_S).json()["mqtt"]
        if mqtt["rows_stored"] + mqtt["duplicates"] >= feed.published:
            break
        if time.monotonic() > deadline:
            break
        time.sleep(0.2)
    issued = {}
    for coach in feed.ids:
        reply = httpx.get(
            f"{base}/api/v1/coaches/{coach}/setpoints",
            params={"start": feed.start_time.isoformat()},
            headers=headers,
            timeout=TIMEOUT_S,
        ).json()
        issued[coach] = len(reply["tick"])
    expected = feed.minutes // sampling_min  # the 5-min periods the clock completed
    return {
        "coaches": len(feed.ids),
        "gateways": len(feed.clients),
        "minutes": feed.minutes,
        "published": feed.published,
        "unacknowledged": feed.unacknowledged,
        "rows_stored": mqtt["rows_stored"],
        "duplicates": mqtt["duplicates"],
        "dropped": mqtt["dropped"],
        "exactly_once": mqtt["rows_stored"] == feed.published and not mqtt["dropped"],
        "publish_latency": latency_ms(feed.publish_s) if feed.publish_s else None,
        "ticks": {
            "expected": expected,
            "issued": issued,
            "behind_at_end": expected - min(issued.values()),
            "on_time": expected - min(issued.values()) <= tolerance,
        },
    }


def mqtt_text(m: dict) -> str:
    """One line (after a newline): what the gateways published and the service stored."""
    pub, t = m["publish_latency"], m["ticks"]
    return (
        f"\nMQTT: {m['gateways']} gateways, {m['coaches']} coaches, "
        f"{m['published']} rows published "
        f"(broker acknowledgement p50 {pub['median_ms']:.1f} ms, p99 {pub['p99_ms']:.1f} ms), "
        f"{m['rows_stored']} stored, {sum(m['dropped'].values())} dropped "
        f"({'exactly once' if m['exactly_once'] else 'NOT exactly once'}); live ticks "
        f"{min(t['issued'].values())}–{max(t['issued'].values())} of {t['expected']:.0f} "
        f"({'on time' if t['on_time'] else 'behind'})"
    )
