"""The live feed's liveness by arrivals on the wall clock: the pace of the fleet's clock (real
time until measured, then the clock's advance per wall second, measured afresh after a long
silence), the silence a coach may keep at that pace, and the status a coach's view then shows."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from trainclimate.service.store import liveness
from trainclimate.service.store.models import FleetClock
from trainclimate.service.store.queries import with_liveness

WALL = datetime(2026, 11, 24, 10, 0, tzinfo=UTC)
SIM = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
PERIOD = timedelta(minutes=5)


def clock(sim_advance_s: float, wall_s: float) -> FleetClock:
    """A live clock measured from (SIM, WALL) to the clock ``sim_advance_s`` later at wall time
    ``wall_s`` later."""
    return FleetClock(
        name="live",
        time=SIM + timedelta(seconds=sim_advance_s),
        anchor_time=SIM,
        anchor_at=WALL,
        arrived_at=WALL + timedelta(seconds=wall_s),
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
def test_the_pace_of_the_fleet_clock(sim_s, wall_s, pace):
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


class FakeSession:
    def __init__(self, row):
        self.row = row

    def get(self, *_args, **_kwargs):
        return self.row


class FakeCoach:
    last_seen_at = None


def test_arrivals_keep_the_anchor_until_a_long_silence():
    row = FleetClock(name="live", time=SIM)
    session, coach = FakeSession(row), FakeCoach()
    liveness.note_arrival(session, coach, WALL)
    assert (row.anchor_time, row.anchor_at, row.arrived_at) == (SIM, WALL, WALL)
    row.time = SIM + timedelta(hours=1)
    liveness.note_arrival(session, coach, WALL + timedelta(seconds=30))
    assert row.anchor_at == WALL and liveness.pace(row) == pytest.approx(120)
    assert coach.last_seen_at == WALL + timedelta(seconds=30)
    # the whole feed silent for longer than PACE_RESET_S: measured anew from the next arrival
    later = WALL + timedelta(seconds=30 + liveness.PACE_RESET_S + 1)
    liveness.note_arrival(session, coach, later)
    assert (row.anchor_time, row.anchor_at) == (row.time, later)
    assert liveness.pace(row) == 1.0


def view(status: str, fleet: str = "live", seen: datetime | None = WALL) -> dict:
    return {"fleet": fleet, "status": status, "last_seen_at": seen}


def test_the_status_a_live_coach_shows():
    fast = clock(3600, 30)
    now = WALL + timedelta(seconds=3)
    assert with_liveness(view("ok"), fast, now, PERIOD, 2)["status"] == "ok"
    silent_now = WALL + timedelta(seconds=6)
    assert with_liveness(view("ok"), fast, silent_now, PERIOD, 2)["status"] == "stale"
    # its tick decided stale (rows behind the clock) while it reports: its gateway is alive
    assert with_liveness(view("stale"), fast, now, PERIOD, 2)["status"] == "fallback"
    # the demo fleet and coaches without data are judged as before
    assert with_liveness(view("ok", "demo"), fast, silent_now, PERIOD, 2)["status"] == "ok"
    assert with_liveness(view("no-data", seen=None), fast, now, PERIOD, 2)["status"] == "no-data"
