"""The HTTP API's operations, on SQLite and on PostgreSQL, with the app's live loop running:
overrides (band, expiry, cancel, audit, the loop's use of them), switching the layer per coach,
predictor models, transactions (a failed request changes nothing), CORS and the errors bad
requests get. The pair comparison is in ``test_trains.py``."""

from __future__ import annotations

from datetime import datetime

import pytest
from fastapi import Request
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.exc import OperationalError

from helpers.service import (
    API,
    at,
    count,
    flat_rows,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
    wait_for_tick,
)
from trainclimate.service.api import deps
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings
from trainclimate.service.store import commands, queries
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import AuditLog, Override, PredictorModel


def when(value: str) -> datetime:
    return datetime.fromisoformat(value)


def audit(client, tokens, **params) -> list[dict]:
    reply = client.get(f"{API}/audit", params=params, headers=tokens["viewer"])
    assert reply.status_code == 200
    return reply.json()


# --- overrides ------------------------------------------------------------------------------------
def test_override_lifecycle(client, tokens, settings):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "A")
    body = {"t_ref_c": 23.5, "duration_min": 60, "reason": "passengers report it is cold"}
    early = client.post(f"{API}/coaches/A/override", json=body, headers=op)
    assert early.status_code == 409
    assert early.json() == {
        "detail": "coach 'A' has reported nothing yet: no T_rule to check against"
    }
    post_rows(client, op, "A", flat_rows(1, 30))
    assert wait_for_tick(client, viewer, "A", at(30))["source"] == "rule"

    reply = client.post(f"{API}/coaches/A/override", json=body, headers=op)
    assert reply.status_code == 201
    created = reply.json()
    assert {k: v for k, v in created.items() if k not in ("id", "starts_at", "ends_at")} == {
        "coach_id": "A",
        "t_ref_c": 23.5,
        "reason": "passengers report it is cold",
        "created_by": "test-operator",
        "cancelled_at": None,
        "cancelled_by": None,
        "active": True,
    }
    assert (when(created["starts_at"]), when(created["ends_at"])) == (at(30), at(90))
    coach = client.get(f"{API}/coaches/A", headers=viewer).json()
    assert coach["status"] == "override" and when(coach["override_until"]) == at(90)
    entry = audit(client, tokens, target="A")[0]
    assert {k: entry[k] for k in ("user", "role", "action", "reason")} == {
        "user": "test-operator",
        "role": "operator",
        "action": "override.create",
        "reason": "passengers report it is cold",
    }
    assert entry["detail"] == {
        "override_id": created["id"],
        "t_ref_c": 23.5,
        "duration_min": 60.0,
        "t_rule_c": 22.0,
    }

    # the next tick applies it; the time series shows it from the minute after that tick
    post_rows(client, op, "A", flat_rows(31, 36))
    sp = wait_for_tick(client, viewer, "A", at(35))
    assert (sp["source"], sp["reason"], sp["t_ref_c"]) == ("override", "override", 23.5)
    assert when(sp["valid_until"]) == at(45)
    (listed,) = client.get(f"{API}/coaches", headers=viewer).json()
    assert {k: listed[k] for k in ("id", "train_id", "ddpc_active", "mode", "status")} == {
        "id": "A",
        "train_id": "T",
        "ddpc_active": True,
        "mode": "regular",
        "status": "override",
    }
    assert (listed["t_rule_c"], listed["t_ref_c"], listed["t_room_c"]) == (22.0, 23.5, [21.5] * 3)
    ts = client.get(f"{API}/coaches/A/timeseries", headers=viewer).json()
    assert ts["source"] == [None] * 30 + ["rule"] * 5 + ["override"]
    listed = client.get(f"{API}/coaches/A/overrides", headers=viewer).json()
    assert [(o["id"], o["active"]) for o in listed] == [(created["id"], True)]

    # DELETE ends it, audited; a second DELETE finds nothing
    ended = client.delete(f"{API}/coaches/A/override", params={"reason": "fixed"}, headers=op)
    assert ended.status_code == 200
    assert (ended.json()["active"], ended.json()["cancelled_by"]) == (False, "test-operator")
    assert when(ended.json()["cancelled_at"]) == at(36)
    entry = audit(client, tokens, target="A")[0]
    assert (entry["action"], entry["user"], entry["reason"]) == (
        "override.cancel",
        "test-operator",
        "fixed",
    )
    assert entry["detail"] == {"override_id": created["id"]}
    again = client.delete(f"{API}/coaches/A/override", headers=op)
    assert again.status_code == 404
    assert again.json() == {"detail": "coach 'A' has no override in force"}
    assert client.get(f"{API}/coaches/A", headers=viewer).json()["override_until"] is None
    post_rows(client, op, "A", flat_rows(37, 41))
    assert wait_for_tick(client, viewer, "A", at(40))["source"] == "rule"  # warm-up again
    assert [a["action"] for a in audit(client, tokens, target="A")] == [
        "override.cancel",
        "override.create",
        "coach.register",
    ]


