"""The MQTT live feed against the real broker (Mosquitto on 127.0.0.1:1883, or
``$TRAINCLIMATE_TEST_MQTT_URL``), each test under its own topic prefix:

- the broker URL and the telemetry message's three forms, and what is refused;
- the bridge stores rows exactly once across its own reconnection (the broker keeps what arrived
  while it was away) and a resent message changes nothing;
- bad messages are counted by reason, logged and dropped, and the feed goes on;
- setpoints are published retained (a gateway connecting later gets them), also the ones issued
  while the broker was away (republished on connection);
- a database that is unavailable delays the acknowledgement, never loses the message;
- ``serve --mqtt`` and ``gateway --mqtt`` as real processes with a gateway token: every row
  stored, the setpoints published back and applied.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import uuid
from datetime import timedelta
from urllib.parse import urlsplit

import pytest
from sqlalchemy import func, select
from sqlalchemy.exc import OperationalError

from service_processes import CLI, Mosquitto, token_cli
from service_support import T0, at, flat_row, flat_rows, wait_for
from trainclimate.service.adapters import demo
from trainclimate.service.adapters.mqtt import (
    Broker,
    BrokerError,
    MessageError,
    MqttBridge,
    parse_rows,
)
from trainclimate.service.store import commands
from trainclimate.service.store.commands import Backfill
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import Setpoint, Telemetry
from trainclimate.service.store.telemetry import to_wire
from trainclimate.service.store.tokens import Principal

MQTT_URL = os.environ.get("TRAINCLIMATE_TEST_MQTT_URL", "mqtt://127.0.0.1:1883")
VALID_FOR = timedelta(minutes=10)
HORIZON = timedelta(days=7)
SYSTEM = Principal("test", "admin")


def _broker_answers() -> bool:
    parts = urlsplit(MQTT_URL)
    try:
        with socket.create_connection((parts.hostname, parts.port or 1883), timeout=1):
            return True
    except OSError:
        return False


needs_broker = pytest.mark.skipif(
    not _broker_answers(), reason=f"no MQTT broker answers at {MQTT_URL} (start mosquitto)"
)


@pytest.fixture
def broker() -> Broker:
    """The test broker, under a prefix of this test's own."""
    return Broker.from_url(MQTT_URL, prefix=f"test-{uuid.uuid4().hex[:10]}/trainclimate/v1")


@pytest.fixture
def db(db_url):
    """A migrated database: live coaches 7-A (activated) and 7-B, and the demo fleet (D1-A …)."""
    migrate(db_url)
    database = Database(db_url)
    with database.transaction() as s:
        commands.register_coach(s, SYSTEM, "7-A", "7", True)
        commands.register_coach(s, SYSTEM, "7-B", "7", False)
        demo.register(s)
    yield database
    database.dispose()


@pytest.fixture
def bridges(db, broker):
    """A factory of bridges on ``db`` and ``broker`` sharing one client id (one persistent
    session); all stopped, and the session removed from the broker, after the test."""
    client_id = f"test-service-{uuid.uuid4().hex[:10]}"
    made: list[MqttBridge] = []

    def make() -> MqttBridge:
        bridge = MqttBridge(
            db, broker, client_id=client_id, valid_for=VALID_FOR, backfill=Backfill(HORIZON)
        )
        made.append(bridge)
        bridge.start()
        wait_for(lambda: bridge.status.connected, 10, "the bridge's connection")
        return bridge

    yield make
    for bridge in made:
        bridge.stop()
    cleaner = broker.client(client_id)  # a clean session replaces the persistent one
    cleaner.connect(broker.host, broker.port)
    cleaner.disconnect()


class Publisher:
    """A plain MQTT client publishing QoS 1 (a gateway, or a misbehaving one)."""

    def __init__(self, broker: Broker):
        self.broker = broker
        self.client = broker.client(f"test-publisher-{uuid.uuid4().hex[:10]}")
        self.client.connect(broker.host, broker.port)
        self.client.loop_start()

    def telemetry(self, coach_id: str, payload) -> None:
        body = payload if isinstance(payload, (bytes, str)) else json.dumps(payload)
        info = self.client.publish(self.broker.topic(coach_id, "telemetry"), body, qos=1)
        info.wait_for_publish(5)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@pytest.fixture
