"""The service starts on both databases, answers health without a token and lists coaches."""

import pytest

from trainclimate.service.store.db import head_revision


def test_health_and_coaches(client, tokens):
    health = client.get("/api/v1/health")
    assert health.status_code == 200 and health.json()["status"] == "ok"
    assert client.get("/api/v1/coaches").status_code == 401
    reply = client.get("/api/v1/coaches", headers=tokens["viewer"])
    assert reply.status_code == 200 and reply.json() == []
    ready = client.get("/api/v1/ready").json()
    assert ready["migrations"] == head_revision() and ready["model_version"] == 1


def test_what_the_server_built_is_frozen_out_of_the_collector_while_it_runs(settings):
    """Started, the app's long-lived objects are out of the garbage collector's full passes
    (``gc.freeze``: the library's modules alone are ≈ 10⁵ objects, whose passes paused requests)
    and the collector runs less often; stopped, they are back in them, so a stopped app's cycles
    can be collected, and the collector runs as before."""
    import gc

    from fastapi.testclient import TestClient

    from trainclimate.service.app import GC_THRESHOLDS, create_app

    gc.unfreeze()
    before = gc.get_threshold()
    with TestClient(create_app(settings)) as client:
        assert client.get("/api/v1/health").status_code == 200
        assert gc.get_freeze_count() > 10_000
        assert gc.get_threshold() == GC_THRESHOLDS != before
    assert gc.get_freeze_count() == 0
    assert gc.get_threshold() == before


def test_serve_json_prints_one_object_then_logs(db_url, servers):
    """``serve --json``: one JSON object on stdout (URL, token, database without its password,
    replica, model status), once it accepts connections."""
    import json

    if not db_url.startswith("sqlite"):
        pytest.skip("the printing does not depend on the database")
    srv = servers(db_url, "--new-token", "viewer", "--replica-name", "r-1", "--json").start()
    line = srv.printed(r"(?m)^\{.*\}$").group(0)
    data = json.loads(line)
    assert data["url"] == f"{srv.url}/" and data["token"].startswith("tc_")
    assert data["dashboard"] == f"{srv.url}/#token={data['token']}"  # the URL that signs in
    assert data["role"] == "viewer" and data["replica"] == "r-1"
    assert data["database"] == db_url and data["model"]["state"] in ("done", "running")
    assert data["mqtt"] is None
    assert "dashboard:" not in srv.output()  # the human lines are not printed with --json