def test_override_outside_the_band_is_refused_and_nothing_stored(client, tokens, settings):
    op = tokens["operator"]
    register(client, op, "A")
    register(client, op, "B")
    post_rows(client, op, "A", flat_rows(1, 10, t_rule_c=21.0, t_ref_c=21.0))
    url = f"{API}/coaches/A/override"
    audit_rows = count(settings.database_url, AuditLog)
    for value in (23.01, 18.99, 30.0, -5.0):
        reply = client.post(
            url, json={"t_ref_c": value, "duration_min": 30, "reason": "x"}, headers=op
        )
        assert reply.status_code == 422, value
        assert reply.json() == {
            "detail": f"t_ref_c {value:g} °C is outside T_rule ± 2 K (19.0 … 23.0 °C)"
        }
    malformed = [
        {"t_ref_c": 21.5, "duration_min": 30},
        {"t_ref_c": 21.5, "duration_min": 30, "reason": ""},
        {"t_ref_c": 21.5, "duration_min": 0, "reason": "x"},
        {"t_ref_c": 21.5, "duration_min": -10, "reason": "x"},
        {"t_ref_c": 21.5, "duration_min": 24 * 60 + 1, "reason": "x"},
        {"t_ref_c": "warm", "duration_min": 30, "reason": "x"},
        {"t_ref_c": 21.5, "duration_min": 30, "reason": "x", "until": "tomorrow"},
        {"duration_min": 30, "reason": "x"},
    ]
    for body in malformed:
        reply = client.post(url, json=body, headers=op)
        assert reply.status_code == 422 and "detail" in reply.json(), body
    for raw in ('{"t_ref_c": NaN, "duration_min": 30, "reason": "x"}', '{"t_ref_c": 21.5,'):
        reply = client.post(url, content=raw, headers={**op, "Content-Type": "application/json"})
        assert reply.status_code == 422 and "detail" in reply.json(), raw
    nan = '{"t_ref_c": NaN, "duration_min": 30, "reason": "x"}'
    reply = client.post(url, content=nan, headers={**op, "Content-Type": "application/json"})
    [error] = reply.json()["detail"]
    assert error["loc"] == ["body", "t_ref_c"] and "finite" in error["msg"]
    assert "input" not in error
    assert count(settings.database_url, Override) == 0
    assert count(settings.database_url, AuditLog) == audit_rows
    # a coach without telemetry (no clock of its own: another coach's is not its) cannot be
    # overridden; an unknown one is 404
    reply = client.post(
        f"{API}/coaches/B/override",
        json={"t_ref_c": 21, "duration_min": 5, "reason": "x"},
        headers=op,
    )
    assert reply.status_code == 409 and reply.json() == {
        "detail": "coach 'B' has reported nothing yet: no T_rule to check against"
    }
    reply = client.post(
        f"{API}/coaches/Z/override",
        json={"t_ref_c": 21, "duration_min": 5, "reason": "x"},
        headers=op,
    )
    assert reply.status_code == 404 and reply.json() == {"detail": "no coach 'Z'"}
    # the band's edges are in it
    for value in (19.0, 23.0):
        reply = client.post(
            url, json={"t_ref_c": value, "duration_min": 30, "reason": "edge"}, headers=op
        )
        assert reply.status_code == 201, value
    # the second replaced the first
    rows = client.get(f"{API}/coaches/A/overrides", headers=tokens["viewer"]).json()
    assert [(o["t_ref_c"], o["active"], o["cancelled_by"]) for o in rows] == [
        (23.0, True, None),
        (19.0, False, "test-operator"),
    ]


