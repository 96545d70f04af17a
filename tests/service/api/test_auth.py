"""Authentication and roles, on SQLite and on PostgreSQL: every protected route refuses a missing,
malformed, unknown or revoked token with 401 and too low a role with 403 (a table of every route
and the role it needs, checked against the router so a new route cannot be left out); health and
readiness need none; tokens are stored as SHA-256 only; ``trainclimate token create`` and
``POST /tokens`` make tokens that work, and ``DELETE /tokens/{id}`` revokes them."""

from __future__ import annotations

import hashlib
import json

import pytest
from fastapi.routing import APIRoute, iter_route_contexts
from sqlalchemy import inspect, select, text

from helpers.service import (
    API,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate import cli
from trainclimate.service import api
from trainclimate.service.store.db import Database, head_revision
from trainclimate.service.store.models import ApiToken, AuditLog, User
from trainclimate.service.store.tokens import RANK

#: (method, path, the lowest role allowed) for every route behind a token.
ROUTES = [
    ("GET", "/me", "viewer"),
    ("GET", "/replicas", "viewer"),
    ("GET", "/metrics", "metrics"),
    ("GET", "/coaches", "viewer"),
    ("POST", "/coaches", "operator"),
    ("GET", "/coaches/{coach_id}", "viewer"),
    ("GET", "/coaches/{coach_id}/timeseries", "viewer"),
    ("GET", "/coaches/{coach_id}/timeseries.csv", "viewer"),
    ("GET", "/coaches/{coach_id}/setpoint", "viewer"),
    ("GET", "/coaches/{coach_id}/setpoints", "viewer"),
    ("POST", "/coaches/{coach_id}/override", "operator"),
    ("DELETE", "/coaches/{coach_id}/override", "operator"),
    ("GET", "/coaches/{coach_id}/overrides", "viewer"),
    ("PUT", "/coaches/{coach_id}/controller", "operator"),
    ("GET", "/trains", "viewer"),
    ("GET", "/trains/{train_id}", "viewer"),
    ("GET", "/trains/{train_id}/plan", "viewer"),
    ("PUT", "/trains/{train_id}/plan", "operator"),
    ("GET", "/trains/{train_id}/guard", "viewer"),
    ("POST", "/trains/{train_id}/guard/reset", "operator"),
    ("GET", "/trains/{train_id}/comparison", "viewer"),
    ("GET", "/trains/{train_id}/comparison.csv", "viewer"),
    ("GET", "/fleet/summary", "viewer"),
    ("GET", "/fleet/summary.csv", "viewer"),
    ("POST", "/telemetry", "operator"),
    ("GET", "/models", "viewer"),
    ("POST", "/models/retrain", "admin"),
    ("GET", "/models/retrain", "viewer"),
    ("POST", "/models/{version}/activate", "admin"),
    ("GET", "/models/active/health", "viewer"),
    ("GET", "/models/{version}/health", "viewer"),
    ("GET", "/audit", "viewer"),
    ("POST", "/tokens", "admin"),
    ("GET", "/tokens", "admin"),
    ("DELETE", "/tokens/{token_id}", "admin"),
    ("PUT", "/users/{name}/role", "admin"),
]
OPEN = [("GET", "/health"), ("GET", "/ready")]
ROLES = ("viewer", "operator", "admin")


@pytest.fixture
def settings(settings):
    """This module sends many wrong tokens on purpose: the failure throttle is set out of reach
    (it has its own tests in test_hardening.py)."""
    return settings.model_copy(update={"auth_failures_burst": 1_000_000})


def _url(path: str) -> str:
    return API + path.format(coach_id="X", train_id="T", version=1, token_id=9999, name="nobody")


def test_the_table_covers_every_route():
    served = {
        (method, route.path.removeprefix(API))
        for route in iter_route_contexts(api.router.routes)
        if isinstance(route.original_route, APIRoute)
        for method in route.methods
    }
    assert served == {(m, p) for m, p, _ in ROUTES} | set(OPEN)


def test_every_protected_route_checks_token_and_role(client, tokens):
    revoked = client.post(f"{API}/tokens", json={"role": "admin"}, headers=tokens["admin"]).json()
    listed = client.get(f"{API}/tokens", headers=tokens["admin"]).json()
    token_id = next(t["id"] for t in listed if t["prefix"] == revoked["token"][:10])
    assert client.delete(f"{API}/tokens/{token_id}", headers=tokens["admin"]).status_code == 200
    invalid = {
        "no header": {},
        "empty bearer": {"Authorization": "Bearer "},
        "other scheme": {"Authorization": "Basic dmlld2VyOnNlY3JldA=="},
        "not a token": {"Authorization": "Bearer hello"},
        "unknown token": {"Authorization": "Bearer tc_" + "A" * 43},
        "token of another prefix": {
            "Authorization": "Bearer x" + tokens["admin"]["Authorization"][8:]
        },
        "revoked admin token": {"Authorization": f"Bearer {revoked['token']}"},
    }
    checked = 0
    for method, path, needed in ROUTES:
        url = _url(path)
        for name, headers in invalid.items():
            reply = client.request(method, url, headers=headers)
            assert reply.status_code == 401, (method, path, name)
            assert reply.headers["www-authenticate"] == "Bearer", (method, path, name)
            assert isinstance(reply.json()["detail"], str)
            checked += 1
        for role in ROLES:
            reply = client.request(method, url, headers=tokens[role])
            if RANK[role] < RANK[needed]:
                assert reply.status_code == 403, (method, path, role, reply.text)
                detail = reply.json()["detail"]
                assert detail == f"this needs the {needed} role; the token is {role}"
            else:  # let in: whatever the route then says about the request itself
                assert reply.status_code not in (401, 403, 500), (method, path, role, reply.text)
            checked += 1
    assert checked == len(ROUTES) * (len(invalid) + len(ROLES)) == 360


def test_health_and_readiness_need_no_token(client):
    health = client.get(f"{API}/health")
    assert health.status_code == 200
    assert health.json()["status"] == "ok" and health.json()["database"] in ("sqlite", "postgresql")
    ready = client.get(f"{API}/ready")
    assert ready.status_code == 200
    body = ready.json()
    assert {k: body[k] for k in ("status", "migrations", "model_version", "under_rule")} == {
        "status": "ready",
        "migrations": head_revision(),
        "model_version": 1,
        "under_rule": False,
    }
    assert body["replica"] and set(body["loops_s"]) == {"live"}


def _all_stored_text(settings) -> str:
    """Every value of every table, as text."""
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            tables = inspect(s.connection()).get_table_names()
            out = []
            for table in tables:
                for row in s.execute(text(f'SELECT * FROM "{table}"')):
                    out.append(repr(tuple(row)))
            return "\n".join(out)
    finally:
        db.dispose()


def _token(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


def test_tokens_are_stored_hashed(client, tokens, settings):
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            rows = s.execute(select(ApiToken, User).join(User).order_by(ApiToken.id)).all()
            stored = [(t.token_hash, t.prefix, u.name, u.role) for t, u in rows]
    finally:
        db.dispose()
    expected = []
    for role in ROLES:
        token = _token(tokens[role])
        assert token.startswith("tc_") and len(token) >= 40
        expected.append(
            (hashlib.sha256(token.encode()).hexdigest(), token[:10], f"test-{role}", role)
        )
    assert stored == expected
    everything = _all_stored_text(settings)
    for role in ROLES:
        token = _token(tokens[role])
        assert token not in everything
        assert token[10:] not in everything  # beyond the displayed prefix, nothing of it


def test_token_create_command(client, settings, capsys):
    code = cli.main(
        [
            "token",
            "create",
            "--role",
            "operator",
            "--name",
            "gw-1",
            "--db",
            settings.database_url,
            "--json",
        ]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["name"] == "gw-1" and out["role"] == "operator"
    headers = {"Authorization": f"Bearer {out['token']}"}
    reply = client.post(f"{API}/coaches", json={"id": "A", "train_id": "T"}, headers=headers)
    assert reply.status_code == 201
    assert client.get(f"{API}/tokens", headers=headers).status_code == 403
    assert out["token"] not in _all_stored_text(settings)
    # without --name: a generated user of that role
    assert (
        cli.main(["token", "create", "--role", "viewer", "--db", settings.database_url, "--json"])
        == 0
    )
    viewer = json.loads(capsys.readouterr().out)
    assert viewer["role"] == "viewer" and viewer["name"].startswith("viewer-")
    headers = {"Authorization": f"Bearer {viewer['token']}"}
    assert client.get(f"{API}/coaches", headers=headers).status_code == 200
    reply = client.post(f"{API}/coaches", json={"id": "B", "train_id": "T"}, headers=headers)
    assert reply.status_code == 403


def test_token_create_command_refuses_an_unknown_role(settings, capsys):
    code = cli.main(["token", "create", "--role", "root", "--db", settings.database_url, "--json"])
    assert code == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "invalid choice: 'root'" in captured.err


def test_tokens_through_the_api(client, tokens, settings):
    admin = tokens["admin"]
    reply = client.post(f"{API}/tokens", json={"role": "viewer", "name": "alice"}, headers=admin)
    assert reply.status_code == 201
    created = reply.json()
    assert set(created) == {"token", "name", "role", "coaches", "expires_at", "mqtt_username"}
    assert created["mqtt_username"] is None  # without serve --mqtt-dynsec
    assert (created["name"], created["role"], created["coaches"]) == ("alice", "viewer", None)
    assert created["expires_at"] is None
    alice = {"Authorization": f"Bearer {created['token']}"}
    assert client.get(f"{API}/coaches", headers=alice).status_code == 200
    assert (
        client.post(f"{API}/coaches", json={"id": "A", "train_id": "T"}, headers=alice).status_code
        == 403
    )

    listed = client.get(f"{API}/tokens", headers=admin).json()
    assert [(t["user"], t["role"]) for t in listed] == [
        ("test-viewer", "viewer"),
        ("test-operator", "operator"),
        ("test-admin", "admin"),
        ("alice", "viewer"),
    ]
    assert all(
        set(t)
        == {"id", "user", "role", "prefix", "coaches", "created_at", "expires_at", "revoked_at"}
        for t in listed
    )
    assert all(t["coaches"] is None and t["expires_at"] is None for t in listed)
    assert created["token"][10:] not in json.dumps(listed)
    mine = listed[-1]
    assert mine["prefix"] == created["token"][:10] and mine["revoked_at"] is None

    # malformed requests and lower roles change nothing
    for body in ({"role": "root"}, {"role": "viewer", "name": ""}, {"role": "viewer", "x": 1}, {}):
        assert client.post(f"{API}/tokens", json=body, headers=admin).status_code == 422, body
    assert (
        client.post(f"{API}/tokens", json={"role": "admin"}, headers=tokens["operator"]).status_code
        == 403
    )
    assert len(client.get(f"{API}/tokens", headers=admin).json()) == 4

    revoked = client.delete(f"{API}/tokens/{mine['id']}", headers=admin)
    assert revoked.status_code == 200
    assert revoked.json()["revoked_at"] is not None and revoked.json()["user"] == "alice"
    reply = client.get(f"{API}/coaches", headers=alice)
    assert reply.status_code == 401 and reply.json() == {"detail": "invalid or revoked token"}
    # revoking again changes nothing (and is not audited twice); an unknown id is 404
    assert client.delete(f"{API}/tokens/{mine['id']}", headers=admin).status_code == 200
    missing = client.delete(f"{API}/tokens/9999", headers=admin)
    assert missing.status_code == 404 and missing.json() == {"detail": "no token 9999"}
    assert client.delete(f"{API}/tokens/abc", headers=admin).status_code == 422
    # the other tokens still work
    assert client.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 200

    audit = client.get(f"{API}/audit", headers=tokens["viewer"]).json()
    assert [(a["action"], a["user"], a["target"]) for a in audit] == [
        ("token.revoke", "test-admin", f"token:{mine['id']}"),
        ("token.create", "test-admin", "user:alice"),
    ]
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            first = s.scalar(select(AuditLog).order_by(AuditLog.id).limit(1))
            assert first.detail == {"role": "viewer"} and first.role == "admin"
    finally:
        db.dispose()


def test_me_names_the_token_and_its_role(client, tokens):
    for role in ROLES:
        reply = client.get(f"{API}/me", headers=tokens[role])
        assert reply.status_code == 200
        assert reply.json() == {"name": f"test-{role}", "role": role}
    assert client.get(f"{API}/me").status_code == 401
