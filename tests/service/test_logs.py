"""Structured logs and request ids: ``--log-format json`` writes one JSON object a line (time,
level, logger, message, replica; the request id, the coach and the tick where they apply), for the
service's own lines and uvicorn's alike; ``X-Request-ID`` is taken from a request when it is a
sane one (else a new one is made) and returned on every answer, and the log lines written while a
request runs carry it. The text format stays the default."""

from __future__ import annotations

import io
import json
import logging
import re
from datetime import UTC, datetime, timedelta

import httpx
import pytest

from helpers.service import API, flat_row
from trainclimate.service import logs
from trainclimate.service.api.observe import valid_request_id
from trainclimate.service.app import register_model_file
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store import commands
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import Coach, Train
from trainclimate.service.store.tokens import Principal

REQUIRED = {"time", "level", "logger", "message", "replica"}
GENERATED = re.compile(r"^[0-9a-f]{32}$")


class Lines:
    """The JSON lines a :class:`~trainclimate.service.logs.JsonFormatter` writes, captured on
    the ``trainclimate`` logger."""

    def __init__(self, replica: str):
        self.stream = io.StringIO()
        self.handler = logging.StreamHandler(self.stream)
        self.handler.setFormatter(logs.JsonFormatter(replica))
        self.logger = logging.getLogger("trainclimate")

    def __enter__(self) -> Lines:
        self.level = self.logger.level
        self.logger.addHandler(self.handler)
        self.logger.setLevel(logging.INFO)
        return self

    def __exit__(self, *exc) -> None:
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self.level)

    def parsed(self) -> list[dict]:
        out = [json.loads(line) for line in self.stream.getvalue().splitlines()]
        for line in out:
            assert set(line) >= REQUIRED, line
            datetime.fromisoformat(line["time"].replace("Z", "+00:00"))
        return out


def test_a_json_line_has_its_fields_and_the_context_and_a_traceback():
    with Lines("r-1") as lines:
        log = logging.getLogger("trainclimate.test")
        log.info("plain %d", 1)
        with logs.context(tick="2024-11-28T02:00:00+00:00", coach="T-A"):
            try:
                raise ValueError("boom ünicode")
            except ValueError:
                log.exception("failed")
        with logs.context(request_id="abc"):
            log.warning("in a request")
    plain, failed, request = lines.parsed()
    assert plain["message"] == "plain 1" and plain["level"] == "info"
    assert plain["logger"] == "trainclimate.test" and plain["replica"] == "r-1"
    assert plain["time"].endswith("Z") and "coach" not in plain and "request_id" not in plain
    assert failed["coach"] == "T-A" and failed["tick"] == "2024-11-28T02:00:00+00:00"
    assert failed["level"] == "error" and "ValueError: boom ünicode" in failed["exception"]
    assert request["request_id"] == "abc" and "coach" not in request


def test_the_scheduler_s_lines_carry_the_tick_and_the_coach(settings):
    """A trial plan switching the layer of a train's two coaches at a tick: each line names the
    tick and the coach."""
    migrate(settings.database_url)
    db = Database(settings.database_url)
    try:
        with db.transaction() as session:
            register_model_file(session, settings)
            session.add(Train(id="T", name="T"))
            session.flush()
            for cid in ("T-A", "T-B"):
                session.add(Coach(id=cid, train_id="T", fleet="live", ddpc_active=cid == "T-A"))
        tick = datetime(2024, 11, 28, 2, 0, tzinfo=UTC)  # 03:00 Zurich: an even service day
        with db.transaction() as session:
            commands.set_plan(
                session, Principal("t", "operator"), "T", "alternate", reason="a trial"
            )
            for cid in ("T-A", "T-B"):
                first = tick - timedelta(minutes=75)
                rows = [flat_row(first + timedelta(minutes=i)) for i in range(76)]
                commands.ingest(session, cid, rows)
        scheduler = Scheduler(db, settings)
        with Lines(settings.replica_name) as lines:
            assert scheduler.tick_fleet("live", tick - timedelta(minutes=5)) == 2
    finally:
        db.dispose()
    switched = [line for line in lines.parsed() if "plan of train T" in line["message"]]
    assert {(line["coach"], line["tick"]) for line in switched} == {
        ("T-A", "2024-11-28T01:55:00+00:00"),
        ("T-B", "2024-11-28T01:55:00+00:00"),
    }
    assert all(line["replica"] == settings.replica_name for line in switched)