def publisher(broker):
    p = Publisher(broker)
    yield p
    p.close()


def retained_setpoints(broker: Broker, coach_ids: list[str], timeout_s=10) -> dict[str, dict]:
    """What a gateway connecting now receives on the coaches' setpoint topics."""
    got: dict[str, dict] = {}
    client = broker.client(f"test-gateway-{uuid.uuid4().hex[:10]}")

    def on_message(_c, _u, msg):
        got[broker.coach_of(msg.topic, "setpoint")] = {**json.loads(msg.payload), "_r": msg.retain}

    client.on_message = on_message
    client.connect(broker.host, broker.port)
    client.subscribe([(broker.topic(c, "setpoint"), 1) for c in coach_ids])
    client.loop_start()
    try:
        wait_for(lambda: len(got) == len(coach_ids), timeout_s, "the retained setpoints")
    finally:
        client.disconnect()
        client.loop_stop()
    return got


def telemetry_times(db: Database, coach_id: str) -> list:
    with db.transaction() as s:
        q = select(Telemetry.time).where(Telemetry.coach_id == coach_id).order_by(Telemetry.time)
        return list(s.scalars(q))


# --- the broker URL and the message ---------------------------------------------------------
@pytest.mark.parametrize(
    "url, address, user, tls",
    [
        ("mqtt://127.0.0.1", "mqtt://127.0.0.1:1883", None, False),
        ("mqtt://broker.sbb.example:1884", "mqtt://broker.sbb.example:1884", None, False),
        ("mqtts://gw%40124:s3cr%2Ft@broker", "mqtts://broker:8883", "gw@124", True),
    ],
)
def test_broker_url(url, address, user, tls):
    b = Broker.from_url(url)
    assert (b.address, b.username, b.tls) == (address, user, tls)
    assert b.topic("124-A", "telemetry") == "trainclimate/v1/coaches/124-A/telemetry"
    assert b.coach_of("trainclimate/v1/coaches/124-A/setpoint", "setpoint") == "124-A"
    assert b.coach_of("trainclimate/v1/coaches//setpoint", "setpoint") is None
    assert b.coach_of("other/v1/coaches/124-A/setpoint", "setpoint") is None


@pytest.mark.parametrize(
    "url, prefix, message",
    [
        ("http://broker:1883", "trainclimate/v1", "not an MQTT broker URL"),
        ("mqtt://", "trainclimate/v1", "not an MQTT broker URL"),
        ("mqtt://broker:99999", "trainclimate/v1", "bad port"),
        ("mqtt://broker/topic", "trainclimate/v1", "no path or query"),
        ("mqtt://broker", "a/+/b", "without \\+ or #"),
    ],
)
def test_broker_url_refused(url, prefix, message):
    with pytest.raises(BrokerError, match=message):
        Broker.from_url(url, prefix=prefix)


def test_a_message_may_hold_one_row_a_list_or_a_batch():
    rows = [to_wire(r) for r in flat_rows(1, 3)]
    assert parse_rows(json.dumps(rows[0]).encode(), "7-A") == [flat_row(at(1))]
    assert parse_rows(json.dumps(rows).encode(), "7-A") == flat_rows(1, 3)
    batch = {"coach_id": "7-A", "rows": rows}
    assert parse_rows(json.dumps(batch).encode(), "7-A") == flat_rows(1, 3)
    # the wire format is the HTTP API's: the same limits
    bad = {**rows[0], "t_room_c": [21.0, 21.0, 95.0]}
    with pytest.raises(MessageError, match=r"t_room_c: .* within −40…70 °C") as refused:
        parse_rows(json.dumps(bad).encode(), "7-A")
    assert refused.value.reason == "invalid_rows"


