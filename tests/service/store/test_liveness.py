"""The live feed's liveness by arrivals on the wall clock: the pace of a coach's own clock (real
time until measured, then the clock's advance per wall second, measured afresh after a long
silence or a jump), the silence a coach may keep at that pace, and the status a coach's view
then shows — per coach: one coach's backlog or jump leaves the others as they are."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from trainclimate.service.store import liveness
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import Coach, CoachLiveness, Train
from trainclimate.service.store.queries import with_liveness

WALL = datetime(2026, 11, 24, 10, 0, tzinfo=UTC)
SIM = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
PERIOD = timedelta(minutes=5)


def clock(sim_advance_s: float, wall_s: float) -> CoachLiveness:
    """A coach's clock measured from (SIM, WALL) to the clock ``sim_advance_s`` later at wall
    time ``wall_s`` later."""
    return CoachLiveness(
        coach_id="A",
        time=SIM + timedelta(seconds=sim_advance_s),
        anchor_time=SIM,
        anchor_at=WALL,
        last_seen_at=WALL + timedelta(seconds=wall_s),
    )


@pytest.mark.parametrize(
    "sim_s, wall_s, pace",
    [
        (0, 0, 1.0),  # nothing measured yet: real time
        (1200, 10, 1.0),  # 120× but only 10 s measured: still counted as real time
        (3600, 30, 120.0),  # an emulator at 120×
        (600, 600, 1.0),  # real gateways
        (60, 600, 1.0),  # slower than real time counts as real time
    ],
)
def test_the_pace_of_a_coach_clock(sim_s, wall_s, pace):
    assert liveness.pace(clock(sim_s, wall_s)) == pytest.approx(pace)


def test_a_coach_is_stale_after_two_periods_at_the_pace():
    fast = clock(3600, 30)  # 120×: two periods are 5 s of wall time
    assert liveness.allowed_silence(fast, PERIOD, 2) == timedelta(seconds=5)
    seen = WALL + timedelta(seconds=30)
    assert not liveness.silent(seen, fast, seen + timedelta(seconds=4.9), PERIOD, 2)
    assert liveness.silent(seen, fast, seen + timedelta(seconds=5.1), PERIOD, 2)
    assert liveness.silent(None, fast, seen, PERIOD, 2)  # never seen
    real = clock(600, 600)  # 1×: ten minutes
    assert liveness.allowed_silence(real, PERIOD, 2) == timedelta(minutes=10)
    assert liveness.allowed_silence(None, PERIOD, 2) == timedelta(minutes=10)


@pytest.fixture
def live_coaches_database(db_url):
    """A migrated database (SQLite, then PostgreSQL) with live coaches A and B."""
    migrate(db_url)
    database = Database(db_url)
    with database.transaction() as s:
        s.add(Train(id="T", name="T"))
        s.flush()
        s.add_all([Coach(id=c, train_id="T", fleet="live") for c in "AB"])
    yield database
    database.dispose()


def arrive(db: Database, coach_id: str, newest: datetime, now: datetime) -> CoachLiveness:
    with db.transaction() as s:
        liveness.note_arrival(s, coach_id, newest, now)
    with db.transaction() as s:
        return liveness.clocks(s)[coach_id]


def test_arrivals_keep_the_anchor_until_a_long_silence(live_coaches_database):
    row = arrive(live_coaches_database, "A", SIM, WALL)
    assert (row.time, row.anchor_time, row.anchor_at, row.last_seen_at) == (SIM, SIM, WALL, WALL)
    row = arrive(
        live_coaches_database, "A", SIM + timedelta(minutes=50), WALL + timedelta(seconds=25)
    )
    assert row.anchor_at == WALL and liveness.pace(row) == pytest.approx(120)
    row = arrive(
        live_coaches_database, "A", SIM, WALL + timedelta(seconds=30)
    )  # older rows: the clock stays
    assert row.time == SIM + timedelta(minutes=50) and row.last_seen_at == WALL + timedelta(
        seconds=30
    )
    # the coach silent for longer than PACE_RESET_S: measured anew from the next arrival
    later = WALL + timedelta(seconds=30 + liveness.PACE_RESET_S + 1)
    row = arrive(live_coaches_database, "A", SIM + timedelta(minutes=51), later)
    assert (row.anchor_time, row.anchor_at) == (row.time, later)
    assert liveness.pace(row) == 1.0


def test_a_backlog_then_live_rows_is_measured_at_the_live_pace(live_coaches_database):
    """A fresh coach sends its week-old rows, then reports live every second: the jump from
    the backlog to now is no pace, so its allowed silence stays that of real time (10 min),
    not under a second; the other coach's clock is untouched."""
    week_ago = WALL - timedelta(days=7)
    arrive(live_coaches_database, "B", WALL, WALL)
    for i in range(10):  # the backlog, oldest first, a batch a second
        arrive(
            live_coaches_database,
            "A",
            week_ago + timedelta(hours=12 * i),
            WALL + timedelta(seconds=i),
        )
    for s in range(60):  # then live, a row a minute… reported each second (real time: 1 s)
        row = arrive(
            live_coaches_database,
            "A",
            WALL + timedelta(seconds=s),
            WALL + timedelta(seconds=10 + s),
        )
    assert liveness.pace(row) == pytest.approx(1.0)
    assert liveness.allowed_silence(row, PERIOD, 2) == timedelta(minutes=10)
    with live_coaches_database.transaction() as s:
        other = liveness.clocks(s)["B"]
    assert (other.time, other.anchor_time, other.last_seen_at) == (WALL, WALL, WALL)
    assert not liveness.silent(other.last_seen_at, other, WALL + timedelta(minutes=9), PERIOD, 2)