@pytest.mark.parametrize(
    ("sent", "kept"),
    [
        ("probe-123", True),
        ("0f8fad5b-d9cb-469f-a165-70867728950e", True),
        ("00-4bf92f3577b34da6a3ce929d0e0e4736-00f067aa0ba902b7-01", True),
        ("a" * 128, True),
        ("a" * 129, False),
        ("", False),
        ("two words", False),
        ('quote"d', False),
        ("ünï", False),
        ("line\\nbreak", False),
    ],
)
def test_a_request_id_is_kept_only_when_sane(sent, kept):
    assert (valid_request_id(sent) == sent) is kept


@pytest.fixture
def settings(settings):
    """The throttle blocks after two failed authentications (a line written in a request)."""
    return settings.model_copy(update={"auth_failures_burst": 2, "max_body_bytes": 1000})


def test_every_answer_returns_a_request_id_and_the_request_s_lines_carry_it(client):
    ids = set()
    for method, path, kwargs, status in [
        ("GET", f"{API}/health", {}, 200),
        ("GET", f"{API}/coaches", {}, 401),
        ("GET", f"{API}/coaches?x=1", {"headers": {"Authorization": "Bearer x"}}, 422),
        ("GET", "/no-such-file.txt", {}, 404),
        ("GET", "/", {}, 200),
        ("POST", f"{API}/telemetry", {"content": b"x" * 2000}, 413),
        ("POST", f"{API}/tokens", {"json": {"role": "nope"}}, 401),
    ]:
        reply = client.request(method, path, **kwargs)
        assert reply.status_code == status, (path, reply.text)
        rid = reply.headers["x-request-id"]
        assert GENERATED.fullmatch(rid), rid
        ids.add(rid)
    assert len(ids) == 7  # a new one each time
    assert (
        client.get(f"{API}/ready", headers={"X-Request-ID": "lb-42"}).headers["x-request-id"]
        == "lb-42"
    )
    replaced = client.get(f"{API}/health", headers={"X-Request-ID": "bad id"})
    assert GENERATED.fullmatch(replaced.headers["x-request-id"])
    bad = {"Authorization": "Bearer tc_" + "B" * 43}
    with Lines("r") as lines:
        for n in range(2):
            reply = client.get(f"{API}/me", headers={**bad, "X-Request-ID": f"auth-{n}"})
            assert reply.status_code == 401 and reply.headers["x-request-id"] == f"auth-{n}"
    [blocked] = [line for line in lines.parsed() if "failed authentications" in line["message"]]
    assert blocked["request_id"] == "auth-1" and blocked["level"] == "warning"


def test_serve_log_format_json_writes_only_json_lines(servers, proc_env, tmp_path):
    db_url = f"sqlite:///{tmp_path / 'trainclimate.db'}"
    server = servers(
        db_url, "--log-format", "json", "--log-level", "info", "--replica-name", "json-1"
    ).start()
    reply = httpx.get(f"{server.url}/api/v1/health", headers={"X-Request-ID": "probe-7"})
    assert reply.headers["x-request-id"] == "probe-7"

    def access() -> list[dict]:
        lines = [json.loads(line) for line in server.output().splitlines() if line.strip()]
        return [x for x in lines if x["logger"] == "uvicorn.access" and "probe-7" in str(x)]

    from helpers.service import wait_for

    [line] = wait_for(access, 15, "the access line")
    assert line["request_id"] == "probe-7" and line["replica"] == "json-1"
    assert "GET /api/v1/health" in line["message"] and line["level"] == "info"
    server.stop()
    lines = [json.loads(line) for line in server.output().splitlines() if line.strip()]
    assert all(set(x) >= REQUIRED and x["replica"] == "json-1" for x in lines)
    loggers = {x["logger"] for x in lines}
    assert {"uvicorn.error", "uvicorn.access", "trainclimate.serve"} <= loggers, loggers
    assert any(x["message"].startswith("serving on http://") for x in lines)


def test_an_error_no_handler_answers_is_a_500_with_its_request_id_and_counted():
    """The middleware on a bare Starlette app whose route fails: the 500 carries the request id
    and is counted, and the error still reaches the server."""
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.routing import Route
    from starlette.testclient import TestClient

    from trainclimate.service.api.observe import Observe
    from trainclimate.service.metrics import Metrics

    def fail(_request):
        raise RuntimeError("a bug")

    metrics = Metrics("r")
    app = Starlette(
        routes=[Route("/fail", fail)], middleware=[Middleware(Observe, metrics=metrics)]
    )
    with TestClient(app, raise_server_exceptions=False) as client:
        reply = client.get("/fail", headers={"X-Request-ID": "err-1"})
    assert reply.status_code == 500 and reply.headers["x-request-id"] == "err-1"
    assert reply.json() == {"detail": "Internal Server Error"}
    assert metrics.snapshot()["responses"] == {500: 1}
    with TestClient(app) as client, pytest.raises(RuntimeError, match="a bug"):
        client.get("/fail")
