"""A full disk is named: on SQLite whose file may not grow (``PRAGMA max_page_count`` at its
size, as a full disk leaves it), writes answer 503, reads are served, ``/health`` and ``/ready``
say ``database or disk is full`` since when — also while small writes still fit — and once the
file may grow again, the next write commits and clears it."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import event, text

from helpers.service import (
    API,
    flat_row,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.service.store.storage import storage_error


def rows(start: datetime, n: int) -> list[dict]:
    return [flat_row(start + timedelta(minutes=m)) for m in range(n)]


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_a_full_disk_is_named_and_clears(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    assert register(client, op, "A").status_code == 201
    start = datetime.now(UTC).replace(second=0, microsecond=0) - timedelta(days=2)
    assert post_rows(client, op, "A", rows(start, 10)).status_code == 200
    assert client.get(f"{API}/health").json()["storage"] == {
        "state": "ok",
        "detail": None,
        "since": None,
    }
    engine = client.app.state.db.engine
    client.app.state.db.storage.clear_after_s = 1.0  # ok again 1 s after the last error

    def full(dbapi_connection, _record):  # every connection: the file may not grow
        cursor = dbapi_connection.cursor()
        pages = cursor.execute("PRAGMA page_count").fetchone()[0]
        cursor.execute(f"PRAGMA max_page_count = {pages}")
        cursor.close()

    event.listen(engine, "connect", full)
    engine.dispose()  # the pooled connections go; new ones are limited
    try:
        failed_at = datetime.now(UTC)
        written = 10
        for _batch in range(5):  # a day of rows at a time until the file is full
            reply = post_rows(client, op, "A", rows(start + timedelta(minutes=written), 1440))
            if reply.status_code == 503:
                break
            assert reply.status_code == 200, reply.text
            written += 1440
        assert reply.status_code == 503 and reply.headers["retry-after"], reply.text
        assert "database or disk is full" in reply.json()["detail"]
        health = client.get(f"{API}/health")
        assert health.status_code == 200  # alive: the process is, and says what fails
        storage = health.json()["storage"]
        assert storage["state"] == "error" and storage["detail"].endswith(
            "database or disk is full"
        )
        since = datetime.fromisoformat(storage["since"])
        assert failed_at - timedelta(seconds=1) <= since <= datetime.now(UTC)
        ready = client.get(f"{API}/ready")
        assert ready.status_code == 503
        assert any(
            r.startswith("storage: ") and "disk is full" in r for r in ready.json()["reasons"]
        )
        assert ready.json()["storage"]["state"] == "error"
        # reads are served meanwhile
        coaches = client.get(f"{API}/coaches", headers=viewer)
        assert coaches.status_code == 200 and [c["id"] for c in coaches.json()] == ["A"]
    finally:
        event.remove(engine, "connect", full)
        engine.dispose()
    # room again: a write committed a second after the last error clears it
    time.sleep(1.1)
    reply = post_rows(client, op, "A", rows(start + timedelta(minutes=written), 5))
    assert reply.status_code == 200 and reply.json()["stored"] == 5
    assert client.get(f"{API}/health").json()["storage"]["state"] == "ok"
    ready = client.get(f"{API}/ready").json()
    assert ready["status"] == "ready" and ready["storage"]["state"] == "ok"
    with engine.connect() as c:
        assert c.execute(text("PRAGMA integrity_check")).scalar() == "ok"


class DriverError(Exception):
    def __init__(self, message: str, sqlstate: str | None = None):
        super().__init__(message)
        self.sqlstate = sqlstate


@pytest.mark.parametrize(
    "error, named",
    [
        (DriverError("database or disk is full"), True),
        (DriverError("disk I/O error"), True),
        (DriverError("could not extend file: No space left on device", "53100"), True),
        (DriverError("could not write to file", "58030"), True),
        (DriverError("canceling statement due to lock timeout", "55P03"), False),
        (DriverError("connection refused", "08001"), False),
        (DriverError("database is locked"), False),
    ],
)
def test_which_errors_are_storage_errors(error, named):
    assert (storage_error(error) is not None) == named