def test_a_failed_request_changes_nothing(client, tokens, settings, monkeypatch):
    """Every write is one transaction: an error after part of it was written (here the audit
    entry failing after the old override was cancelled and the new one inserted) leaves the
    database as it was; and a commit that fails gives an error, not a 2xx."""
    op = tokens["operator"]
    register(client, op, "A")
    post_rows(client, op, "A", flat_rows(1, 10))
    body = {"t_ref_c": 21.0, "duration_min": 30, "reason": "first"}
    first = client.post(f"{API}/coaches/A/override", json=body, headers=op).json()
    audited = count(settings.database_url, AuditLog)
    real_audit = commands.audit

    def failing_audit(session, who, action, *args, **kwargs):
        if action == "override.create":
            raise queries.RequestError("the audit log refused the entry")
        return real_audit(session, who, action, *args, **kwargs)

    monkeypatch.setattr(commands, "audit", failing_audit)
    body = {"t_ref_c": 23.0, "duration_min": 30, "reason": "second"}
    reply = client.post(f"{API}/coaches/A/override", json=body, headers=op)
    assert reply.status_code == 422
    assert reply.json() == {"detail": "the audit log refused the entry"}
    monkeypatch.setattr(commands, "audit", real_audit)
    rows = client.get(f"{API}/coaches/A/overrides", headers=tokens["viewer"]).json()
    assert [(o["id"], o["t_ref_c"], o["active"], o["cancelled_at"]) for o in rows] == [
        (first["id"], 21.0, True, None)
    ]
    assert count(settings.database_url, AuditLog) == audited

    # the commit itself fails (the connection drops at the end of the request)
    def session_that_cannot_commit(request: Request):
        with request.app.state.db.sessions() as s:
            s.begin()
            yield s
            s.rollback()
            raise OperationalError("COMMIT", {}, Exception("server closed the connection"))

    client.app.dependency_overrides[deps.session] = session_that_cannot_commit
    try:
        body = {"active": False, "reason": "maintenance"}
        reply = client.put(f"{API}/coaches/A/controller", json=body, headers=op)
    finally:
        client.app.dependency_overrides.clear()
    assert reply.status_code == 503
    assert "server closed the connection" in reply.json()["detail"]
    assert client.get(f"{API}/coaches/A", headers=tokens["viewer"]).json()["ddpc_active"] is True
    assert count(settings.database_url, AuditLog) == audited


# --- the layer per coach --------------------------------------------------------------------------
def test_switching_the_controller_per_coach(client, tokens, settings):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "A")
    register(client, op, "B", active=False)
    post_rows(client, op, "A", flat_rows(1, 10))
    wait_for_tick(client, viewer, "A", at(10))
    url = f"{API}/coaches/A/controller"
    body = {"active": False, "reason": "HVAC maintenance"}
    assert client.put(url, json=body, headers=viewer).status_code == 403
    for bad in (
        {"active": False},
        {"active": False, "reason": ""},
        {"active": "maybe", "reason": "x"},
        {"active": False, "reason": "x", "until": "never"},
        {"reason": "x"},
    ):
        assert client.put(url, json=bad, headers=op).status_code == 422, bad
    missing = client.put(f"{API}/coaches/Z/controller", json=body, headers=op)
    assert missing.status_code == 404 and missing.json() == {"detail": "no coach 'Z'"}
    assert [a["action"] for a in audit(client, tokens, target="A")] == ["coach.register"]

    reply = client.put(url, json=body, headers=op)
    assert reply.status_code == 200 and reply.json()["ddpc_active"] is False
    entry = audit(client, tokens, target="A")[0]
    assert {k: entry[k] for k in ("user", "role", "action", "reason", "detail")} == {
        "user": "test-operator",
        "role": "operator",
        "action": "controller.deactivate",
        "reason": "HVAC maintenance",
        "detail": {"before": True, "after": False},
    }
    assert client.get(f"{API}/trains/T", headers=viewer).json()["activated"] == []
    post_rows(client, op, "A", flat_rows(11, 15))
    sp = wait_for_tick(client, viewer, "A", at(15))
    assert (sp["source"], sp["reason"], sp["t_ref_c"]) == ("rule", "inactive", 22.0)
    assert client.get(f"{API}/coaches/A", headers=viewer).json()["status"] == "inactive"

    reply = client.put(url, json={"active": True, "reason": "maintenance done"}, headers=op)
    assert reply.status_code == 200 and reply.json()["ddpc_active"] is True
    entry = audit(client, tokens, target="A")[0]
    assert (entry["action"], entry["reason"], entry["detail"]) == (
        "controller.activate",
        "maintenance done",
        {"before": False, "after": True},
    )
    train = client.get(f"{API}/trains/T", headers=viewer).json()
    assert (train["activated"], train["deactivated"]) == (["A"], ["B"])


