"""The Alembic migrations on SQLite and PostgreSQL: upgrade head, downgrade base (with data in the
tables) and upgrade head again, through the service's own functions and through the alembic
command line as migrations/README.md shows it; and the ORM models match the migrated schema
(autogenerate compares them and finds nothing to change)."""

from __future__ import annotations

import os
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import inspect, select, text

from helpers.service import PG_SKIP, PG_URL, drop_pg_database, pg_database
from trainclimate.service.store import commands, liveness, partitions, plans
from trainclimate.service.store.db import MIGRATIONS, Database, downgrade, make_engine, migrate
from trainclimate.service.store.models import (
    AuditLog,
    Base,
    Coach,
    CoachFeed,
    FleetClock,
    Setpoint,
    SetpointRollup,
    Telemetry,
    Train,
    TrainPlan,
    TrialDay,
    User,
    WindowRollup,
)
from trainclimate.service.store.tokens import Principal, create_token

REPO = MIGRATIONS.parent
ALEMBIC = Path(sys.executable).with_name("alembic")
#: The newest revision.
HEAD = "0020"
TABLES = {
    "fleet_days",
    "pair_days",
    "setpoint_rollups",
    "window_rollups",
    "coach_feed",
    "coach_liveness",
    "pair_guards",
    "train_plans",
    "trial_days",
    "shadow_predictions",
    "trains",
    "coaches",
    "fleet_clocks",
    "telemetry",
    "setpoints",
    "overrides",
    "predictor_models",
    "users",
    "api_tokens",
    "audit_log",
}

#: The tables before 0008.
BEFORE_0008 = TABLES - {
    "fleet_days",
    "pair_days",
    "setpoint_rollups",
    "train_plans",
    "trial_days",
    "pair_guards",
    "coach_liveness",
    "window_rollups",
    "coach_feed",
}


def schema(url: str) -> tuple[set[str], str | None]:
    """The tables of the database at ``url`` (alembic's own and telemetry's partitions left
    out) and its revision."""
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            names = set(inspect(conn).get_table_names())
            revision = MigrationContext.configure(conn).get_current_revision()
    finally:
        engine.dispose()
    return {n for n in names - {"alembic_version"} if not partitions.is_partition(n)}, revision


def differences(url: str) -> list:
    """What autogenerate would change to make the database match the models (types too), with
    the filter migrations/env.py gives it: telemetry's partitions on PostgreSQL are pieces of
    that one table, not tables the models lack. The primary key of the partitioned table, (id,
    time), differs from the models' (id) — the ORM's identity, kept on both databases — and
    autogenerate does not compare primary keys, so the schemas compare equal."""
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            opts = {"compare_type": True, "include_name": partitions.include_name}
            context = MigrationContext.configure(conn, opts=opts)
            return compare_metadata(context, Base.metadata)
    finally:
        engine.dispose()


def fill(url: str) -> None:
    """A row in the tables with foreign keys, so the downgrade drops them in a valid order."""
    db = Database(url)
    now = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
    try:
        with db.transaction() as s:
            s.add(Train(id="T1", name="t"))
            s.flush()
            s.add(Coach(id="T1-A", train_id="T1", ddpc_active=True))
            s.flush()
            s.add(Telemetry(coach_id="T1-A", time=now, t_room_mid_c=21.0))
            s.add(Setpoint(coach_id="T1-A", tick=now, source="rule", reason="warmup"))
            s.add(
                TrainPlan(
                    train_id="T1",
                    plan="reference",
                    switch_hour=3,
                    seed=0,
                    reason="r",
                    effective_from=now,
                    created_by="alice",
                )
            )
            s.add(
                TrialDay(
                    train_id="T1",
                    day=now.date(),
                    plan="fixed",
                    switch_hour=3,
                    activated_coach_id="T1-A",
                )
            )
            create_token(s, "admin", "alice")
            s.add(AuditLog(user_name="alice", role="admin", action="test"))
        with db.transaction() as s:
            assert s.get(Coach, "T1-A").last_tick is None
            assert s.query(User).count() == 1
    finally:
        db.dispose()


