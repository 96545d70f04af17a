"""Whether the live feed is alive, judged against time that moves.

The live coaches share one clock: the newest telemetry time any gateway reported. When every
gateway stops, that clock stops too, so nothing measured on it can say the feed is down. Liveness
is judged on the wall clock instead, by *arrivals*: each post or MQTT message stamps its coach's
``last_seen_at`` and the live clock's ``arrived_at`` (wall time). The server also measures the
clock's **pace** — how many seconds of the clock pass per second of wall time, between an anchor
(the clock and the wall time when the measurement began) and the newest arrival: 1 for real
gateways, which report in real time, 120 for emulators at 120×. A live coach is **stale** when
nothing has arrived from it for ``stale_periods`` periods of the clock at that pace (10 min of
wall time at 1×, 5 s at 120×). One gateway that stops turns its coaches stale; all of them
stopping turns every live coach stale, and the feed is **down** since the last arrival.

Until :data:`PACE_MIN_S` of wall time has been measured the pace counts as 1 (real time: the
slowest, so nothing is called stale too early); after a silence of :data:`PACE_RESET_S` the
measurement starts again, so a feed that resumes at another speed is measured afresh.

**Clocks of different gateways** are not reconciled: the live coaches have one clock, the
newest row of any gateway, and the ticks follow it. Rows behind it are always stored (a gateway
sending what it kept through a lost connection loses nothing), and their coach is not called
stale while they arrive; but its ticks, at the fleet's clock, find no recent data of it and are
decided under T_rule (reason ``stale``; its status shows ``fallback``, not ``stale``, since its
gateway is alive) until its rows catch up. A gateway reporting ahead of the others moves the
clock, and so every other coach's ticks, into its future. Real gateways report UTC now (the API
refuses rows more than 5 min ahead of the server's clock), so this is a matter for emulators:
faster than real time, they must run at one speed and start together.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from sqlalchemy.orm import Session

from trainclimate.service.store.models import Coach, FleetClock

#: The live fleet's clock.
LIVE = "live"
#: Wall time the pace must have been measured over before it counts; until then it is 1. [s]
PACE_MIN_S = 20.0
#: A silence of the whole feed this long (wall time) starts the pace's measurement anew. [s]
PACE_RESET_S = 600.0


def note_arrival(session: Session, coach: Coach, now: datetime) -> None:
    """Telemetry of ``coach`` arrived at wall time ``now`` (after the live clock was advanced
    in this transaction): stamp the coach and the clock, and keep the pace's anchor."""
    coach.last_seen_at = now
    clock = session.get(FleetClock, LIVE, with_for_update=True, populate_existing=True)
    if (
        clock.anchor_at is None
        or clock.arrived_at is None
        or (now - clock.arrived_at).total_seconds() > PACE_RESET_S
    ):
        clock.anchor_time, clock.anchor_at = clock.time, now
    clock.arrived_at = now


def pace(clock: FleetClock | None) -> float:
    """Seconds of the live clock per second of wall time (≥ 1; 1 until measured over
    :data:`PACE_MIN_S`)."""
    if clock is None or clock.anchor_at is None or clock.arrived_at is None:
        return 1.0
    wall = (clock.arrived_at - clock.anchor_at).total_seconds()
    if wall < PACE_MIN_S:
        return 1.0
    return max(1.0, (clock.time - clock.anchor_time).total_seconds() / wall)


def allowed_silence(clock: FleetClock | None, period: timedelta, stale_periods: int) -> timedelta:
    """How long (wall time) a live coach may send nothing before it is stale:
    ``stale_periods`` periods of the clock at its :func:`pace`."""
    return stale_periods * period / pace(clock)


def silent(
    last_seen_at: datetime | None,
    clock: FleetClock | None,
    now: datetime,
    period: timedelta,
    stale_periods: int,
) -> bool:
    """Whether a live coach last seen at ``last_seen_at`` (wall time; None: never) is stale at
    wall time ``now``."""
    return last_seen_at is None or now - last_seen_at > allowed_silence(
        clock, period, stale_periods
    )
