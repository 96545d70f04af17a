"""``GET /api/v1/metrics``, on SQLite and PostgreSQL: after the demo fleet's ticks its series
match the database (ticks, their durations, setpoints by source, each coach by its latest
decision), every series carries the replica, the model's online MAE equals the model health's;
the HTTP answers, failed authentications, 429s and the telemetry taken and refused are counted as
they happen; a ``metrics`` token reads the metrics and nothing else; a scrape runs no query but
the token's check, whatever the fleet's size."""

from __future__ import annotations

import threading
import time
from datetime import UTC

import pytest
from fastapi.routing import APIRoute, iter_route_contexts
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from sqlalchemy import event, func, select

from helpers.service import API, at, flat_rows, post_rows, register, wait_for
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings
from trainclimate.service.store.models import Coach, Setpoint, Train
from trainclimate.service.store.tokens import create_token

REPLICA = "replica-a"


def scrape(client, headers) -> dict[tuple[str, frozenset], float]:
    """The samples of ``GET /metrics``: (name, labels) → value; every one has the replica."""
    reply = client.get(f"{API}/metrics", headers=headers)
    assert reply.status_code == 200, reply.text
    assert reply.headers["content-type"].startswith("text/plain; version=0.0.4")
    out = {}
    for family in text_string_to_metric_families(reply.text):
        for sample in family.samples:
            labels = dict(sample.labels)
            assert labels.pop("replica") == REPLICA, sample
            out[(sample.name, frozenset(labels.items()))] = sample.value
    return out


def value(samples: dict, name: str, **labels) -> float:
    return samples[(name, frozenset(labels.items()))]


def series(samples: dict, name: str) -> dict[frozenset, float]:
    return {labels: v for (n, labels), v in samples.items() if n == name}


def make_tokens(app, *roles: str) -> dict[str, dict[str, str]]:
    out = {}
    with app.state.db.transaction() as session:
        for role in roles:
            coaches = ["C1"] if role == "gateway" else None
            token, _ = create_token(session, role, f"metrics-test-{role}", coaches)
            out[role] = {"Authorization": f"Bearer {token}"}
    return out


@pytest.fixture
def demo(db_url, small_predictor_file):
    """The demo fleet served at 900× until its first DDPC setpoints, then its loops stopped."""
    settings = Settings(
        database_url=db_url,
        predictor_path=small_predictor_file,
        fleet="demo",
        speedup=900,
        scheduler_interval_s=0.05,
        replica_name=REPLICA,
    )
    with TestClient(create_app(settings)) as client:
        db = client.app.state.db

        def ddpc() -> bool:
            with db.sessions() as s:
                return bool(s.scalar(select(func.count()).where(Setpoint.source == "ddpc")))

        wait_for(ddpc, 90, "the first DDPC setpoints")
        time.sleep(1.0)  # a few predictions with what followed them
        client.app.state.stop.set()
        last_tick = client.app.state.metrics.last_tick
        previous = None
        while last_tick.get("demo") != previous:  # the demo loop's last tick is done
            previous = last_tick.get("demo")
            time.sleep(0.5)
        yield client


