"""The hardening middleware, on SQLite and on PostgreSQL: the security headers on every answer
(API, dashboard, errors), the request body limit (Content-Length and chunked: 413, nothing
stored) and the throttle of failed authentications per client address (429 with Retry-After,
other addresses and every valid token served, free again once the window passes;
``X-Forwarded-For`` read only from a trusted proxy, checked on a real server)."""

from __future__ import annotations

import asyncio
import json
import logging
import time

import httpx
import pytest
from fastapi.testclient import TestClient

from helpers.service import API, count, flat_rows, post_rows, register, to_wire
from trainclimate.service.api.hardening import (
    CONTENT_SECURITY_POLICY,
    BodySizeLimit,
    FailureCounter,
)
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import Telemetry
from trainclimate.service.store.tokens import create_token

WRONG = {"Authorization": "Bearer tc_not-a-token"}


def assert_secured(reply) -> None:
    assert reply.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
    assert reply.headers["x-content-type-options"] == "nosniff"
    assert reply.headers["x-frame-options"] == "DENY"
    assert reply.headers["referrer-policy"] == "no-referrer"


# --- security headers ---------------------------------------------------------------------------
def test_security_headers_on_every_answer(client, tokens):
    answers = {
        "/": 200,
        "/app.js": 200,
        "/vendor/plotly.min.js": 200,
        f"{API}/health": 200,
        f"{API}/coaches": 401,
        "/no-such-file.txt": 404,
    }
    for path, status in answers.items():
        reply = client.get(path)
        assert reply.status_code == status, path
        assert_secured(reply)
    missing = client.get(f"{API}/coaches/nope", headers=tokens["viewer"])
    assert missing.status_code == 404
    assert_secured(missing)
    assert_secured(client.get(f"{API}/coaches", headers=WRONG))


def test_a_server_error_has_the_headers_too(settings):
    app = create_app(settings)

    def boom():
        raise RuntimeError("boom")

    app.add_api_route("/boom", boom)
    app.router.routes.insert(0, app.router.routes.pop())  # before the dashboard's mount at /
    with TestClient(app, raise_server_exceptions=False) as c:
        reply = c.get("/boom")
    assert reply.status_code == 500
    assert_secured(reply)


