"""Concurrent writers against a real ``serve`` process, on SQLite and PostgreSQL: ten gateways
registering the same trains and coaches at once, then fifty first telemetry posts at once (the
same minutes twice among them) — every answer a 2xx (after any 503 of a machine too busy to admit
them all, sent again as a gateway does), every row stored once, each coach's clock its newest
row, one audit entry per coach created."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
from sqlalchemy import func, select

from helpers.processes import token_cli
from helpers.service import at, flat_rows
from trainclimate.service.store import liveness
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import AuditLog, Coach, Telemetry, Train
from trainclimate.service.store.telemetry import to_wire

GATEWAYS = 10


def all_at_once(requests: list[tuple[str, str, dict]], url: str, token: str) -> list[list[int]]:
    """Send ``requests`` (method, path, body) from as many threads, released together, each
    sent again after a 503 (an overloaded service sheds load with ``Retry-After``, and a gateway
    sends again: on a busy machine fifty requests at once can exceed the admission's wait) up to
    60 s; per request its status codes in order (599 for a connection error)."""
    start = threading.Barrier(len(requests))

    def send(request):
        method, path, body = request
        codes: list[int] = []
        with httpx.Client(
            base_url=f"{url}/api/v1", headers={"Authorization": f"Bearer {token}"}, timeout=30
        ) as client:
            start.wait()
            deadline = time.monotonic() + 60.0
            while True:
                try:
                    reply = client.request(method, path, json=body)
                except httpx.TransportError:
                    return [*codes, 599]
                codes.append(reply.status_code)
                if reply.status_code != 503 or time.monotonic() > deadline:
                    return codes
                time.sleep(min(float(reply.headers.get("Retry-After", "1")), 2.0))

    with ThreadPoolExecutor(len(requests)) as pool:
        return list(pool.map(send, requests))


def _shed_then(codes: list[list[int]]) -> list[int]:
    """Each request's final status, after checking that every earlier answer was a 503 (load
    shed, nothing done), never an error of the write itself."""
    for tries in codes:
        assert set(tries[:-1]) <= {503}, tries
    return [tries[-1] for tries in codes]


def wire(first: int, last: int) -> list[dict]:
    return [to_wire(r) for r in flat_rows(first, last)]


def test_concurrent_first_writes_never_fail(db_url, servers, proc_env):
    server = servers(db_url).start()
    token = token_cli(db_url, "operator", proc_env)
    coaches = [(f"{g}-{side}", str(g)) for g in range(1, GATEWAYS + 1) for side in "AB"]
    # every gateway registers its two coaches, and each request is sent twice
    register = [("POST", "/coaches", {"id": c, "train_id": t}) for c, t in coaches] * 2
    codes = _shed_then(all_at_once(register, server.url, token))
    assert sorted(set(codes)) in ([200, 201], [201]), codes
    assert codes.count(201) == len(coaches)  # each coach created once, then found
    # fifty first posts: five per gateway — coach A's first minutes twice, and three more
    posts = []
    for g in range(1, GATEWAYS + 1):
        a, b = f"{g}-A", f"{g}-B"

        def post(coach, first, last):
            return ("POST", "/telemetry", {"coach_id": coach, "rows": wire(first, last)})

        posts += [post(a, 1, 3), post(a, 1, 3), post(b, 1, 3), post(a, 2, 5), post(b, 4, max(g, 4))]
    assert len(posts) == 50
    codes = _shed_then(all_at_once(posts, server.url, token))
    assert codes == [200] * 50, codes
    server.stop()
    db = Database(db_url)
    try:
        with db.transaction() as s:
            assert s.scalar(select(func.count()).select_from(Coach)) == len(coaches)
            assert s.scalar(select(func.count()).select_from(Train)) == GATEWAYS
            registered = select(func.count()).where(AuditLog.action == "coach.register")
            assert s.scalar(registered) == len(coaches)
            for g in range(1, GATEWAYS + 1):
                times = s.scalars(
                    select(Telemetry.time)
                    .where(Telemetry.coach_id == f"{g}-A")
                    .order_by(Telemetry.time)
                ).all()
                assert times == [at(m) for m in range(1, 6)]
                count = select(func.count()).where(Telemetry.coach_id == f"{g}-B")
                assert s.scalar(count) == max(g, 4)
            # each coach's clock its newest row, however the posts interleaved
            clocks = {c: r.time for c, r in liveness.clocks(s).items()}
            assert clocks == {
                c: at(5) if c.endswith("A") else at(max(int(c[:-2]), 4)) for c, _ in coaches
            }
    finally:
        db.dispose()
