"""A request whose transaction lost a race in the database (a deadlock, a serialization
failure) is run again and answered as if nothing happened; after the last run it is a 503 with
``Retry-After``, never a 500. Any other database error is a 503 at once."""

from __future__ import annotations

import psycopg.errors
from fastapi import Request
from sqlalchemy.exc import OperationalError

from helpers.service import API, count
from trainclimate.service.api import deps
from trainclimate.service.api.retry import ATTEMPTS, RETRY_HEADER
from trainclimate.service.store.models import Coach


def losing(times: int, error=psycopg.errors.DeadlockDetected):
    """A request transaction that loses a race the first ``times`` runs, then is the real one;
    ``runs`` counts them."""

    def session(request: Request):
        session.runs += 1
        if session.runs <= times:
            raise OperationalError("INSERT …", {}, error("deadlock detected"))
        yield from deps.session(request)

    session.runs = 0
    return session


def post_coach(client, headers, coach_id="R-A"):
    body = {"id": coach_id, "train_id": "R", "ddpc_active": True}
    return client.post(f"{API}/coaches", json=body, headers=headers)


def test_a_request_that_lost_a_race_is_run_again(client, tokens, settings):
    for error in (psycopg.errors.DeadlockDetected, psycopg.errors.SerializationFailure):
        session = losing(ATTEMPTS - 1, error)
        client.app.dependency_overrides[deps.session] = session
        try:
            reply = post_coach(client, tokens["operator"], f"R-{error.sqlstate}")
        finally:
            client.app.dependency_overrides.clear()
        assert reply.status_code == 201, reply.text
        assert session.runs == ATTEMPTS
        assert RETRY_HEADER.decode() not in reply.headers
    assert count(settings.database_url, Coach) == 2


def test_a_request_losing_every_run_is_a_503_not_a_500(client, tokens, settings):
    session = losing(ATTEMPTS)
    client.app.dependency_overrides[deps.session] = session
    try:
        reply = post_coach(client, tokens["operator"])
    finally:
        client.app.dependency_overrides.clear()
    assert reply.status_code == 503
    assert reply.headers["retry-after"] and RETRY_HEADER.decode() not in reply.headers
    assert reply.json()["detail"].startswith("(psycopg.errors.DeadlockDetected)")
    assert session.runs == ATTEMPTS
    assert count(settings.database_url, Coach) == 0


def test_other_database_errors_are_not_run_again(client, tokens):
    session = losing(1, psycopg.errors.ConnectionTimeout)
    client.app.dependency_overrides[deps.session] = session
    try:
        reply = post_coach(client, tokens["operator"])
    finally:
        client.app.dependency_overrides.clear()
    assert reply.status_code == 503 and session.runs == 1