# --- the bridge against the broker ----------------------------------------------------------
@needs_broker
def test_rows_are_stored_exactly_once_across_a_reconnection(db, bridges, publisher):
    first = bridges()
    publisher.telemetry("7-A", [to_wire(r) for r in flat_rows(1, 2)])
    wait_for(lambda: first.status.rows_stored == 2, 10, "the first message")
    first.stop()
    # while the service is away: a new message, and the first one again (a gateway resending)
    publisher.telemetry("7-A", [to_wire(r) for r in flat_rows(3, 4)])
    publisher.telemetry("7-A", [to_wire(r) for r in flat_rows(1, 2)])
    second = bridges()  # the same persistent session: the broker kept both
    wait_for(lambda: second.status.messages == 2, 10, "the messages kept by the broker")
    assert (second.status.rows_stored, second.status.duplicates) == (2, 2)
    publisher.telemetry("7-A", [to_wire(flat_row(at(4)))])  # resent while connected
    wait_for(lambda: second.status.messages == 3, 10, "the resent row")
    assert (second.status.rows_stored, second.status.duplicates) == (2, 3)
    assert telemetry_times(db, "7-A") == [at(m) for m in (1, 2, 3, 4)]
    assert second.status.connections == 1 and second.status.dropped == {}


@needs_broker
def test_bad_messages_are_counted_and_dropped(db, bridges, publisher, broker, caplog):
    bridge = bridges()
    good = to_wire(flat_row(at(1)))
    publisher.telemetry("7-A", b"{not json")
    publisher.telemetry("7-A", {**good, "t_amb_c": float("nan")})  # json.dumps writes NaN
    publisher.telemetry("7-A", {**good, "occupancy_pct": -5})
    publisher.telemetry("7-A", {"rows": []})
    publisher.telemetry("7-A", {"coach_id": "7-B", "rows": [good]})
    publisher.telemetry("99-Z", good)
    publisher.telemetry("D1-A", good)  # simulated by the demo fleet
    publisher.telemetry("", good)  # prefix/coaches//telemetry: no coach
    publisher.telemetry("7-B", good)  # and the feed goes on
    wait_for(lambda: bridge.status.messages == 9, 10, "nine messages")
    assert bridge.status.dropped == {
        "malformed_json": 1,
        "invalid_rows": 3,
        "coach_mismatch": 1,
        "unknown_coach": 1,
        "not_live": 1,
        "bad_topic": 1,
    }
    assert bridge.status.rows_stored == 1 and telemetry_times(db, "7-B") == [at(1)]
    assert telemetry_times(db, "7-A") == [] and telemetry_times(db, "D1-A") == []
    assert bridge.status.connected
    dropped = [r.getMessage() for r in caplog.records if "dropped a message" in r.getMessage()]
    assert len(dropped) == 8 and any("(unknown_coach): no coach '99-Z'" in m for m in dropped)


def test_rows_outside_the_backfill_horizon_are_dropped_as_over_http(db, broker):
    """The bridge's handling of a message, without a broker: a message with a row older than the
    coach's newest less the horizon is dropped whole (reason outside_horizon) and its rows are
    counted where the HTTP API counts its own; a topic whose coach id holds a NUL is no coach's
    (on PostgreSQL too, where such text fails)."""
    backfill = Backfill(HORIZON)
    bridge = MqttBridge(db, broker, client_id="unused", valid_for=VALID_FOR, backfill=backfill)
    topic = broker.topic("7-A", "telemetry")
    bridge.handle(topic, json.dumps([to_wire(r) for r in flat_rows(1, 3)]).encode())
    stray = [to_wire(flat_row(T0 - timedelta(days=365))), to_wire(flat_row(at(4)))]
    bridge.handle(topic, json.dumps({"rows": stray}).encode())
    bridge.handle(broker.topic("7\x00A", "telemetry"), json.dumps(stray[1]).encode())
    assert bridge.status.rows_stored == 3
    assert bridge.status.dropped == {"outside_horizon": 1, "bad_topic": 1}
    assert backfill.refused == {"outside_horizon": 1}
    assert telemetry_times(db, "7-A") == [at(1), at(2), at(3)]


@needs_broker
def test_setpoints_are_published_retained(db, bridges, broker):
    bridge = bridges()
    rows = [
        {"coach_id": "7-A", "tick": at(5), "t_ref_c": 21.4, "t_rule_c": 22.0}
        | {"source": "ddpc", "reason": "ok"},
        {"coach_id": "7-B", "tick": at(5), "t_ref_c": 22.0, "t_rule_c": 22.0}
        | {"source": "rule", "reason": "inactive"},
    ]
    bridge.publish_setpoints("demo", rows)  # the demo fleet has no gateway
    assert bridge.status.setpoints_published == 0
    bridge.publish_setpoints("live", rows)
    retained_setpoints(broker, ["7-A", "7-B"])  # they have reached the broker
    got = retained_setpoints(broker, ["7-A", "7-B"])  # a gateway connecting afterwards
    assert got["7-A"] == {
        "coach_id": "7-A",
        "tick": at(5).isoformat(),
        "t_ref_c": 21.4,
        "t_rule_c": 22.0,
        "source": "ddpc",
        "reason": "ok",
        "valid_until": (at(5) + VALID_FOR).isoformat(),
        "_r": True,
    }
    assert got["7-B"]["source"] == "rule"
    _clear_retained(broker, ["7-A", "7-B"])


