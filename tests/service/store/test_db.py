"""The service's PostgreSQL sessions: the lock and idle-in-transaction timeouts every connection
sets, added to (never replacing) the ``options`` its URL carries, and times read in UTC."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from sqlalchemy import text

from helpers.service import PG_SKIP, PG_URL, drop_pg_database, pg_database
from trainclimate.service.store.db import make_engine, probe_engine, session_options


def test_the_sessions_options_follow_those_of_the_url():
    assert session_options("postgresql://h/db", lock_timeout=2.0) == "-c lock_timeout=2000"
    url = "postgresql://h/db?options=-csearch_path%3Dbench"
    assert session_options(url, lock_timeout=0.5, statement_timeout=1) == (
        "-csearch_path=bench -c lock_timeout=500 -c statement_timeout=1000"
    )


@pytest.mark.skipif(not PG_URL, reason=PG_SKIP)
def test_a_schema_named_in_the_url_survives_the_timeouts():
    """A URL's ``options=-csearch_path=…`` (one database, a schema per environment) was replaced
    by the timeouts: the service then read and wrote the public schema."""
    url, name = pg_database()
    try:
        schema_url = f"{url}?options=-csearch_path%3Dother"
        for engine in (make_engine(schema_url, lock_timeout_s=2.0), probe_engine(schema_url)):
            with engine.connect() as conn:
                assert conn.execute(text("SHOW search_path")).scalar() == "other"
                assert conn.execute(text("SHOW lock_timeout")).scalar() in ("2s", "1s")
            engine.dispose()
    finally:
        drop_pg_database(name)


@pytest.mark.skipif(not PG_URL, reason=PG_SKIP)
def test_times_come_back_in_pythons_own_utc_whatever_the_servers_zone():
    """The sessions work in UTC, so psycopg gives :data:`datetime.UTC` itself, which the models'
    timestamps take as they are (a zone named otherwise, e.g. ``Etc/UTC`` or the URL's
    ``-c TimeZone=…``, came back as a zoneinfo to convert on every row)."""
    url, name = pg_database()
    try:
        zoned = f"{url}?options=-c%20TimeZone%3DEurope/Zurich"
        engine = make_engine(zoned)
        with engine.connect() as conn:
            assert conn.execute(text("SHOW TimeZone")).scalar() == "UTC"
            found = conn.execute(text("SELECT timestamptz '2024-07-01 12:00+02'")).scalar()
        engine.dispose()
        assert found == datetime(2024, 7, 1, 10, tzinfo=UTC) and found.tzinfo is UTC
    finally:
        drop_pg_database(name)