# --- body size limit ----------------------------------------------------------------------------
def test_an_oversized_body_is_refused_and_nothing_stored(client, tokens, settings):
    op = tokens["operator"]
    register(client, op, "A")
    limit = settings.max_body_bytes
    rows = [to_wire(r) for r in flat_rows(1, 30)]
    body = json.dumps({"coach_id": "A", "rows": rows}).encode()
    while len(body) <= limit + 1_000_000:  # valid telemetry (duplicates aside), too much of it
        rows = rows + rows
        body = json.dumps({"coach_id": "A", "rows": rows}).encode()
    headers = {**op, "Content-Type": "application/json"}
    start = time.monotonic()
    reply = client.post(f"{API}/telemetry", content=body, headers=headers)
    assert time.monotonic() - start < 5
    assert reply.status_code == 413
    assert reply.json() == {"detail": f"request body larger than {limit} bytes"}
    assert_secured(reply)
    # the same without Content-Length (chunked): counted as it streams in
    chunked = client.post(
        f"{API}/telemetry",
        content=iter([body[: limit // 2], body[limit // 2 :]]),
        headers=headers,
    )
    assert chunked.status_code == 413
    assert chunked.json() == {"detail": f"request body larger than {limit} bytes"}
    assert count(settings.database_url, Telemetry) == 0
    # a body within the limit is served as before
    small = post_rows(client, op, "A", flat_rows(1, 3))
    assert small.status_code == 200 and small.json()["stored"] == 3


def test_a_chunked_body_is_not_read_past_the_limit():
    """Straight on the middleware: it stops at the first chunk over the limit and answers 413,
    whatever the app behind does with the error; a body within the limit reaches the app."""

    async def app(scope, receive, send):  # reads the whole body, then answers 200
        body = b""
        while True:
            message = await receive()
            body += message.get("body", b"")
            if not message.get("more_body"):
                break
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": str(len(body)).encode()})

    def run(chunks: int) -> tuple[list[dict], int]:
        read = 0
        sent: list[dict] = []

        async def receive():
            nonlocal read
            read += 1
            return {"type": "http.request", "body": b"x" * 100, "more_body": read < chunks}

        async def send(message):
            sent.append(message)

        scope = {"type": "http", "method": "POST", "path": "/", "headers": []}
        asyncio.run(BodySizeLimit(app, max_bytes=250)(scope, receive, send))
        return sent, read

    sent, read = run(1000)
    assert sent[0]["status"] == 413 and read == 3
    assert json.loads(sent[1]["body"]) == {"detail": "request body larger than 250 bytes"}
    sent, read = run(2)
    assert sent[0]["status"] == 200 and sent[1]["body"] == b"200"


# --- throttle of failed authentications ---------------------------------------------------------
def test_failed_authentications_are_throttled_per_address(client, tokens, settings, caplog):
    clock = [1000.0]
    client.app.state.auth_failures.clock = lambda: clock[0]
    burst = settings.auth_failures_burst
    caplog.set_level(logging.WARNING, logger="trainclimate.service.api.hardening")
    statuses = []
    for _ in range(300):
        reply = client.get(f"{API}/coaches", headers=WRONG)
        statuses.append(reply.status_code)
        clock[0] += 0.01
    assert statuses == [401] * burst + [429] * (300 - burst)
    assert_secured(reply)
    assert "try again" in reply.json()["detail"]
    wait = int(reply.headers["retry-after"])
    assert 1 <= wait <= settings.auth_failures_window_s
    blocked = [r for r in caplog.records if "failed authentications" in r.getMessage()]
    assert len(blocked) == 1 and "testclient" in blocked[0].getMessage()
    # the blocked address: a valid token is served; without a token the dashboard is served
    assert client.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 200
    assert client.get("/").status_code == 200
    assert client.get(f"{API}/health").status_code == 200
    # another address is served, and its failures and successes leave the first one's count
    with TestClient(client.app, client=("10.0.0.2", 123)) as other:
        assert other.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 200
        assert other.get(f"{API}/coaches", headers=WRONG).status_code == 401
    assert client.get(f"{API}/coaches", headers=WRONG).status_code == 429
    # once the window has passed: 401 again (and the valid token served)
    clock[0] += wait
    assert client.get(f"{API}/coaches", headers=WRONG).status_code == 401
    assert client.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 200


def test_a_valid_token_is_served_from_a_blocked_address(client, tokens, settings):
    """Many wrong tokens from the address that gateways and operators share (a NAT, a reverse
    proxy) lock none of them out: a valid token is checked before anything is refused, and only
    failed authentications answer 429 — a revoked token's among them."""
    db = Database(settings.database_url)
    with db.transaction() as s:
        gateway = {"Authorization": f"Bearer {create_token(s, 'gateway', 'gw', ['G-A'])[0]}"}
    db.dispose()
    operator, admin, revoked = tokens["operator"], tokens["admin"], tokens["viewer"]
    listed = client.get(f"{API}/tokens", headers=admin).json()
    viewer_id = next(t["id"] for t in listed if t["user"] == "test-viewer")
    assert client.delete(f"{API}/tokens/{viewer_id}", headers=admin).is_success
    statuses = [client.get(f"{API}/coaches", headers=WRONG).status_code for _ in range(25)]
    assert statuses == [401] * 20 + [429] * 5
    register_reply = client.post(
        f"{API}/coaches", json={"id": "G-A", "train_id": "G"}, headers=gateway
    )
    assert register_reply.status_code == 201, register_reply.text
    assert post_rows(client, gateway, "G-A", flat_rows(1, 3)).json()["stored"] == 3
    assert client.get(f"{API}/coaches/G-A/setpoint", headers=gateway).status_code in (200, 404)
    assert client.get(f"{API}/coaches", headers=operator).status_code == 200
    reason = {"active": False, "reason": "a test"}
    assert client.put(f"{API}/coaches/G-A/controller", json=reason, headers=operator).is_success
    for headers in (WRONG, revoked, {"Authorization": "Basic dXNlcjpwdw=="}):
        reply = client.get(f"{API}/coaches", headers=headers)
        assert reply.status_code == 429 and int(reply.headers["retry-after"]) >= 1, headers


def wrong_from(server, forwarded_for: str, peer: str = "127.0.0.1") -> int:
    """The status of a wrong token sent to ``server`` from ``peer`` (a loopback address) with
    ``X-Forwarded-For: forwarded_for``."""
    headers = {**WRONG, "X-Forwarded-For": forwarded_for}
    with httpx.Client(transport=httpx.HTTPTransport(local_address=peer), timeout=10) as c:
        return c.get(f"{server.url}{API}/coaches", headers=headers).status_code


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_forwarded_for_counts_only_from_a_trusted_proxy(db_url, servers, proc_env):
    """``trainclimate serve --forwarded-allow-ips`` over real HTTP, its proxy 127.0.0.2. From
    127.0.0.1, not a trusted proxy (uvicorn's own default trusts it), ``X-Forwarded-For`` is
    ignored: wrong tokens claiming 21 different clients are one client's, refused at the 21st.
    From the proxy the header names the client: one client's 21st wrong token is refused,
    another's is not."""
    env = {**proc_env, "TRAINCLIMATE_AUTH_FAILURES_WINDOW_S": "3600"}  # however slow the machine
    server = servers(db_url, "--forwarded-allow-ips", "10.9.9.0/24, 127.0.0.2", env=env).start()
    statuses = [wrong_from(server, f"198.51.100.{i}") for i in range(21)]
    assert statuses == [401] * 20 + [429]
    statuses = [wrong_from(server, "203.0.113.7", peer="127.0.0.2") for _ in range(21)]
    assert statuses == [401] * 20 + [429]
    assert wrong_from(server, "203.0.113.8", peer="127.0.0.2") == 401
    # the client is the last address before the trusted proxies: an earlier one is the client's
    assert wrong_from(server, "203.0.113.8, 203.0.113.7", peer="127.0.0.2") == 429
    assert wrong_from(server, "203.0.113.7, 10.9.9.1", peer="127.0.0.2") == 429
    output = server.output()
    assert "127.0.0.1: 20 failed" in output and "203.0.113.7: 20 failed" in output


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_the_throttle_settings_apply(settings):
    settings = settings.model_copy(update={"auth_failures_burst": 3, "auth_failures_window_s": 10})
    with TestClient(create_app(settings)) as c:
        statuses = [c.get(f"{API}/coaches", headers=WRONG).status_code for _ in range(5)]
        assert statuses == [401, 401, 401, 429, 429]
        assert int(c.get(f"{API}/coaches", headers=WRONG).headers["retry-after"]) <= 10


def test_trusted_proxies_from_the_environment(monkeypatch):
    monkeypatch.setenv("TRAINCLIMATE_FORWARDED_ALLOW_IPS", " 10.0.0.5, 10.1.0.0/16,,::1")
    assert Settings().forwarded_allow_ips == ["10.0.0.5", "10.1.0.0/16", "::1"]
    monkeypatch.setenv("TRAINCLIMATE_FORWARDED_ALLOW_IPS", "")
    assert Settings().forwarded_allow_ips == []
    monkeypatch.setenv("TRAINCLIMATE_FORWARDED_ALLOW_IPS", "10.0.0.5,proxy")
    with pytest.raises(ValueError, match="'proxy' is not an IP address or network"):
        Settings()


def test_the_failure_counter():
    now = [0.0]
    counter = FailureCounter(3, 60, clock=lambda: now[0])
    assert [counter.record_failure("a") for _ in range(2)] == [False, False]
    assert counter.retry_after("a") is None
    now[0] = 30.0
    assert counter.record_failure("a") is True  # the third within 60 s: blocked, logged once
    assert counter.retry_after("a") == 30 and counter.retry_after("b") is None
    assert counter.record_failure("a") is False  # already blocked: not a new block
    now[0] = 59.5
    assert counter.retry_after("a") == 1
    now[0] = 60.0  # the oldest of the last three is out of the window: free again
    assert counter.retry_after("a") is None
