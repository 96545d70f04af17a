"""Telemetry by calendar month (``store.partitions``) and migration 0013: a retention drops whole
monthly partitions before its cut-off on PostgreSQL and deletes the older rows left (all of them
on SQLite), never touching the window rollups; a row outside every month goes to the default
partition; a new month's partition takes its rows out of the default one; the migration turns a
table with rows into partitions and back with the same rows, ids and indexes; the service
creates the coming months' partitions at start, and starts all the same when it cannot."""

from __future__ import annotations

import logging
from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import insert, inspect, select, text
from sqlalchemy.exc import OperationalError

from helpers.service import flat_row
from trainclimate.service.app import create_app
from trainclimate.service.store import partitions
from trainclimate.service.store.db import Database, downgrade, make_engine, migrate
from trainclimate.service.store.models import Coach, CoachFeed, Telemetry, Train, WindowRollup
from trainclimate.service.store.telemetry import insert_rows

SEP, OCT, NOV = (datetime(2024, m, 1, tzinfo=UTC) for m in (9, 10, 11))
FAR = datetime(2099, 1, 15, 6, 1, tzinfo=UTC)


def hourly(start: datetime, hours: int) -> list[dict]:
    """:func:`flat_row` every hour from ``start`` on (each in a window of its own)."""
    return [flat_row(start + timedelta(hours=h)) for h in range(hours)]


def where(session) -> dict[str, int]:
    """Telemetry rows per partition (PostgreSQL) or in the one table (SQLite)."""
    if session.get_bind().dialect.name != "postgresql":
        return {"telemetry": session.query(Telemetry).count()}
    rows = session.execute(
        text("SELECT tableoid::regclass::text, count(*) FROM telemetry GROUP BY 1")
    )
    return dict(rows.all())


def rollups(session) -> tuple[list, list]:
    """Every window rollup and comfort state, as tuples."""
    windows = session.scalars(select(WindowRollup).order_by(WindowRollup.window)).all()
    comfort = session.scalars(select(CoachFeed)).all()
    return (
        [(w.coach_id, w.window, w.present, w.energy_kwh) for w in windows],
        [(c.coach_id, c.newest, c.last_ok) for c in comfort],
    )


@pytest.fixture
def one_coach_database(db_url):
    migrate(db_url)
    database = Database(db_url)
    with database.transaction() as s:
        s.add(Train(id="T", name="T"))
        s.flush()
        s.add(Coach(id="T-A", train_id="T", fleet="live", ddpc_active=True))
    yield database
    database.dispose()


def test_retention_drops_old_months_and_deletes_older_rows(one_coach_database):
    pg = one_coach_database.engine.dialect.name == "postgresql"
    with one_coach_database.transaction() as s:
        assert partitions.ensure_months(s, SEP, NOV) == (
            ["telemetry_y2024m09", "telemetry_y2024m10", "telemetry_y2024m11"] if pg else []
        )
        rows = [*hourly(SEP + timedelta(days=9), 48), *hourly(OCT + timedelta(days=9), 48)]
        rows += [*hourly(OCT + timedelta(days=24), 48), *hourly(NOV + timedelta(days=9), 48)]
        assert insert_rows(s, "T-A", rows) == 192
    with one_coach_database.transaction() as s:
        if pg:
            assert where(s) == {
                "telemetry_y2024m09": 48,
                "telemetry_y2024m10": 96,
                "telemetry_y2024m11": 48,
            }
        kept = rollups(s)
        assert len(kept[0]) == 192  # an hour apart: a window each
        assert s.get(CoachFeed, "T-A").first == SEP + timedelta(days=9)
    now = datetime(2024, 11, 19, 12, 0, tzinfo=UTC)
    with one_coach_database.transaction() as s:
        report = partitions.raw_retention(s, 30, now)
    cutoff = datetime(2024, 10, 20, 12, 0, tzinfo=UTC)
    assert report == {
        "cutoff": cutoff,
        "partitions_dropped": ["telemetry_y2024m09"] if pg else [],
        "rows_dropped": 48 if pg else 0,
        "rows_deleted": 48 if pg else 96,  # the 10th and 11th of October (and September)
        "database": "postgresql" if pg else "sqlite",
    }
    with one_coach_database.transaction() as s:
        times = s.scalars(select(Telemetry.time).order_by(Telemetry.time)).all()
        assert len(times) == 96 and times[0] == OCT + timedelta(days=24)
        assert s.get(CoachFeed, "T-A").first == times[0]  # where its data now begins
        assert where(s) == (
            {"telemetry_y2024m10": 48, "telemetry_y2024m11": 48} if pg else {"telemetry": 96}
        )
        assert partitions.monthly_partitions(s).keys() >= (
            {"telemetry_y2024m10", "telemetry_y2024m11"} if pg else set()
        )
        assert "telemetry_y2024m09" not in partitions.monthly_partitions(s)
        assert rollups(s) == kept
        # the next run has nothing left to drop
        again = partitions.raw_retention(s, 30, now)
        assert (again["partitions_dropped"], again["rows_dropped"], again["rows_deleted"]) == (
            [],
            0,
            0,
        )