# --- predictor models -----------------------------------------------------------------------------
def test_models(client, tokens, settings):
    viewer, admin = tokens["viewer"], tokens["admin"]
    models = client.get(f"{API}/models", headers=viewer).json()
    assert [(m["version"], m["active"], m["method"], m["rho"], m["horizon"]) for m in models] == [
        (1, True, "transient", 12, 6)
    ]
    assert models[0]["sampling_min"] == 5.0
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:  # a second version, as a training job would register it
            v1 = s.scalar(select(PredictorModel).where(PredictorModel.version == 1))
            s.add(
                PredictorModel(
                    version=2,
                    method=v1.method,
                    rho=v1.rho,
                    horizon=v1.horizon,
                    sampling_min=v1.sampling_min,
                    artifact=v1.artifact,
                    info={"note": "retrained"},
                    state="candidate",
                )
            )
    finally:
        db.dispose()
    url = f"{API}/models/2/activate"
    assert client.post(url, params={"reason": "x"}, headers=tokens["operator"]).status_code == 403
    assert client.post(url, headers=admin).status_code == 422  # a reason is required
    assert client.post(url, params={"reason": ""}, headers=admin).status_code == 422
    missing = client.post(f"{API}/models/7/activate", params={"reason": "x"}, headers=admin)
    assert missing.status_code == 404 and missing.json() == {"detail": "no model version 7"}
    assert (
        client.post(f"{API}/models/two/activate", params={"reason": "x"}, headers=admin).status_code
        == 422
    )
    assert [m["active"] for m in client.get(f"{API}/models", headers=viewer).json()] == [
        True,
        False,
    ]
    assert audit(client, tokens) == []

    reply = client.post(url, params={"reason": "better validation MAE"}, headers=admin)
    assert reply.status_code == 200
    assert (reply.json()["version"], reply.json()["active"]) == (2, True)
    assert [
        (m["version"], m["active"]) for m in client.get(f"{API}/models", headers=viewer).json()
    ] == [
        (1, False),
        (2, True),
    ]
    assert client.get(f"{API}/ready").json()["model_version"] == 2
    (entry,) = audit(client, tokens)
    assert {k: entry[k] for k in ("user", "role", "action", "target", "reason")} == {
        "user": "test-admin",
        "role": "admin",
        "action": "model.activate",
        "target": "model:2",
        "reason": "better validation MAE",
    }


# --- CORS -----------------------------------------------------------------------------------------
PREFLIGHT = {
    "Access-Control-Request-Method": "GET",
    "Access-Control-Request-Headers": "authorization",
}


@pytest.fixture
def sqlite_settings(tmp_path, small_predictor_file):
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'cors.db'}", predictor_path=small_predictor_file
    )


def test_no_cors_by_default(sqlite_settings):
    """The dashboard is served by the same origin: other origins get no CORS headers."""
    with TestClient(create_app(sqlite_settings)) as c:
        pre = c.options(f"{API}/coaches", headers={"Origin": "http://x", **PREFLIGHT})
        assert pre.status_code == 405
        assert "access-control-allow-origin" not in pre.headers
        reply = c.get(f"{API}/health", headers={"Origin": "http://x"})
        assert reply.status_code == 200 and "access-control-allow-origin" not in reply.headers