def view(status: str, fleet: str = "live", seen: datetime | None = WALL) -> dict:
    return {"fleet": fleet, "status": status, "last_seen_at": seen}


def test_the_status_a_live_coach_shows():
    fast = clock(3600, 30)  # last seen at WALL + 30 s, at 120×
    now = WALL + timedelta(seconds=33)
    # the arrival is the clock's, whatever the (cached) view last said
    shown = with_liveness(view("ok"), fast, now, PERIOD, 2)
    assert shown["status"] == "ok" and shown["last_seen_at"] == WALL + timedelta(seconds=30)
    silent_now = WALL + timedelta(seconds=36)
    assert with_liveness(view("ok"), fast, silent_now, PERIOD, 2)["status"] == "stale"
    assert with_liveness(view("ok"), None, now, PERIOD, 2)["status"] == "stale"  # never seen
    # its tick decided stale (rows behind the clock) while it reports: its gateway is alive
    assert with_liveness(view("stale"), fast, now, PERIOD, 2)["status"] == "fallback"
    # the demo fleet and coaches without data are judged as before
    assert with_liveness(view("ok", "demo"), fast, silent_now, PERIOD, 2)["status"] == "ok"
    assert with_liveness(view("no-data", seen=None), fast, now, PERIOD, 2)["status"] == "no-data"


def test_a_coach_not_yet_measured_counts_at_the_fleet_pace():
    """A gateway joining a fleet of emulators at 120× is judged at 120× from its first arrival
    (the median of the measured paces), not at real time for its first 20 s."""
    fleet = liveness.Clocks({"A": clock(3600, 30), "B": clock(3600, 30), "C": clock(600, 600)})
    assert fleet.fleet_pace == pytest.approx(120)
    new = CoachLiveness(coach_id="N", time=SIM, anchor_time=SIM, anchor_at=WALL, last_seen_at=WALL)
    assert not liveness.measured(new)
    assert liveness.allowed_silence(new, PERIOD, 2, fleet.fleet_pace) == timedelta(seconds=5)
    assert liveness.silent(WALL, new, WALL + timedelta(seconds=6), PERIOD, 2, fleet.fleet_pace)
    assert liveness.Clocks().fleet_pace == 1.0  # nothing measured: real time