@pytest.mark.slow  # the demo fleet served until its first DDPC setpoints
def test_the_series_after_the_demo_ticks_match_the_database(demo):
    headers = make_tokens(demo.app, "metrics", "viewer")
    with demo.app.state.db.sessions() as s:
        ticks = s.scalar(select(func.count(func.distinct(Setpoint.tick))))
        by_source = dict(
            s.execute(select(Setpoint.source, func.count()).group_by(Setpoint.source)).all()
        )
        newest = (
            select(Setpoint.coach_id, func.max(Setpoint.tick).label("tick"))
            .group_by(Setpoint.coach_id)
            .subquery()
        )
        latest = s.execute(
            select(Setpoint.source, Setpoint.reason, func.count())
            .join(
                newest,
                (Setpoint.coach_id == newest.c.coach_id) & (Setpoint.tick == newest.c.tick),
            )
            .group_by(Setpoint.source, Setpoint.reason)
        ).all()
        coaches = s.scalar(select(func.count()).select_from(Coach))
    samples = scrape(demo, headers["metrics"])
    assert ticks > 5 and by_source.get("ddpc", 0) > 0
    assert value(samples, "trainclimate_ticks_total", fleet="demo") == ticks
    with demo.app.state.db.sessions() as s:
        newest = s.scalar(select(func.max(Setpoint.tick)))
    newest = newest if newest.tzinfo else newest.replace(tzinfo=UTC)
    last = value(samples, "trainclimate_last_tick_timestamp_seconds", fleet="demo")
    assert last == newest.timestamp()
    assert value(samples, "trainclimate_tick_duration_seconds_count", fleet="demo") == ticks
    assert 0 < value(samples, "trainclimate_tick_duration_seconds_sum", fleet="demo") < ticks * 5
    assert {
        dict(labels)["source"]: v
        for labels, v in series(samples, "trainclimate_setpoints_total").items()
    } == by_source
    assert series(samples, "trainclimate_coaches") == {
        frozenset({"fleet": "demo", "source": src, "reason": why}.items()): n
        for src, why, n in latest
    }
    assert sum(series(samples, "trainclimate_coaches").values()) == coaches == 20
    assert value(samples, "trainclimate_database_up") == 1
    assert value(samples, "trainclimate_preparation", task="predictor model", state="done") == 1
    ages = series(samples, "trainclimate_loop_age_seconds")
    assert {dict(k)["loop"] for k in ages} == {"live", "demo"}
    assert value(samples, "trainclimate_db_pool_size") >= demo.app.state.settings.worker_threads
    assert value(samples, "trainclimate_requests_waiting") == 0
    assert value(samples, "trainclimate_disk_free_bytes", path=str(_home())) > 0
    # the model's figures are refreshed outside the scrape; refreshed now, they are the health's
    demo.app.state.metrics_refresher.refresh(demo.app.state.db, demo.app.state.settings)
    samples = scrape(demo, headers["metrics"])
    health = demo.get(f"{API}/models/active/health?hours=1", headers=headers["viewer"]).json()
    version = str(health["version"])
    assert value(samples, "trainclimate_model_active_version") == health["version"]
    mae = {
        int(dict(labels)["step"]): v
        for labels, v in series(samples, "trainclimate_model_online_mae_celsius").items()
    }
    expected = {k: v for k, v in enumerate(health["mae_per_step_c"], start=1) if v is not None}
    assert expected and mae == pytest.approx(expected)
    assert value(samples, "trainclimate_model_drift", version=version) == int(health["drift"])
    assert value(samples, "trainclimate_live_coaches") == 0


def _home():
    from trainclimate.paths import home

    return home()


@pytest.fixture
def settings(settings):
    """A throttle reached after three failed authentications, a known replica name."""
    return settings.model_copy(update={"auth_failures_burst": 3, "replica_name": REPLICA})