def test_cors_for_the_configured_origin_only(sqlite_settings):
    settings = sqlite_settings.model_copy(update={"cors_origins": ["http://x"]})
    with TestClient(create_app(settings)) as c:
        pre = c.options(f"{API}/coaches", headers={"Origin": "http://x", **PREFLIGHT})
        assert pre.status_code == 200
        assert pre.headers["access-control-allow-origin"] == "http://x"
        assert "authorization" in pre.headers["access-control-allow-headers"].lower()
        reply = c.get(f"{API}/health", headers={"Origin": "http://x"})
        assert reply.headers["access-control-allow-origin"] == "http://x"
        for other in ("http://y", "http://x.evil", "https://x"):
            pre = c.options(f"{API}/coaches", headers={"Origin": other, **PREFLIGHT})
            assert pre.status_code == 400 and "access-control-allow-origin" not in pre.headers
            reply = c.get(f"{API}/health", headers={"Origin": other})
            assert reply.status_code == 200 and "access-control-allow-origin" not in reply.headers


# --- errors ---------------------------------------------------------------------------------------
def test_errors_are_json_4xx(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    for path in (
        "/coaches/Z",
        "/coaches/Z/timeseries",
        "/coaches/Z/setpoint",
        "/coaches/Z/setpoints",
        "/coaches/Z/overrides",
    ):
        reply = client.get(API + path, headers=viewer)
        assert reply.status_code == 404 and reply.json() == {"detail": "no coach 'Z'"}, path
    reply = client.delete(f"{API}/coaches/Z/override", headers=op)
    assert reply.status_code == 404 and reply.json() == {"detail": "no coach 'Z'"}
    for path in ("/trains/Z", "/trains/Z/comparison"):
        reply = client.get(API + path, headers=viewer)
        assert reply.status_code == 404 and reply.json() == {"detail": "no train 'Z'"}, path

    register(client, op, "A")
    post_rows(client, op, "A", flat_rows(1, 10))
    url = f"{API}/coaches/A/timeseries"
    cases = {
        "start after end": ({"start": at(10), "end": at(5)}, "start must be before end"),
        "start equal to end": ({"start": at(5), "end": at(5)}, "start must be before end"),
        "start after the clock": ({"start": at(60)}, "start must be before end"),
        "over 31 days": ({"start": at(-60 * 24 * 32), "end": at(0)}, "at most 31 days at a time"),
        "before 1970": (
            {"end": "1969-12-31T00:00:00+00:00"},
            "start and end must lie in 1970 … 2200",
        ),
        "end of time": (
            {"end": "9999-12-31T23:00:00-02:00"},
            "start and end must lie in 1970 … 2200",
        ),
    }
    for name, (params, detail) in cases.items():
        params = {k: v.isoformat() if isinstance(v, datetime) else v for k, v in params.items()}
        for path in (url, f"{API}/coaches/A/setpoints"):
            reply = client.get(path, params=params, headers=viewer)
            assert reply.status_code == 422 and reply.json() == {"detail": detail}, (name, path)
    for params in (
        {"start": "yesterday"},
        {"start": "2024-11-28T06:00:00"},  # no offset
        {"end": "2024-13-01T00:00:00Z"},
        {"start": "1e30"},
    ):
        reply = client.get(url, params=params, headers=viewer)
        assert reply.status_code == 422, params
        assert (
            isinstance(reply.json()["detail"], list)
            and reply.json()["detail"][0]["loc"][0] == "query"
        )
    ok = client.get(
        url,
        params={"start": at(-60 * 24 * 31).isoformat(), "end": at(0).isoformat()},
        headers=viewer,
    )
    assert ok.status_code == 200 and ok.json()["time"] == []
    for params in ({"limit": 0}, {"limit": 1001}, {"offset": -1}):
        assert client.get(f"{API}/audit", params=params, headers=viewer).status_code == 422
    reply = client.post(
        f"{API}/coaches", content="{not json", headers={**op, "Content-Type": "application/json"}
    )
    assert reply.status_code == 422 and "detail" in reply.json()
    # nothing of the above touched the coach
    coach = client.get(f"{API}/coaches/A", headers=viewer).json()
    assert coach["ddpc_active"] is True and coach["override_until"] is None
    assert [c["id"] for c in client.get(f"{API}/coaches", headers=viewer).json()] == ["A"]