@needs_broker
def test_setpoints_issued_while_away_are_published_on_connection(db, bridges, broker):
    with db.transaction() as s:
        s.execute(
            Setpoint.__table__.insert(),
            [
                {"coach_id": "7-A", "tick": T0, "t_ref_c": 21.0, "t_rule_c": 22.0}
                | {"source": "override", "reason": "override", "created_at": T0},
                {"coach_id": "7-A", "tick": at(5), "t_ref_c": 21.5, "t_rule_c": 22.0}
                | {"source": "ddpc", "reason": "ok", "created_at": at(5)},
            ],
        )
    bridge = bridges()
    wait_for(lambda: bridge.status.setpoints_published == 1, 10, "the newest setpoint")
    got = retained_setpoints(broker, ["7-A"])
    assert (got["7-A"]["tick"], got["7-A"]["t_ref_c"]) == (at(5).isoformat(), 21.5)
    _clear_retained(broker, ["7-A"])


@needs_broker
def test_an_unavailable_database_delays_the_message_never_loses_it(db, bridges, publisher):
    bridge = bridges()
    handle, calls = bridge.handle, []

    def flaky(topic, payload):
        calls.append(topic)
        if len(calls) == 1:
            raise OperationalError("INSERT", {}, Exception("database is locked"))
        handle(topic, payload)

    bridge.handle = flaky
    publisher.telemetry("7-A", [to_wire(r) for r in flat_rows(1, 3)])
    wait_for(lambda: bridge.status.rows_stored == 3, 10, "the retried message")
    assert len(calls) == 2 and bridge.status.database_retries == 1
    assert "database is locked" in bridge.status.last_error
    with db.transaction() as s:
        assert s.scalar(select(func.count()).select_from(Telemetry)) == 3


def _clear_retained(broker: Broker, coach_ids: list[str]) -> None:
    """Remove retained messages (an empty retained message clears a topic)."""
    client = broker.client(f"test-cleaner-{uuid.uuid4().hex[:10]}")
    client.connect(broker.host, broker.port)
    client.loop_start()
    for c in coach_ids:
        client.publish(broker.topic(c, "setpoint"), b"", qos=1, retain=True).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()