def test_answers_failures_throttling_and_telemetry_are_counted(client):
    headers = make_tokens(client.app, "metrics", "operator")
    register(client, headers["operator"], "L1")
    rows = flat_rows(0, 9)
    body = {"coach_id": "L1", "rows": rows}
    assert post_rows(client, headers["operator"], "L1", rows).status_code == 200
    assert post_rows(client, headers["operator"], "L1", rows[:4]).status_code == 200
    old = flat_rows(-20 * 24 * 60, -20 * 24 * 60)  # 20 days before: outside the 7-day horizon
    assert post_rows(client, headers["operator"], "L1", old).status_code == 422
    assert post_rows(client, headers["operator"], "NOPE", rows[:1]).status_code == 404
    not_a_list = {**body, "rows": "x"}
    reply = client.post(f"{API}/telemetry", json=not_a_list, headers=headers["operator"])
    assert reply.status_code == 422
    bad = {"Authorization": "Bearer tc_" + "A" * 43}
    codes = [client.get(f"{API}/coaches", headers=bad).status_code for _ in range(4)]
    assert codes == [401, 401, 401, 429]
    client.app.state.metrics_refresher.refresh(client.app.state.db, client.app.state.settings)
    metrics = client.app.state.metrics
    # the live loop issues the tick at or before the newest row (the row at 9 min is its minute)
    wait_for(
        lambda: (
            metrics.clock.get("live") == at(9).timestamp()
            and metrics.last_tick.get("live") == at(5).timestamp()
        ),
        10,
        "the live loop to read the clock and issue its tick",
    )
    before = time.time()
    samples = scrape(client, headers["metrics"])
    rows_taken = series(samples, "trainclimate_telemetry_rows_total")
    assert rows_taken == {
        frozenset({"transport": "http", "outcome": "stored"}.items()): 10,
        frozenset({"transport": "http", "outcome": "duplicate"}.items()): 4,
    }
    refused = series(samples, "trainclimate_telemetry_refused_total")
    assert refused == {
        frozenset({"transport": "http", "reason": "invalid"}.items()): 2,  # horizon, not a list
        frozenset({"transport": "http", "reason": "unknown_coach"}.items()): 1,
    }
    assert (
        value(samples, "trainclimate_telemetry_refused_rows_total", reason="outside_horizon") == 1
    )
    assert (
        before - 60
        < value(samples, "trainclimate_telemetry_last_row_timestamp_seconds")
        <= (time.time())
    )
    assert value(samples, "trainclimate_live_coaches") == 1
    live = {"fleet": "live"}
    assert value(samples, "trainclimate_fleet_clock_timestamp_seconds", **live) == at(9).timestamp()
    assert value(samples, "trainclimate_last_tick_timestamp_seconds", **live) == at(5).timestamp()
    assert value(samples, "trainclimate_auth_failures_total") == 3
    assert value(samples, "trainclimate_auth_throttled_total") == 1
    assert value(samples, "trainclimate_http_responses_total", code="429") == 1
    assert value(samples, "trainclimate_http_responses_total", code="401") == 3
    assert value(samples, "trainclimate_http_responses_total", code="422") == 2
    assert value(samples, "trainclimate_admission_rejected_total") == 0
    # register, five batches, four with a bad token (the scrape counts once answered)
    assert value(samples, "trainclimate_http_request_duration_seconds_count") == 10
    assert "trainclimate_mqtt_connected" not in {name for name, _ in samples}  # no --mqtt


def test_a_metrics_token_reads_the_metrics_and_nothing_else(client):
    headers = make_tokens(client.app, "metrics", "gateway", "viewer")
    assert client.get(f"{API}/metrics", headers=headers["viewer"]).status_code == 200
    assert client.get(f"{API}/metrics").status_code == 401
    reply = client.get(f"{API}/metrics", headers=headers["gateway"])
    assert reply.status_code == 403
    assert reply.json()["detail"] == "this needs the metrics role; the token is gateway"
    checked = 0
    for route in iter_route_contexts(client.app.routes):
        if not isinstance(route.original_route, APIRoute) or not route.path.startswith(API):
            continue
        if route.path in (f"{API}/metrics", f"{API}/health", f"{API}/ready"):
            continue
        path = route.path.format(coach_id="C1", train_id="T", version=1, token_id=1, name="nobody")
        for method in route.methods:
            reply = client.request(method, path, headers=headers["metrics"])
            assert reply.status_code == 403, (method, path, reply.text)
            checked += 1
    assert checked >= 30