def test_a_coach_whose_rows_are_all_dropped_begins_again_with_its_next(one_coach_database):
    with one_coach_database.transaction() as s:
        insert_rows(s, "T-A", hourly(OCT, 3))
    with one_coach_database.transaction() as s:
        partitions.raw_retention(s, 1, NOV)
    with one_coach_database.transaction() as s:
        feed = s.get(CoachFeed, "T-A")
        assert feed.first is None and feed.newest == OCT + timedelta(hours=2)
        insert_rows(s, "T-A", [flat_row(NOV)])
    with one_coach_database.transaction() as s:
        assert s.get(CoachFeed, "T-A").first == NOV


def test_a_row_outside_every_month_goes_to_the_default_partition(one_coach_database):
    pg = one_coach_database.engine.dialect.name == "postgresql"
    with one_coach_database.transaction() as s:
        assert insert_rows(s, "T-A", [flat_row(FAR)]) == 1
        assert insert_rows(s, "T-A", [flat_row(FAR)]) == 0  # ON CONFLICT (coach_id, time)
    with one_coach_database.transaction() as s:
        assert where(s) == ({"telemetry_default": 1} if pg else {"telemetry": 1})
        report = partitions.raw_retention(s, 1, datetime(2026, 11, 28, tzinfo=UTC))
        assert (report["rows_deleted"], report["rows_dropped"]) == (0, 0)
        assert s.scalars(select(Telemetry.time)).all() == [FAR]


def test_a_new_month_takes_its_rows_out_of_the_default_partition(one_coach_database):
    pg = one_coach_database.engine.dialect.name == "postgresql"
    february = FAR + timedelta(days=31)
    with one_coach_database.transaction() as s:
        insert_rows(
            s, "T-A", [flat_row(FAR), flat_row(FAR + timedelta(days=1)), flat_row(february)]
        )
        assert where(s) == ({"telemetry_default": 3} if pg else {"telemetry": 3})
    with one_coach_database.transaction() as s:
        created = partitions.ensure_months(s, FAR, FAR)
        assert created == (["telemetry_y2099m01"] if pg else [])
    with one_coach_database.transaction() as s:
        assert partitions.ensure_months(s, FAR, FAR) == []  # there already
        assert insert_rows(s, "T-A", [flat_row(FAR), flat_row(FAR + timedelta(days=2))]) == 1
        assert where(s) == (
            {"telemetry_y2099m01": 3, "telemetry_default": 1} if pg else {"telemetry": 4}
        )


def children(conn) -> set[str]:
    """The partitions of ``telemetry`` (from ``pg_inherits``)."""
    query = (
        "SELECT c.relname FROM pg_inherits i JOIN pg_class c ON c.oid = i.inhrelid "
        "WHERE i.inhparent = 'telemetry'::regclass"
    )
    return set(conn.execute(text(query)).scalars())