# --- serve --mqtt and gateway --mqtt as processes -------------------------------------------
@needs_broker
def test_gateway_over_mqtt_end_to_end(db_url, servers, proc_env, broker):
    """``serve --mqtt`` and ``gateway --mqtt`` (a gateway token for its two coaches): every
    row arrives through the broker, setpoints come back on the retained topics and are applied,
    the DDPC layer on for the activated coach."""
    hours, minutes = 1.5, 90
    env = {**proc_env, "TRAINCLIMATE_SCHEDULER_INTERVAL_S": "0.01"}
    mqtt = ["--mqtt", MQTT_URL, "--mqtt-prefix", broker.prefix]
    client_id = f"test-serve-{uuid.uuid4().hex[:10]}"
    server = servers(db_url, *mqtt, "--mqtt-client-id", client_id, env=env).start()
    wait_for(lambda: _health(server)["mqtt"]["connected"], 10, "the server's MQTT connection")
    token = token_cli(db_url, "gateway", proc_env, "--coaches", "8-A,8-B")
    run = ["--hours", str(hours), "--speedup", "1200", "--json", *mqtt]
    done = subprocess.run(
        [*CLI, "gateway", "--server", server.url, "--coaches", "8-A,8-B", "--token", token, *run],
        env=proc_env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    stats = json.loads(done.stdout)
    assert (stats["minutes"], stats["rows_sent"], stats["failed_posts"]) == (90, 180, 0)
    assert stats["rows_unsent"] == 0
    assert stats["sources"].get("ddpc", 0) > 0 and stats["sources"].get("rule", 0) > 0
    assert stats["setpoints_applied"] > minutes  # both coaches, most minutes
    feed = wait_for(
        lambda: (h := _health(server)["mqtt"])["rows_stored"] == 2 * minutes and h, 10, "rows"
    )
    assert feed["dropped"] == {} and feed["setpoints_published"] >= 2 * (minutes // 5 - 1)
    db = Database(db_url)
    try:
        for coach in ("8-A", "8-B"):
            assert len(telemetry_times(db, coach)) == minutes
    finally:
        db.dispose()
    server.stop()
    _clear_retained(broker, ["8-A", "8-B"])
    cleaner = broker.client(client_id)
    cleaner.connect(broker.host, broker.port)
    cleaner.disconnect()


def _health(server) -> dict:
    import httpx

    return httpx.get(f"{server.url}/api/v1/health", timeout=5).json()


def test_serve_refuses_a_bad_broker_url(proc_env, model_file):
    done = subprocess.run(
        [*CLI, "serve", "--mqtt", "http://broker", "--predictor", str(model_file)],
        env=proc_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "--mqtt: not an MQTT broker URL" in done.stderr


# --- the broker's ACL (deploy/mosquitto, as the compose demo runs it) -----------------------
def test_the_acl_lets_a_gateway_use_only_its_own_coaches(db, tmp_path):
    """On a broker configured as the compose demo's (no anonymous users; the ACL), the gateway
    of train 126 publishes its coaches' telemetry and reads their setpoints; what it publishes
    for another coach never reaches the service, it cannot read other setpoints, and a wrong
    password or no user is refused."""
    users = {"trainclimate-service": "service-pw", "gateway-126": "gateway-pw"}
    mosquitto = Mosquitto(tmp_path / "broker", users)
    try:
        with db.transaction() as s:
            for coach in ("126-A", "125-A"):
                commands.register_coach(s, SYSTEM, coach, coach[:3], False)
        service = Broker.from_url(
            mosquitto.url, username="trainclimate-service", password="service-pw"
        )
        bridge = MqttBridge(
            db, service, client_id="acl-service", valid_for=VALID_FOR, backfill=Backfill(HORIZON)
        )
        bridge.start()
        wait_for(lambda: bridge.status.connected, 10, "the service's connection")
        gateway = Broker.from_url(mosquitto.url, username="gateway-126", password="gateway-pw")
        publisher = Publisher(gateway)
        publisher.telemetry("125-A", to_wire(flat_row(at(1))))  # another train's coach: denied
        publisher.telemetry("126-A", to_wire(flat_row(at(1))))
        wait_for(lambda: bridge.status.rows_stored == 1, 10, "the gateway's own row")
        publisher.close()
        assert bridge.status.messages == 1  # the other never reached the service
        assert telemetry_times(db, "126-A") == [at(1)] and telemetry_times(db, "125-A") == []
        rows = [
            {"coach_id": c, "tick": at(5), "t_ref_c": 22.0, "t_rule_c": 22.0}
            | {"source": "rule", "reason": "inactive"}
            for c in ("126-A", "125-A")
        ]
        bridge.publish_setpoints("live", rows)
        assert set(retained_setpoints(gateway, ["126-A"])) == {"126-A"}
        assert bridge.status.setpoints_published == 2
        with pytest.raises(AssertionError, match="timed out"):  # 125-A's is not for it
            retained_setpoints(gateway, ["126-A", "125-A"], timeout_s=2)
        bridge.stop()
        assert connection_answer(gateway) == "Success"
        wrong = Broker.from_url(mosquitto.url, username="gateway-126", password="wrong")
        assert connection_answer(wrong) == "Not authorized"
        assert connection_answer(Broker.from_url(mosquitto.url)) == "Not authorized"
    finally:
        mosquitto.stop()


def connection_answer(broker: Broker) -> str:
    """The broker's answer to a connection (its reason string)."""
    answers = []
    client = broker.client(f"test-connect-{uuid.uuid4().hex[:10]}")
    client.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
    client.connect(broker.host, broker.port)
    client.loop_start()
    try:
        return wait_for(lambda: answers and answers[0], 10, "the broker's answer")
    finally:
        client.disconnect()
        client.loop_stop()
