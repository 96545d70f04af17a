"""The hardening middleware, on SQLite and on PostgreSQL: the security headers on every answer
(API, dashboard, errors), the request body limit (Content-Length and chunked: 413, nothing
stored) and the throttle of failed authentications per client address (429 with Retry-After,
other addresses served, free again once the window passes)."""

from __future__ import annotations

import asyncio
import json
import logging
import time

import pytest
from fastapi.testclient import TestClient

from service_support import API, count, flat_rows, post_rows, register, to_wire
from trainclimate.service.api.hardening import (
    CONTENT_SECURITY_POLICY,
    BodySizeLimit,
    FailureCounter,
)
from trainclimate.service.app import create_app
from trainclimate.service.store.models import Telemetry

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
    # the blocked address: even a valid token waits; without a token the dashboard is served
    assert client.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 429
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


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_the_throttle_settings_apply(settings):
    settings = settings.model_copy(update={"auth_failures_burst": 3, "auth_failures_window_s": 10})
    with TestClient(create_app(settings)) as c:
        statuses = [c.get(f"{API}/coaches", headers=WRONG).status_code for _ in range(5)]
        assert statuses == [401, 401, 401, 429, 429]
        assert int(c.get(f"{API}/coaches", headers=WRONG).headers["retry-after"]) <= 10


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