def test_the_migration_partitions_a_table_with_rows_and_back(db_url):
    """From 0012 with rows in September and October 2024 and an index added by hand: 0013 makes
    their months' partitions, this month's and the next two's and the default one, with the same
    rows and ids, the index, and the id sequence going on; the downgrade makes it one table
    again with the same rows."""
    migrate(db_url, "0012")
    db = Database(db_url)
    pg = db.engine.dialect.name == "postgresql"
    with db.transaction() as s:
        s.add(Train(id="T", name="T"))
        s.flush()
        # as the table is at 0012 (the model's coach has columns added since)
        s.execute(
            text(
                "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at) "
                "VALUES ('T-A', 'T', 'live', true, :t)"
            ),
            {"t": SEP},
        )
        # the rows alone (the feed's columns at 0012 are not the model's either)
        rows = [*hourly(SEP + timedelta(days=28), 30), *hourly(OCT, 5)]
        s.execute(insert(Telemetry.__table__), [{**r, "coach_id": "T-A"} for r in rows])
    db.dispose()
    engine = make_engine(db_url)
    everything = text("SELECT * FROM telemetry ORDER BY id")
    with engine.begin() as c:
        if pg:
            c.execute(text("CREATE INDEX ix_telemetry_time ON telemetry (time)"))
        before = c.execute(everything).all()
    assert len(before) == 35
    migrate(db_url)
    now = datetime.now(UTC)
    ahead = [partitions.month_start(now)]
    ahead += [
        partitions.next_month(ahead[-1]),
        partitions.next_month(partitions.next_month(ahead[-1])),
    ]
    with engine.begin() as c:
        assert c.execute(everything).all() == before
        if pg:
            assert children(c) == {
                "telemetry_y2024m09",
                "telemetry_y2024m10",
                "telemetry_default",
                *(partitions.partition_name(m) for m in ahead),
            }
            assert inspect(c).get_pk_constraint("telemetry")["constrained_columns"] == [
                "id",
                "time",
            ]
            assert "ix_telemetry_time" in {i["name"] for i in inspect(c).get_indexes("telemetry")}
    db = Database(db_url)
    with db.transaction() as s:  # the sequence goes on from the ids copied
        insert_rows(s, "T-A", [flat_row(OCT + timedelta(days=3))])
        newest = s.scalars(select(Telemetry.id).order_by(Telemetry.id.desc())).first()
        assert newest == before[-1].id + 1
    db.dispose()
    downgrade(db_url, "0012")
    with engine.begin() as c:
        after = c.execute(everything).all()
        assert after[:-1] == before and after[-1].id == before[-1].id + 1
        assert inspect(c).get_pk_constraint("telemetry")["constrained_columns"] == ["id"]
        if pg:
            assert children(c) == set()
            kind = c.execute(text("SELECT relkind FROM pg_class WHERE relname = 'telemetry'"))
            assert kind.scalar() == "r"
            assert not {t for t in inspect(c).get_table_names() if t.startswith("telemetry_")}
            assert "ix_telemetry_time" in {i["name"] for i in inspect(c).get_indexes("telemetry")}
    engine.dispose()


def test_the_service_creates_the_coming_months_at_start(settings, monkeypatch, caplog):
    migrate(settings.database_url)
    pg = settings.database_url.startswith("postgresql")
    last = partitions.month_start(datetime.now(UTC))
    for _ in range(partitions.AHEAD_MONTHS):
        last = partitions.next_month(last)
    db = Database(settings.database_url)
    if pg:  # as if the migration had run two months ago
        with db.transaction() as s:
            s.execute(text(f"DROP TABLE {partitions.partition_name(last)}"))
    with TestClient(create_app(settings)):
        pass
    with db.transaction() as s:
        have = partitions.monthly_partitions(s)
        assert (partitions.partition_name(last) in have) == pg
    db.dispose()

    def refused(*_args):
        raise OperationalError("ATTACH PARTITION", {}, Exception("lock timeout"))

    monkeypatch.setattr(partitions, "ensure_ahead", refused)
    with caplog.at_level(logging.ERROR), TestClient(create_app(settings)) as client:
        assert client.app.state.db is not None  # started
    assert "creating the telemetry partitions failed" in caplog.text
