"""The service under more requests than it has threads for: the admission (503 with Retry-After
once its slots are full and none frees in time; health, readiness and the dashboard still served),
its slots handed over first come first served, the database pool sized to the worker threads, and
a pool time-out or an unreachable database answered 503 with Retry-After, never 500."""

from __future__ import annotations

import asyncio
import logging
import sys
import threading

import pytest
from anyio import to_thread
from fastapi import Request
from fastapi.testclient import TestClient
from sqlalchemy.exc import OperationalError

from helpers.service import API, wait_for
from trainclimate.service.api import deps
from trainclimate.service.api.hardening import (
    DATABASE_RETRY_AFTER_S,
    OVERLOAD_RETRY_AFTER_S,
    SWITCH_INTERVAL_S,
    Slots,
)
from trainclimate.service.app import create_app
from trainclimate.service.store import db as store_db
from trainclimate.service.store.db import BACKGROUND_THREADS, POOL_OVERFLOW, Database

SQLITE_ONLY = pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)


def with_hold(app) -> threading.Event:
    """Add ``GET /api/v1/test-hold``, which answers once the returned event is set: it holds a
    slot of the admission but no worker thread (it waits in the event loop)."""
    release = threading.Event()

    async def hold() -> dict:
        while not release.is_set():
            await asyncio.sleep(0.01)
        return {"held": True}

    app.add_api_route(f"{API}/test-hold", hold)
    app.router.routes.insert(0, app.router.routes.pop())  # before the dashboard's mount at /
    return release


@SQLITE_ONLY
def test_a_request_beyond_the_slots_answers_503_with_retry_after(settings, tokens, caplog):
    settings = settings.model_copy(update={"worker_threads": 1, "overload_wait_s": 0.2})
    app = create_app(settings)
    release = with_hold(app)
    caplog.set_level(logging.WARNING, logger="trainclimate.service.api.hardening")
    viewer = tokens["viewer"]
    with TestClient(app) as c:
        held = threading.Thread(target=c.get, args=(f"{API}/test-hold",))
        held.start()
        try:
            wait_for(lambda: app.state.admission.busy == 1, what="the held request's slot")
            replies = [c.get(f"{API}/coaches", headers=viewer) for _ in range(2)]
            for reply in replies:
                assert reply.status_code == 503
                assert reply.headers["retry-after"] == str(OVERLOAD_RETRY_AFTER_S)
                assert "busy" in reply.json()["detail"]
                assert reply.headers["x-frame-options"] == "DENY"  # the security headers too
            assert app.state.admission.rejected == 2
            # liveness, readiness and the dashboard take no slot
            assert c.get(f"{API}/health").status_code == 200
            assert c.get(f"{API}/ready").status_code == 200
            assert c.get("/").status_code == 200
        finally:
            release.set()
            held.join()
        assert app.state.admission.busy == 0
        assert c.get(f"{API}/coaches", headers=viewer).status_code == 200
    warnings = [r for r in caplog.records if "overloaded" in r.getMessage()]
    assert len(warnings) == 1  # at most one warning per OVERLOAD_LOG_EVERY_S


def test_slots_are_handed_over_first_come_first_served():
    """Straight on :class:`Slots`, in one event loop: a slot given back goes to the first request
    in line; a request whose wait runs out gets none (counted); one that leaves the line (its
    client gone) takes no slot with it."""

    async def scenario() -> list:
        slots = Slots(1, wait_s=10.0)
        order = []

        async def request(name: str) -> None:
            if await slots.acquire():
                order.append(name)
                await asyncio.sleep(0)
                slots.release()

        assert await slots.acquire()
        waiters = [asyncio.create_task(request(n)) for n in ("first", "second", "third")]
        await asyncio.sleep(0.01)
        assert slots.waiting == 3
        waiters[1].cancel()  # the second client leaves the line
        slots.release()
        await asyncio.gather(waiters[0], waiters[2])
        assert waiters[1].cancelled()
        assert (slots.busy, slots.waiting, slots.rejected) == (0, 0, 0)

        impatient = Slots(1, wait_s=0.01)
        assert await impatient.acquire()
        assert not await impatient.acquire()  # none freed within 10 ms
        assert (impatient.busy, impatient.waiting, impatient.rejected) == (1, 0, 1)
        impatient.release()
        assert await impatient.acquire()
        return order

    assert asyncio.run(scenario()) == ["first", "third"]


def test_the_pool_is_sized_to_the_worker_threads(db_url):
    db = Database(db_url, worker_threads=3)
    try:
        assert db.engine.pool.size() == 3 + BACKGROUND_THREADS
        assert db.engine.pool._max_overflow == POOL_OVERFLOW
    finally:
        db.dispose()


@SQLITE_ONLY
def test_the_worker_threads_setting_sizes_threads_and_pool(settings):
    settings = settings.model_copy(update={"worker_threads": 5})
    switch = sys.getswitchinterval()
    try:
        with TestClient(create_app(settings)) as c:
            limit = c.portal.call(lambda: to_thread.current_default_thread_limiter().total_tokens)
            assert limit == 5
            assert c.app.state.admission.size == 5
            assert c.app.state.db.engine.pool.size() == 5 + BACKGROUND_THREADS
            assert sys.getswitchinterval() == pytest.approx(SWITCH_INTERVAL_S)
    finally:
        sys.setswitchinterval(switch)


@SQLITE_ONLY
def test_a_pool_time_out_answers_503_with_retry_after(settings, tokens, monkeypatch):
    monkeypatch.setattr(store_db, "POOL_TIMEOUT_S", 0.1)
    monkeypatch.setattr(store_db, "POOL_OVERFLOW", 0)
    # the live loop runs once at start and then sleeps: the test's connections are the pool's
    settings = settings.model_copy(update={"worker_threads": 1, "scheduler_interval_s": 3600})
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        engine = c.app.state.db.engine
        assert c.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 200
        wait_for(lambda: engine.pool.checkedout() == 0, what="the loops' connections back")
        # every pooled connection taken (as by requests and loops stuck elsewhere)
        taken = [engine.connect() for _ in range(engine.pool.size())]
        try:
            reply = c.get(f"{API}/coaches", headers=tokens["viewer"])
        finally:
            for conn in taken:
                conn.close()
        assert reply.status_code == 503
        assert reply.headers["retry-after"] == str(OVERLOAD_RETRY_AFTER_S)
        assert "QueuePool limit" in reply.json()["detail"]
        assert c.get(f"{API}/coaches", headers=tokens["viewer"]).status_code == 200


@SQLITE_ONLY
def test_an_unreachable_database_answers_503_with_retry_after(client, tokens):
    def session_that_cannot_connect(request: Request):
        raise OperationalError("SELECT 1", {}, Exception("connection refused"))
        yield  # pragma: no cover - a generator dependency, like the real one

    client.app.dependency_overrides[deps.session] = session_that_cannot_connect
    try:
        reply = client.get(f"{API}/coaches", headers=tokens["viewer"])
    finally:
        client.app.dependency_overrides.clear()
    assert reply.status_code == 503
    assert reply.headers["retry-after"] == str(DATABASE_RETRY_AFTER_S)
    assert "connection refused" in reply.json()["detail"]