def test_migrate_up_down_up(db_url):
    migrate(db_url)
    assert schema(db_url) == (TABLES, HEAD)
    assert set(Base.metadata.tables) == TABLES
    assert differences(db_url) == []
    fill(db_url)
    migrate(db_url)  # at head already: nothing to do, the data stays
    downgrade(db_url)
    assert schema(db_url) == (set(), None)
    migrate(db_url)
    assert schema(db_url) == (TABLES, HEAD)
    assert differences(db_url) == []


def alembic(db_url: str, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    """``alembic -c migrations/alembic.ini ARGS`` from the repository's root, the URL in
    ``$TRAINCLIMATE_DATABASE_URL`` (migrations/README.md)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    env |= {"TRAINCLIMATE_DATABASE_URL": db_url, "TRAINCLIMATE_HOME": str(tmp_path / "home")}
    done = subprocess.run(
        [str(ALEMBIC), "-c", "migrations/alembic.ini", *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    return done


@pytest.mark.slow  # four `alembic` processes
def test_alembic_command_line(db_url, tmp_path):
    assert ALEMBIC.exists(), f"no alembic script next to {sys.executable}"
    alembic(db_url, tmp_path, "upgrade", "head")
    assert schema(db_url) == (TABLES, HEAD)
    # `check` autogenerates against the models and fails on any difference
    assert "No new upgrade operations detected" in alembic(db_url, tmp_path, "check").stdout
    fill(db_url)
    alembic(db_url, tmp_path, "downgrade", "base")
    assert schema(db_url) == (set(), None)
    alembic(db_url, tmp_path, "upgrade", "head")
    assert schema(db_url) == (TABLES, HEAD)
    assert differences(db_url) == []


def test_the_active_flag_becomes_a_state(db_url):
    """0007 turns 0006's ``active`` flag into ``state`` (active or retired) and back."""
    from sqlalchemy import create_engine, text

    migrate(db_url, "0006")
    engine = create_engine(db_url)
    insert = text(
        "INSERT INTO predictor_models (version, method, rho, horizon, sampling_min, artifact,"
        " info, active, created_at) VALUES (:v, 'transient', 12, 6, 5, :a, '{}', :on, :t)"
    )
    now = datetime(2024, 11, 28, tzinfo=UTC)
    with engine.begin() as c:
        c.execute(insert, [{"v": 1, "a": b"x", "on": False, "t": now},
                           {"v": 2, "a": b"y", "on": True, "t": now}])  # fmt: skip
    migrate(db_url)
    with engine.begin() as c:
        rows = c.execute(text("SELECT version, state FROM predictor_models ORDER BY version"))
        assert rows.all() == [(1, "retired"), (2, "active")]
    downgrade(db_url, "0006")
    with engine.begin() as c:
        rows = c.execute(text("SELECT version, active FROM predictor_models ORDER BY version"))
        assert [(v, bool(a)) for v, a in rows] == [(1, False), (2, True)]
    engine.dispose()


def test_trial_plans_upgrade_a_database_in_use(db_url):
    """0008 adds the plan tables to a database at 0007 with trains, coaches and telemetry: every
    train then runs fixed, a plan can be set, and the downgrade drops the tables and keeps the
    trains."""
    migrate(db_url, "0007")
    db = Database(db_url)
    now = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
    try:
        with db.transaction() as s:
            s.add(Train(id="T1", name="t"))
            s.flush()
            # as the tables are at 0007 (the models have columns added since)
            s.execute(
                text(
                    "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at) "
                    "VALUES (:id, 'T1', 'live', :on, :t)"
                ),
                [{"id": "T1-A", "on": True, "t": now}, {"id": "T1-B", "on": False, "t": now}],
            )
            s.execute(
                text(
                    "INSERT INTO telemetry (coach_id, time, t_room_mid_c, mode, connected) "
                    "VALUES ('T1-A', :t, 21.0, 'regular', true)"
                ),
                {"t": now},
            )
        assert schema(db_url) == (BEFORE_0008, "0007")
        migrate(db_url)
        assert schema(db_url) == (TABLES, HEAD)
        with db.transaction() as s:
            train = s.get(Train, "T1")
            assert plans.view(s, train)["plan"] == "fixed"
            view = commands.set_plan(
                s, Principal("alice", "operator"), "T1", "alternate", 3, 0, "x"
            )
            assert view["pending"]["effective_from"] == "2024-11-29T02:00:00+00:00"
        downgrade(db_url, "0007")
        assert schema(db_url) == (BEFORE_0008, "0007")
        with db.transaction() as s:
            coaches = s.scalars(text("SELECT id FROM coaches WHERE train_id = 'T1' ORDER BY id"))
            assert list(coaches) == ["T1-A", "T1-B"]
    finally:
        db.dispose()


def test_liveness_moves_to_a_table_of_its_own(db_url):
    """0011 moves each live coach's arrival out of ``coaches`` (which the ticks lock) and the
    shared live clock out of ``fleet_clocks`` into ``coach_liveness``: each coach's clock its
    newest row, its arrival as it was; the downgrade brings both back."""
    from sqlalchemy import create_engine, text

    migrate(db_url, "0010")
    engine = create_engine(db_url)
    t0 = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
    seen = datetime(2026, 11, 27, 9, 0, tzinfo=UTC)
    with engine.begin() as c:
        train = text("INSERT INTO trains (id, name, created_at) VALUES ('T', 't', :t)")
        c.execute(train, {"t": t0})
        c.execute(
            text(
                "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at, last_seen_at)"
                " VALUES (:id, 'T', 'live', false, :t, :seen)"
            ),
            [{"id": "A", "t": t0, "seen": seen}, {"id": "B", "t": t0, "seen": None}],
        )
        c.execute(
            text(
                "INSERT INTO telemetry (coach_id, time, t_room_mid_c, mode, connected) "
                "VALUES ('A', :t, 21.0, 'regular', true)"
            ),
            [{"t": t0 + timedelta(minutes=m)} for m in (1, 2, 3)],
        )
        c.execute(
            text("INSERT INTO fleet_clocks (name, time, updated_at) VALUES ('live', :t, :t)"),
            {"t": t0 + timedelta(minutes=3)},
        )
    migrate(db_url)
    db = Database(db_url)
    try:
        with db.transaction() as s:
            rows = {c: (r.time, r.last_seen_at) for c, r in liveness.clocks(s).items()}
            assert rows == {"A": (t0 + timedelta(minutes=3), seen)}  # B never reported
            assert [f.name for f in s.scalars(select(FleetClock))] == []
    finally:
        db.dispose()
    downgrade(db_url, "0010")
    with engine.begin() as c:
        got = c.execute(text("SELECT id, last_seen_at FROM coaches ORDER BY id")).all()
        assert [g[0] for g in got] == ["A", "B"] and got[1][1] is None and got[0][1] is not None
        assert c.execute(text("SELECT count(*) FROM fleet_clocks WHERE name = 'live'")).scalar()
    engine.dispose()


def test_rollups_are_computed_for_the_telemetry_already_stored(db_url):
    """0012 adds the window rollups and comfort states and computes them from the telemetry a
    database at 0011 holds: the rows stamped 06:01–06:03 are bits 0–2 of their window; 0017
    each coach's oldest row."""
    from sqlalchemy import create_engine, text

    migrate(db_url, "0011")
    engine = create_engine(db_url)
    t0 = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
    with engine.begin() as c:
        train = text("INSERT INTO trains (id, name, created_at) VALUES ('T', 't', :t)")
        c.execute(train, {"t": t0})
        c.execute(
            text(
                "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at)"
                " VALUES ('A', 'T', 'live', false, :t)"
            ),
            {"t": t0},
        )
        c.execute(
            text(
                "INSERT INTO telemetry (coach_id, time, t_room_mid_c, t_rule_c, power_kw, mode,"
                " connected) VALUES ('A', :t, 21.0, 21.0, 6.0, 'regular', :up)"
            ),
            [{"t": t0 + timedelta(minutes=m), "up": m != 2} for m in (1, 2, 3)],
        )
    engine.dispose()
    migrate(db_url)
    db = Database(db_url)
    try:
        with db.transaction() as s:
            (rollup,) = s.scalars(select(WindowRollup))
            assert (rollup.coach_id, rollup.window) == ("A", round(t0.timestamp()) // 1800)
            assert (rollup.present, rollup.connected, rollup.powered) == (0b111, 0b101, 0b111)
            assert rollup.energy_kwh == pytest.approx(3 * 6.0 / 60)
            comfort = s.get(CoachFeed, "A")
            assert comfort.newest == comfort.last_ok == t0 + timedelta(minutes=3)
            assert comfort.first == t0 + timedelta(minutes=1)  # 0017, from the rows stored
    finally:
        db.dispose()
    downgrade(db_url, "0011")
    assert schema(db_url) == (
        TABLES - {"window_rollups", "coach_feed", "setpoint_rollups", "pair_days", "fleet_days"},
        "0011",
    )


def test_setpoint_rollups_are_counted_from_the_setpoints_already_stored(db_url):
    """0015 adds the setpoint rollups and counts the setpoints a database at 0014 holds: coach
    A's ticks at 06:00–06:25 in one window, its tick at 06:30 in the next, B's in its own."""
    from sqlalchemy import create_engine, text

    migrate(db_url, "0014")
    engine = create_engine(db_url)
    t0 = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
    ticks = [
        ("A", 0, "ddpc", "ok"),
        ("A", 5, "rule", "inactive"),
        ("A", 10, "rule", "costing_energy"),
        ("A", 15, "fallback", "stale"),
        ("A", 20, "rule", "no_model"),
        ("A", 25, "rule", "not_regular"),
        ("A", 30, "override", "override"),
        ("B", 0, "ddpc", "ok"),
    ]
    with engine.begin() as c:
        train = text("INSERT INTO trains (id, name, created_at) VALUES ('T', 't', :t)")
        c.execute(train, {"t": t0})
        c.execute(
            text(
                "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at)"
                " VALUES (:id, 'T', 'live', false, :t)"
            ),
            [{"id": cid, "t": t0} for cid in "AB"],
        )
        c.execute(
            text(
                "INSERT INTO setpoints (coach_id, tick, source, reason, detail, created_at)"
                " VALUES (:c, :t, :s, :r, '', :t)"
            ),
            [
                {"c": cid, "t": t0 + timedelta(minutes=m), "s": source, "r": reason}
                for cid, m, source, reason in ticks
            ],
        )
    engine.dispose()
    migrate(db_url)
    w0 = round(t0.timestamp()) // 1800
    columns = ("ticks", "ddpc", "inactive", "no_model", "override", "fallback", "not_regular")
    db = Database(db_url)
    try:
        with db.transaction() as s:
            got = {
                (r.coach_id, r.window - w0): tuple(getattr(r, c) for c in columns)
                for r in s.scalars(select(SetpointRollup))
            }
    finally:
        db.dispose()
    assert got == {
        ("A", 0): (6, 1, 2, 1, 0, 1, 1),
        ("A", 1): (1, 0, 0, 0, 1, 0, 0),
        ("B", 0): (1, 1, 0, 0, 0, 0, 0),
    }
    downgrade(db_url, "0014")
    assert schema(db_url) == (TABLES - {"setpoint_rollups", "pair_days", "fleet_days"}, "0014")


@pytest.mark.skipif(not PG_URL, reason=PG_SKIP)
def test_pair_days_keep_their_windows_uncompressed_on_postgresql():
    """A range's partial days cut their windows out of ``minutes``: stored uncompressed out of
    line from 0020 on (the server no longer decompresses every value it cuts), and back to
    PostgreSQL's default when downgraded."""
    url, name = pg_database()
    try:

        def storage() -> str:
            engine = make_engine(url)
            try:
                with engine.connect() as conn:
                    return conn.execute(
                        text(
                            "SELECT attstorage FROM pg_attribute "
                            "WHERE attrelid = 'pair_days'::regclass AND attname = 'minutes'"
                        )
                    ).scalar_one()
            finally:
                engine.dispose()

        migrate(url)
        assert storage() == "e"  # external: out of line, uncompressed
        downgrade(url, "0019")
        assert storage() == "x"  # extended: compressed, then out of line
    finally:
        drop_pg_database(name)