def test_a_scrape_runs_no_query_but_the_token_check_whatever_the_fleet(client):
    headers = make_tokens(client.app, "metrics", "operator")
    statements: list[str] = []
    engine = client.app.state.db.engine

    def record(_conn, _cursor, statement, *_):
        if threading.current_thread().name != "live-loop":  # the live loop's own, every 50 ms
            statements.append(statement)

    client.app.state.metrics_refresher.at = time.monotonic()  # the figures count as fresh
    event.listen(engine, "before_cursor_execute", record)
    try:
        scrape(client, headers["metrics"])
        small = list(statements)
        with client.app.state.db.transaction() as s:
            s.add_all(Train(id=f"T{i}") for i in range(150))
            s.flush()
            s.add_all(
                Coach(id=f"X{i:04d}", train_id=f"T{i // 2}", fleet="live") for i in range(300)
            )
        statements.clear()
        scrape(client, headers["metrics"])
        large = list(statements)
    finally:
        event.remove(engine, "before_cursor_execute", record)
    assert len(small) == len(large) == 1, small  # the token's
    assert not [q for q in small + large if "setpoints" in q or "telemetry" in q]


def test_the_mqtt_feed_s_state_and_counts(db_url, small_predictor_file, tmp_path):
    """A private Mosquitto configured as the compose broker: a batch stored, a malformed
    message dropped, then the broker killed — the metrics follow."""
    import json as jsonlib

    from helpers.processes import Mosquitto
    from trainclimate.service.adapters.mqtt import Broker
    from trainclimate.service.store import commands
    from trainclimate.service.store.telemetry import to_wire
    from trainclimate.service.store.tokens import Principal

    users = {"trainclimate-service": "svc-pw", "gateway-126": "gw-pw"}
    mosquitto = Mosquitto(tmp_path / "mqtt", users)
    settings = Settings(
        database_url=db_url,
        predictor_path=small_predictor_file,
        scheduler_interval_s=0.05,
        replica_name=REPLICA,
        mqtt_url=mosquitto.url,
        mqtt_username="trainclimate-service",
        mqtt_password="svc-pw",
    )
    try:
        with TestClient(create_app(settings)) as client:
            headers = make_tokens(client.app, "metrics")
            with client.app.state.db.transaction() as s:
                commands.register_coach(s, Principal("t", "admin"), "126-A", "126", True)
                gateway, _ = create_token(s, "gateway", "gw-126", ["126-A"])
            bridge = client.app.state.mqtt
            wait_for(lambda: bridge.status.connected, 15, "the bridge's connection")
            broker = Broker.from_url(mosquitto.url, username="gateway-126", password="gw-pw")
            publisher = broker.client("metrics-test-gateway")
            publisher.connect(broker.host, broker.port)
            publisher.loop_start()
            topic = broker.topic("126-A", "telemetry")
            rows = [to_wire(r) for r in flat_rows(0, 5)]
            for body in (jsonlib.dumps({"token": gateway, "rows": rows}), "{not json"):
                publisher.publish(topic, body, qos=1).wait_for_publish(5)
            publisher.disconnect()
            publisher.loop_stop()
            wait_for(lambda: bridge.status.messages == 2, 15, "both messages handled")
            samples = scrape(client, headers["metrics"])
            assert value(samples, "trainclimate_mqtt_connected") == 1
            assert value(samples, "trainclimate_mqtt_connections_total") == 1
            assert (
                value(samples, "trainclimate_mqtt_messages_total", outcome="stored", reason="") == 1
            )
            dropped = {"outcome": "dropped", "reason": "malformed_json"}
            assert value(samples, "trainclimate_mqtt_messages_total", **dropped) == 1
            stored = {"transport": "mqtt", "outcome": "stored"}
            assert value(samples, "trainclimate_telemetry_rows_total", **stored) == 6
            refused = {"transport": "mqtt", "reason": "malformed_json"}
            assert value(samples, "trainclimate_telemetry_refused_total", **refused) == 1
            assert value(samples, "trainclimate_telemetry_last_row_timestamp_seconds") > 0
            mosquitto.kill()
            wait_for(lambda: not bridge.status.connected, 15, "the bridge to see the broker gone")
            assert value(scrape(client, headers["metrics"]), "trainclimate_mqtt_connected") == 0
    finally:
        mosquitto.stop()
