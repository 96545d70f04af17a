"""The MQTT live feed against the real broker (Mosquitto on 127.0.0.1:1883, or
``$TRAINCLIMATE_TEST_MQTT_URL``), each test under its own topic prefix:

- the broker URL and the telemetry message (a batch with its gateway's token), and what is
  refused;
- the bridge stores rows exactly once across its own reconnection (the broker keeps what arrived
  while it was away) and a resent message changes nothing;
- bad messages are counted by reason, logged and dropped, and the feed goes on;
- a message's token is checked as the HTTP API checks it: a revoked one is refused at once;
  a stored batch is confirmed to its gateway;
- setpoints are published retained (a gateway connecting later gets them), also the ones issued
  while the broker was away (republished on connection);
- a database that is unavailable delays the acknowledgement, never loses the message;
- ``serve --mqtt`` and ``gateway --mqtt`` as real processes with a gateway token: every row
  stored, the setpoints published back and applied; and every row stored exactly once when the
  broker is killed (kill -9, nothing saved) while the service is away;
- on a private broker with the dynamic security plugin (``serve --mqtt-dynsec``), a gateway
  token gets its own broker client, and revoking the token disconnects it.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import time
import uuid
from datetime import timedelta
from urllib.parse import urlsplit

import httpx
import pytest
from sqlalchemy import func, select
from sqlalchemy.exc import OperationalError

from helpers.processes import CLI, Mosquitto, token_cli
from helpers.service import T0, at, flat_row, flat_rows, rows_per_minute, wait_for
from trainclimate.service.adapters import demo
from trainclimate.service.adapters.dynsec import BrokerClients
from trainclimate.service.adapters.mqtt import (
    Broker,
    BrokerError,
    MessageError,
    MqttBridge,
    parse_batch,
)
from trainclimate.service.store import commands
from trainclimate.service.store.commands import Backfill
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import ApiToken, Setpoint, Telemetry
from trainclimate.service.store.telemetry import to_wire
from trainclimate.service.store.tokens import Principal, create_token, hash_token

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
def fleet_database(db_url):
    """A migrated database: live coaches 7-A (activated) and 7-B, and the demo fleet (D1-A …)."""
    migrate(db_url)
    database = Database(db_url)
    with database.transaction() as s:
        commands.register_coach(s, SYSTEM, "7-A", "7", True)
        commands.register_coach(s, SYSTEM, "7-B", "7", False)
        demo.register(s)
    yield database
    database.dispose()


def new_token(db: Database, role: str, coaches: list[str] | None = None) -> str:
    """A new token of ``role`` (a gateway's scoped to ``coaches``)."""
    with db.transaction() as s:
        token, _ = create_token(s, role, None, coaches)
    return token


@pytest.fixture
def gateway(fleet_database) -> str:
    """A gateway token for 7-A and 7-B."""
    return new_token(fleet_database, "gateway", ["7-A", "7-B"])


def batch(token: str, rows: list[dict], **extra) -> dict:
    """A telemetry message: the token and the rows (stored format), ``extra`` keys added."""
    return {"token": token, "rows": [to_wire(r) for r in rows], **extra}


@pytest.fixture
def bridges(fleet_database, broker):
    """A factory of bridges on ``fleet_database`` and ``broker`` sharing one client id (one
    persistent session); all stopped, and the session removed from the broker, after the test."""
    client_id = f"test-service-{uuid.uuid4().hex[:10]}"
    made: list[MqttBridge] = []

    def make() -> MqttBridge:
        bridge = MqttBridge(
            fleet_database,
            broker,
            client_id=client_id,
            valid_for=VALID_FOR,
            backfill=Backfill(HORIZON),
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


def test_a_message_is_a_batch_with_its_token():
    rows = [to_wire(r) for r in flat_rows(1, 3)]
    got = parse_batch(json.dumps({"token": "tc_x", "rows": rows}).encode(), "7-A")
    assert (got.token, got.id, got.rows, got.through) == ("tc_x", None, flat_rows(1, 3), at(3))
    message = {"token": "tc_x", "id": "gw-1", "coach_id": "7-A", "rows": rows}
    assert parse_batch(json.dumps(message).encode(), "7-A").id == "gw-1"
    # a row or a list of rows carries no token: refused
    for payload in (rows[0], rows, {"rows": rows}, {"token": "", "rows": rows}):
        with pytest.raises(MessageError) as refused:
            parse_batch(json.dumps(payload).encode(), "7-A")
        assert refused.value.reason == "no_token"
    # the wire format is the HTTP API's: the same limits
    bad = {**rows[0], "t_room_c": [21.0, 21.0, 95.0]}
    with pytest.raises(MessageError, match=r"t_room_c: .* within −40…70 °C") as refused:
        parse_batch(json.dumps({"token": "tc_x", "rows": [bad]}).encode(), "7-A")
    assert refused.value.reason == "invalid_rows"
    with pytest.raises(MessageError, match="id: String should have at most 64") as refused:
        parse_batch(json.dumps({"token": "tc_x", "id": "x" * 65, "rows": rows}).encode(), "7-A")
    assert refused.value.reason == "invalid_rows"


# --- the bridge against the broker ----------------------------------------------------------
@needs_broker
def test_rows_are_stored_exactly_once_across_a_reconnection(
    fleet_database, bridges, publisher, gateway
):
    first = bridges()
    publisher.telemetry("7-A", batch(gateway, flat_rows(1, 2)))
    wait_for(lambda: first.status.rows_stored == 2, 10, "the first message")
    first.stop()
    # while the service is away: a new message, and the first one again (a gateway resending)
    publisher.telemetry("7-A", batch(gateway, flat_rows(3, 4)))
    publisher.telemetry("7-A", batch(gateway, flat_rows(1, 2)))
    second = bridges()  # the same persistent session: the broker kept both
    wait_for(lambda: second.status.messages == 2, 10, "the messages kept by the broker")
    assert (second.status.rows_stored, second.status.duplicates) == (2, 2)
    publisher.telemetry("7-A", batch(gateway, [flat_row(at(4))]))  # resent while connected
    wait_for(lambda: second.status.messages == 3, 10, "the resent row")
    assert (second.status.rows_stored, second.status.duplicates) == (2, 3)
    assert telemetry_times(fleet_database, "7-A") == [at(m) for m in (1, 2, 3, 4)]
    assert second.status.connections == 1 and second.status.dropped == {}


@needs_broker
def test_bad_messages_are_counted_and_dropped(fleet_database, bridges, publisher, broker, caplog):
    bridge = bridges()
    operator = new_token(fleet_database, "operator")  # may send any coach's rows, as over HTTP
    good = to_wire(flat_row(at(1)))
    publisher.telemetry("7-A", b"{not json")
    publisher.telemetry("7-A", good)  # a row without its gateway's token
    publisher.telemetry("7-A", {"token": operator, "rows": [{**good, "t_amb_c": float("nan")}]})
    publisher.telemetry("7-A", {"token": operator, "rows": [{**good, "occupancy_pct": -5}]})
    publisher.telemetry("7-A", {"token": operator, "rows": []})
    publisher.telemetry("7-A", {"token": operator, "coach_id": "7-B", "rows": [good]})
    publisher.telemetry("99-Z", {"token": operator, "rows": [good]})
    publisher.telemetry("D1-A", {"token": operator, "rows": [good]})  # the demo fleet's
    publisher.telemetry("", {"token": operator, "rows": [good]})  # prefix/coaches//telemetry
    publisher.telemetry("7-B", {"token": operator, "rows": [good]})  # and the feed goes on
    wait_for(lambda: bridge.status.messages == 10, 10, "ten messages")
    assert bridge.status.dropped == {
        "malformed_json": 1,
        "no_token": 1,
        "invalid_rows": 3,
        "coach_mismatch": 1,
        "unknown_coach": 1,
        "not_live": 1,
        "bad_topic": 1,
    }
    assert bridge.status.rows_stored == 1 and telemetry_times(fleet_database, "7-B") == [at(1)]
    assert (
        telemetry_times(fleet_database, "7-A") == []
        and telemetry_times(fleet_database, "D1-A") == []
    )
    assert bridge.status.connected
    dropped = [r.getMessage() for r in caplog.records if "dropped a message" in r.getMessage()]
    assert len(dropped) == 9 and any("(unknown_coach): no coach '99-Z'" in m for m in dropped)
    assert not any(operator in m for m in dropped)  # a token is never logged


@needs_broker
def test_a_token_is_checked_as_over_http_and_a_revoked_one_refused_at_once(
    fleet_database, bridges, publisher, broker, gateway
):
    """The token a message carries must be valid and for the topic's coach (a gateway token
    scoped to it, or an operator's): revoked, a gateway token of other coaches and a viewer's
    are refused and counted; a batch with an id is confirmed on ``…/stored`` once stored."""
    bridge = bridges()
    confirmations = Confirmations(broker, ["7-A"])
    try:
        publisher.telemetry("7-A", batch(gateway, flat_rows(1, 2), id="gw-1"))
        wait_for(lambda: bridge.status.rows_stored == 2, 10, "the valid token's rows")
        wait_for(lambda: confirmations.got, 10, "the confirmation")
        assert confirmations.got == [
            {"coach_id": "7-A", "id": "gw-1", "through": at(2).isoformat()}
            | {"rows": 2, "stored": 2, "duplicates": 0}
        ]
        with fleet_database.transaction() as s:
            token_id = s.scalar(
                select(ApiToken.id).where(ApiToken.token_hash == hash_token(gateway))
            )
            commands.revoke_token(s, SYSTEM, token_id)
        publisher.telemetry("7-A", batch(gateway, flat_rows(3, 4), id="gw-2"))
        other = new_token(fleet_database, "gateway", ["7-B"])
        publisher.telemetry("7-A", batch(other, flat_rows(3, 4), id="gw-3"))
        publisher.telemetry("7-A", batch(new_token(fleet_database, "viewer"), flat_rows(3, 4)))
        publisher.telemetry("7-A", batch("tc_" + "x" * 43, flat_rows(3, 4)))  # unknown
        wait_for(lambda: bridge.status.messages == 5, 10, "five messages")
        assert bridge.status.dropped == {"revoked": 2, "forbidden": 2}
        assert telemetry_times(fleet_database, "7-A") == [at(1), at(2)]
        assert [c["id"] for c in confirmations.got] == ["gw-1"]  # a refused batch: none
        assert bridge.status.confirmations_published == 1
    finally:
        confirmations.close()


class Confirmations:
    """A gateway's view of the service's confirmations (``…/stored``) for ``coach_ids``."""

    def __init__(self, broker: Broker, coach_ids: list[str]):
        self.got: list[dict] = []
        subscribed = []
        self.client = broker.client(f"test-confirmations-{uuid.uuid4().hex[:10]}")
        self.client.on_message = lambda _c, _u, msg: self.got.append(json.loads(msg.payload))
        self.client.on_subscribe = lambda *_: subscribed.append(True)
        self.client.connect(broker.host, broker.port)
        self.client.subscribe([(broker.topic(c, "stored"), 1) for c in coach_ids])
        self.client.loop_start()
        wait_for(lambda: subscribed, 10, "the subscription to the confirmations")

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def test_rows_outside_the_backfill_horizon_are_dropped_as_over_http(
    fleet_database, broker, gateway
):
    """The bridge's handling of a message, without a broker: a message with a row older than the
    coach's newest less the horizon is dropped whole (reason outside_horizon) and its rows are
    counted where the HTTP API counts its own; a topic whose coach id holds a NUL is no coach's
    (on PostgreSQL too, where such text fails)."""
    backfill = Backfill(HORIZON)
    bridge = MqttBridge(
        fleet_database, broker, client_id="unused", valid_for=VALID_FOR, backfill=backfill
    )
    topic = broker.topic("7-A", "telemetry")
    bridge.handle(topic, json.dumps(batch(gateway, flat_rows(1, 3))).encode())
    stray = [flat_row(T0 - timedelta(days=365)), flat_row(at(4))]
    bridge.handle(topic, json.dumps(batch(gateway, stray)).encode())
    bridge.handle(
        broker.topic("7\x00A", "telemetry"), json.dumps(batch(gateway, stray[1:])).encode()
    )
    assert bridge.status.rows_stored == 3
    assert bridge.status.dropped == {"outside_horizon": 1, "bad_topic": 1}
    assert backfill.refused == {"outside_horizon": 1}
    assert telemetry_times(fleet_database, "7-A") == [at(1), at(2), at(3)]


@needs_broker
def test_setpoints_are_published_retained(fleet_database, bridges, broker):
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
def test_an_expired_setpoint_is_never_published(fleet_database, bridges, broker):
    """A replica paused between deciding a setpoint and publishing it resumes to find its
    coach's clock past the setpoint's validity: it is not published (counted), and the coach's
    retained setpoint stays whatever was valid; a setpoint still valid is published."""
    with (
        fleet_database.transaction() as s
    ):  # 7-A's gateway has reported up to T0 + 20 min meanwhile
        commands.ingest(s, "7-A", flat_rows(1, 20))
        commands.ingest(s, "7-B", flat_rows(1, 5))
    bridge = bridges()
    rows = [
        {"coach_id": "7-A", "tick": at(5), "t_ref_c": 21.4, "t_rule_c": 22.0}
        | {"source": "ddpc", "reason": "ok"},  # valid until T0 + 15 min: expired
        {"coach_id": "7-B", "tick": at(5), "t_ref_c": 22.0, "t_rule_c": 22.0}
        | {"source": "rule", "reason": "inactive"},  # valid until T0 + 15 min; its clock at 5
    ]
    bridge.publish_setpoints("live", rows)
    assert (bridge.status.setpoints_published, bridge.status.setpoints_expired) == (1, 1)
    assert set(retained_setpoints(broker, ["7-B"])) == {"7-B"}
    with pytest.raises(AssertionError, match="timed out"):  # nothing retained for 7-A
        retained_setpoints(broker, ["7-A"], timeout_s=2)
    _clear_retained(broker, ["7-B"])


@needs_broker
def test_setpoints_issued_while_away_are_published_on_connection(fleet_database, bridges, broker):
    with fleet_database.transaction() as s:
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
def test_an_unavailable_database_delays_the_message_never_loses_it(
    fleet_database, bridges, publisher, gateway
):
    bridge = bridges()
    handle, calls = bridge.handle, []

    def flaky(topic, payload):
        calls.append(topic)
        if len(calls) == 1:
            raise OperationalError("INSERT", {}, Exception("database is locked"))
        handle(topic, payload)

    bridge.handle = flaky
    publisher.telemetry("7-A", batch(gateway, flat_rows(1, 3)))
    wait_for(lambda: bridge.status.rows_stored == 3, 10, "the retried message")
    assert len(calls) == 2 and bridge.status.database_retries == 1
    assert "database is locked" in bridge.status.last_error
    with fleet_database.transaction() as s:
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
    hours, minutes = 2.0, 120
    env = {**proc_env, "TRAINCLIMATE_SCHEDULER_INTERVAL_S": "0.01"}
    mqtt = ["--mqtt", MQTT_URL, "--mqtt-prefix", broker.prefix]
    client_id = f"test-serve-{uuid.uuid4().hex[:10]}"
    server = servers(db_url, *mqtt, "--mqtt-client-id", client_id, env=env).start()
    wait_for(lambda: _health(server)["mqtt"]["connected"], 10, "the server's MQTT connection")
    token = token_cli(db_url, "gateway", proc_env, "--coaches", "8-A,8-B")
    # 300×: a setpoint is valid for two ticks of the gateway's clock (2 s here); at 1200× and
    # at 600× a loaded machine (CI, two test workers) published every DDPC setpoint after its
    # validity had run out on its coach's clock, and none was applied; two hours leave an hour
    # of DDPC ticks after the twelve samples of the lead-in
    run = ["--hours", str(hours), "--speedup", "300", "--json", *mqtt]
    done = subprocess.run(
        [*CLI, "gateway", "--server", server.url, "--coaches", "8-A,8-B", "--token", token, *run],
        env=proc_env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    stats = json.loads(done.stdout)
    assert (stats["minutes"], stats["rows_sent"], stats["failed_posts"]) == (120, 240, 0)
    assert stats["rows_unsent"] == 0
    assert stats["sources"].get("ddpc", 0) > 0 and stats["sources"].get("rule", 0) > 0
    assert stats["setpoints_applied"] > minutes  # both coaches, most minutes
    feed = wait_for(
        lambda: (h := _health(server)["mqtt"])["rows_stored"] == 2 * minutes and h, 10, "rows"
    )
    assert feed["dropped"] == {}
    db = Database(db_url)
    try:
        for coach in ("8-A", "8-B"):
            assert len(telemetry_times(db, coach)) == minutes
        with db.transaction() as s:
            live = Setpoint.coach_id.in_(["8-A", "8-B"])
            issued = s.scalar(select(func.count()).select_from(Setpoint).where(live))
    finally:
        db.dispose()
    # how many ticks the server ran in the gateway's 24 seconds depends on the machine's load;
    # that every setpoint it issued went out (or was counted as expired on its coach's clock)
    # does not
    assert issued >= 2 and feed["setpoints_published"] >= 2
    assert feed["setpoints_published"] + feed["setpoints_expired"] >= issued
    server.stop()
    _clear_retained(broker, ["8-A", "8-B"])
    cleaner = broker.client(client_id)
    cleaner.connect(broker.host, broker.port)
    cleaner.disconnect()


def _health(server) -> dict:
    return httpx.get(f"{server.url}/api/v1/health", timeout=5).json()


def test_no_row_is_lost_when_the_broker_crashes_while_the_service_is_away(
    servers, proc_env, tmp_path
):
    """``serve --mqtt`` and ``gateway --mqtt`` on a private broker as the compose demo's, except
    that it saves nothing before it stops (``autosave_interval 0``): the service is stopped, the
    gateway goes on publishing (the broker acknowledges it), the broker is killed with kill -9
    (what it held for the service is lost) and started again, then the service. The gateway
    keeps every row until the service confirms it, so every coach and minute is stored, once."""
    db_url = f"sqlite:///{tmp_path / 'trainclimate.db'}"  # the gateway's part: one database
    users = {"trainclimate-service": "service-pw", "gateway-126": "gateway-pw"}
    mosquitto = Mosquitto(tmp_path / "broker", users, settings={"autosave_interval": "0"})
    env = {**proc_env, "TRAINCLIMATE_MQTT_PASSWORD": "service-pw"}
    mqtt = ["--mqtt", mosquitto.url, "--mqtt-username", "trainclimate-service"]
    server = servers(db_url, *mqtt, env=env).start()
    spy = None
    try:
        wait_for(lambda: _health(server)["mqtt"]["connected"], 30, "the service's connection")
        token = token_cli(db_url, "gateway", proc_env, "--coaches", "126-A,126-B")
        gateway = _gateway_process(server.url, token, mosquitto.url, proc_env, tmp_path)
        wait_for(lambda: _health(server)["mqtt"]["rows_stored"] >= 20, 120, "rows stored")
        server.stop()
        spy = Spy(
            Broker.from_url(mosquitto.url, username="trainclimate-service", password="service-pw")
        )
        wait_for(lambda: spy.rows, 60, "rows published while the service is away")
        time.sleep(5)  # the outage goes on: the gateway keeps its new rows
        mosquitto.kill()  # what it held for the service was in memory only
        away = spy.rows
        mosquitto.start()
        server.start(timeout=120)
        out, err = gateway.communicate(timeout=420)
        assert gateway.returncode == 0, err[-4000:]
        stats = json.loads(out)
        assert stats["rows_unsent"] == 0
        minutes = stats["minutes"]
        expected = {(coach, at(m)) for coach in ("126-A", "126-B") for m in range(1, minutes + 1)}
        stored = rows_per_minute(db_url)
        lost = expected - set(stored)
        duplicated = {key: n for key, n in stored.items() if n > 1}
        extra = set(stored) - expected
        print(
            f"rows published while the service was away: {away}; expected {len(expected)}, "
            f"stored {sum(stored.values())}, lost {len(lost)}, duplicated {len(duplicated)}"
        )
        assert (lost, duplicated, extra) == (set(), {}, set())
        assert stats["rows_sent"] == len(expected)
        feed = wait_for(
            lambda: (h := _health(server)["mqtt"])["rows_stored"] and h, 10, "the feed's counts"
        )
        assert feed["dropped"] == {}
    finally:
        if spy is not None:
            spy.close()
        server.stop()
        mosquitto.stop()


def _gateway_process(url: str, token: str, broker: str, env: dict, tmp_path) -> subprocess.Popen:
    """``trainclimate gateway --mqtt`` for train 126: two hours of its clock at 60×."""
    command = [*CLI, "gateway", "--server", url, "--coaches", "126-A,126-B", "--token", token]
    command += ["--hours", "2", "--speedup", "60", "--quiet", "--json"]
    command += ["--mqtt", broker, "--mqtt-username", "gateway-126"]
    gateway_env = {**env, "TRAINCLIMATE_MQTT_PASSWORD": "gateway-pw"}
    return subprocess.Popen(
        command, env=gateway_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


class Spy:
    """Counts the rows published on every coach's telemetry topic (a client of its own)."""

    def __init__(self, broker: Broker):
        self.rows = 0
        self.client = broker.client(f"test-spy-{uuid.uuid4().hex[:10]}")
        self.client.on_message = self._on_message
        self.client.connect(broker.host, broker.port)
        self.client.subscribe(broker.topic("+", "telemetry"), qos=1)
        self.client.loop_start()

    def _on_message(self, _client, _userdata, msg) -> None:
        self.rows += len(json.loads(msg.payload)["rows"])

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


#: The plugin's admin on the private broker (``mosquitto_ctrl dynsec init``).
ADMIN = ("admin", "admin-pw")


def test_revoking_a_gateway_token_disconnects_its_broker_client(
    db_url, servers, proc_env, tmp_path
):
    """On a private broker with the dynamic security plugin (``deploy/mosquitto/
    mosquitto-dynsec.conf``; the service's client made with ``mosquitto_ctrl`` as
    docs/deployment.md says) and ``serve --mqtt-dynsec``: a gateway token made through the API
    gets its own broker client (its password the token), which publishes its coaches' telemetry,
    gets their confirmations and setpoints, and nothing of other coaches. Revoking the token
    disconnects it and refuses it the broker at once, as HTTP answers 401; a message carrying the
    revoked token sent by another client is refused and counted (``revoked``); and the sweep
    deletes the client of a token revoked while the service did not tell the broker."""
    mosquitto = Mosquitto(tmp_path / "broker", config="mosquitto-dynsec.conf", admin=ADMIN)
    service_client(mosquitto, "trainclimate/v1", "service-pw")
    env = {
        **proc_env,
        "TRAINCLIMATE_MQTT_PASSWORD": "service-pw",
        "TRAINCLIMATE_MQTT_DYNSEC_USERNAME": ADMIN[0],
        "TRAINCLIMATE_MQTT_DYNSEC_PASSWORD": ADMIN[1],
        "TRAINCLIMATE_SCHEDULER_INTERVAL_S": "0.05",
    }
    mqtt = ["--mqtt", mosquitto.url, "--mqtt-username", "trainclimate-service", "--mqtt-dynsec"]
    server = servers(db_url, *mqtt, env=env).start()
    api = f"{server.url}/api/v1"
    gateways: list[GatewayClient] = []
    try:
        wait_for(lambda: _health(server)["mqtt"]["connected"], 30, "the service's connection")
        admin = {"Authorization": f"Bearer {token_cli(db_url, 'admin', proc_env)}"}
        first, second = (_gateway_token(api, admin, ["9-A", "9-B"]) for _ in range(2))
        assert first["mqtt_username"].startswith("tc-gateway-")
        for coach in ("9-A", "9-B"):
            body = {"id": coach, "train_id": "9", "ddpc_active": coach == "9-A"}
            reply = httpx.post(f"{api}/coaches", json=body, headers=_bearer(first["token"]))
            assert reply.status_code in (200, 201), reply.text
        gateway = GatewayClient(mosquitto.url, first, ["9-A", "9-B"])
        gateways.append(gateway)
        assert gateway.granted == [True] * 4
        assert not GatewayClient(mosquitto.url, second, ["8-A"]).closed().granted[0]  # not its own
        for coach in ("9-A", "9-B"):
            gateway.publish(coach, batch(first["token"], flat_rows(1, 12), id=f"{coach}-1"))
        wait_for(lambda: len(gateway.confirmed) == 2, 30, "the confirmations")
        wait_for(lambda: "9-A" in gateway.setpoints, 60, "a setpoint of 9-A")
        token_id = _token_id(api, admin, first["token"])
        assert httpx.delete(f"{api}/tokens/{token_id}", headers=admin).status_code == 200
        wait_for(lambda: gateway.disconnected, 10, "the revoked gateway's disconnection")
        revoked = Broker.from_url(
            mosquitto.url, username=first["mqtt_username"], password=first["token"]
        )
        assert connection_answer(revoked) == "Not authorized"
        reply = httpx.get(f"{api}/coaches/9-A/setpoint", headers=_bearer(first["token"]))
        assert reply.status_code == 401
        # the revoked token in a message of another gateway's client: refused by the service
        other = GatewayClient(mosquitto.url, second, ["9-A"])
        gateways.append(other)
        other.publish("9-A", batch(first["token"], flat_rows(13, 14), id="9-A-2"))
        feed = wait_for(lambda: (h := _health(server)["mqtt"])["dropped"] and h, 30, "the refusal")
        assert feed["dropped"] == {"revoked": 1} and feed["rows_stored"] == 24
        # a token revoked behind the broker's back (the broker away): the sweep deletes its client
        db = Database(db_url)
        try:
            with db.transaction() as s:
                commands.revoke_token(s, SYSTEM, _token_id(api, admin, second["token"]))
            clients = BrokerClients(
                Broker.from_url(mosquitto.url, username=ADMIN[0], password=ADMIN[1])
            )
            swept = clients.sweep(db)  # unless the service's own sweep (every minute) came first
            assert swept in ([second["mqtt_username"]], [])
        finally:
            db.dispose()
        wait_for(lambda: other.disconnected, 10, "the swept gateway's disconnection")
        assert "tc-gateway-" not in mosquitto.ctrl(ADMIN, "listClients")
    finally:
        for g in gateways:
            g.close()
        server.stop()
        mosquitto.stop()


def service_client(mosquitto: Mosquitto, prefix: str, password: str) -> None:
    """The service's broker client and role, made with ``mosquitto_ctrl`` (docs/deployment.md)."""
    name = "trainclimate-service"
    mosquitto.ctrl(ADMIN, "createRole", name)
    for acltype, kind in (
        ("subscribePattern", "telemetry"),
        ("publishClientSend", "setpoint"),
        ("publishClientSend", "stored"),
    ):
        mosquitto.ctrl(ADMIN, "addRoleACL", name, acltype, f"{prefix}/coaches/+/{kind}", "allow")
    mosquitto.ctrl(ADMIN, "createClient", name, "-p", password)
    mosquitto.ctrl(ADMIN, "addClientRole", name, name)


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def _gateway_token(api: str, admin: dict, coaches: list[str]) -> dict:
    """``POST /tokens`` of a gateway token for ``coaches``: the answer."""
    reply = httpx.post(f"{api}/tokens", json={"role": "gateway", "coaches": coaches}, headers=admin)
    assert reply.status_code == 201, reply.text
    return reply.json()


def _token_id(api: str, admin: dict, token: str) -> int:
    """The id of ``token`` (found by its prefix in ``GET /tokens``)."""
    listed = httpx.get(f"{api}/tokens", headers=admin).json()
    [token_id] = [t["id"] for t in listed if t["prefix"] == token[:10]]
    return token_id


class GatewayClient:
    """A gateway on its own broker client (``mqtt_username``, the token as its password),
    subscribed to the setpoints and confirmations of ``coaches``: ``granted`` per subscription,
    the ``setpoints`` and ``confirmed`` batch ids received, ``disconnected`` once the broker
    cut it off."""

    def __init__(self, url: str, token: dict, coaches: list[str]):
        self.broker = Broker.from_url(url, username=token["mqtt_username"], password=token["token"])
        self.setpoints: dict[str, dict] = {}
        self.confirmed: list[str] = []
        self.granted: list[bool] = []
        self.disconnected = False
        self.client = self.broker.client(f"test-{token['mqtt_username']}-{uuid.uuid4().hex[:6]}")
        self.client.on_message = self._on_message
        self.client.on_subscribe = lambda _c, _u, _m, reasons, _p: self.granted.extend(
            not r.is_failure for r in reasons
        )
        self.client.on_disconnect = lambda *_: setattr(self, "disconnected", True)
        self.client.reconnect_delay_set(60, 60)  # no reconnection within the test
        self.client.connect(self.broker.host, self.broker.port)
        kinds = ("setpoint", "stored")
        topics = [(self.broker.topic(c, kind), 1) for c in coaches for kind in kinds]
        self.client.subscribe(topics)
        self.client.loop_start()
        wait_for(lambda: len(self.granted) == len(topics), 10, "the subscriptions' answer")

    def _on_message(self, _client, _userdata, msg) -> None:
        coach = self.broker.coach_of(msg.topic, "setpoint")
        if coach is not None:
            self.setpoints[coach] = json.loads(msg.payload)
        else:
            self.confirmed.append(json.loads(msg.payload)["id"])

    def publish(self, coach: str, message: dict) -> None:
        topic = self.broker.topic(coach, "telemetry")
        self.client.publish(topic, json.dumps(message), qos=1).wait_for_publish(10)

    def closed(self) -> GatewayClient:
        """Disconnected (returned, to read what it got)."""
        self.close()
        return self

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@pytest.mark.slow  # a `serve` process
def test_serve_refuses_a_bad_broker_url(proc_env, small_predictor_file):
    done = subprocess.run(
        [*CLI, "serve", "--mqtt", "http://broker", "--predictor", str(small_predictor_file)],
        env=proc_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "--mqtt: not an MQTT broker URL" in done.stderr


# --- the broker's ACL (deploy/mosquitto, as the compose demo runs it) -----------------------
def test_the_acl_lets_a_gateway_use_only_its_own_coaches(fleet_database, tmp_path):
    """On a broker configured as the compose demo's (no anonymous users; the ACL), the gateway
    of train 126 publishes its coaches' telemetry and reads their setpoints and confirmations;
    what it publishes for another coach never reaches the service, it cannot read other
    setpoints, and a wrong password or no user is refused."""
    users = {"trainclimate-service": "service-pw", "gateway-126": "gateway-pw"}
    mosquitto = Mosquitto(tmp_path / "broker", users)
    try:
        with fleet_database.transaction() as s:
            for coach in ("126-A", "125-A"):
                commands.register_coach(s, SYSTEM, coach, coach[:3], False)
        service = Broker.from_url(
            mosquitto.url, username="trainclimate-service", password="service-pw"
        )
        bridge = MqttBridge(
            fleet_database,
            service,
            client_id="acl-service",
            valid_for=VALID_FOR,
            backfill=Backfill(HORIZON),
        )
        bridge.start()
        wait_for(lambda: bridge.status.connected, 10, "the service's connection")
        gateway = Broker.from_url(mosquitto.url, username="gateway-126", password="gateway-pw")
        token = new_token(
            fleet_database, "operator"
        )  # the broker's ACL alone keeps it to its coaches
        confirmations = Confirmations(gateway, ["126-A"])
        publisher = Publisher(gateway)
        publisher.telemetry("125-A", batch(token, [flat_row(at(1))]))  # another train's: denied
        publisher.telemetry("126-A", batch(token, [flat_row(at(1))], id="126-1"))
        wait_for(lambda: bridge.status.rows_stored == 1, 10, "the gateway's own row")
        wait_for(lambda: confirmations.got, 10, "its confirmation")
        publisher.close()
        confirmations.close()
        assert bridge.status.messages == 1  # the other never reached the service
        assert (
            telemetry_times(fleet_database, "126-A") == [at(1)]
            and telemetry_times(fleet_database, "125-A") == []
        )
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
