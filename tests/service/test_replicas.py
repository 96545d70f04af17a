"""Replicas, in process, on SQLite and PostgreSQL: readiness covers the database, the schema's
migration, the model and this replica's own loop (a stopped loop turns ``/ready`` 503 with the
reason); each setpoint records the replica that decided it and ``GET /replicas`` lists them."""

from __future__ import annotations

import socket
import time

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine

from helpers.service import API, at, flat_rows, post_rows, register, wait_for
from trainclimate.service.app import create_app
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store.db import Database, downgrade, head_revision, migrate
from trainclimate.service.store.tokens import create_token


@pytest.fixture
def app_client(settings):
    """The app as replica ``replica-a``, its loops counted as stopped 0.5 s after their last
    iteration, with a viewer's headers."""
    app = create_app(settings.model_copy(update={"replica_name": "replica-a", "loop_ready_s": 0.5}))
    with TestClient(app) as client:
        db = Database(settings.database_url)
        with db.transaction() as s:
            client.viewer = {"Authorization": f"Bearer {create_token(s, 'viewer', 'v')[0]}"}
        db.dispose()
        yield client


def test_ready_names_the_replica_and_its_loops(app_client):
    reply = app_client.get(f"{API}/ready")
    assert reply.status_code == 200, reply.text
    body = reply.json()
    assert body["replica"] == "replica-a" and body["status"] == "ready"
    assert set(body["loops_s"]) == {"live"} and 0 <= body["loops_s"]["live"] < 0.5


def test_a_stopped_loop_turns_ready_503_with_the_reason(app_client):
    app_client.app.state.stop.set()  # the replica's loops stop; the API goes on answering

    def not_ready():
        reply = app_client.get(f"{API}/ready")
        return reply if reply.status_code == 503 else None

    reply = wait_for(not_ready, 10, "/ready to answer 503")
    body = reply.json()
    assert body["detail"].startswith("not ready: the live loop completed no iteration for")
    assert body["reasons"] == [body["detail"].removeprefix("not ready: ")]
    assert app_client.get(f"{API}/health").status_code == 200  # alive, though not ready


def test_a_schema_behind_the_newest_migration_is_not_ready(app_client, settings):
    app_client.app.state.stop.set()  # no loop writes while the schema changes under it
    downgrade(settings.database_url, "0002")
    try:
        reply = app_client.get(f"{API}/ready")
        assert reply.status_code == 503
        assert f"migrations at 0002, not at the newest {head_revision()}" in reply.json()["reasons"]
    finally:
        migrate(settings.database_url)


def test_each_setpoint_records_its_replica_and_replicas_lists_them(app_client, settings):
    app_client.app.state.stop.set()  # only the schedulers below decide
    db = Database(settings.database_url)
    with db.transaction() as s:
        op = {"Authorization": f"Bearer {create_token(s, 'operator', 'o')[0]}"}
    for cid in ("R-A", "R-B"):
        assert register(app_client, op, cid, "R").status_code == 201
        assert post_rows(app_client, op, cid, flat_rows(1, 30)).status_code == 200
    for minutes, name in ((35, "replica-a"), (40, "replica-b"), (45, "replica-b")):
        replica = settings.model_copy(update={"replica_name": name})
        assert Scheduler(db, replica).tick_fleet("live", at(minutes)) == 2
    db.dispose()
    reply = app_client.get(f"{API}/replicas", headers=app_client.viewer)
    assert reply.status_code == 200
    seen = {r["replica"]: r for r in reply.json()}
    assert set(seen) == {"replica-a", "replica-b"}
    assert seen["replica-b"]["coaches"] == ["R-A", "R-B"] and seen["replica-b"]["ticks"] == 4
    assert seen["replica-a"]["this"] and not seen["replica-b"]["this"]
    assert seen["replica-a"]["ticks"] == 2
    assert [r["replica"] for r in reply.json()] == ["replica-b", "replica-a"]  # busiest first


def test_a_database_that_does_not_answer_is_not_ready(app_client, monkeypatch):
    """The probe's connection refused (nothing listens on port 1): 503 naming it."""
    refused = create_engine("postgresql+psycopg://nobody@127.0.0.1:1/none")
    monkeypatch.setattr(app_client.app.state.db, "probe", lambda: refused)
    reply = app_client.get(f"{API}/ready")
    assert reply.status_code == 503
    assert any(r.startswith("database: ") and "connection refused" in r.lower()
               for r in reply.json()["reasons"])  # fmt: skip
    refused.dispose()


def test_a_database_that_hangs_leaves_ready_an_answer_in_time(settings, monkeypatch):
    """The probe's database accepts the connection and never answers: ``/ready`` answers 503
    within its timeout (here 1 s), on threads of its own, and ``/health`` at once meanwhile."""
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)
    port = silent.getsockname()[1]
    hanging = create_engine(f"postgresql+psycopg://nobody@127.0.0.1:{port}/none")
    app = create_app(settings.model_copy(update={"ready_timeout_s": 1.0, "worker_threads": 2}))
    try:
        with TestClient(app) as client:
            monkeypatch.setattr(app.state.db, "probe", lambda: hanging)
            started = time.monotonic()
            reply = client.get(f"{API}/ready")
            took = time.monotonic() - started
            assert reply.status_code == 503 and took < 2.5, (took, reply.text)
            assert "database: no answer within 1 s" in reply.json()["reasons"]
            started = time.monotonic()
            assert client.get(f"{API}/health").status_code == 200
            assert time.monotonic() - started < 0.5
    finally:
        silent.close()
