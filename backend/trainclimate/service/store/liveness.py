"""Whether a live coach's feed is alive, judged against time that moves.

Each live coach has **its own clock**: the newest time of its own telemetry (``coach_liveness``,
:class:`~trainclimate.service.store.models.CoachLiveness`). Its ticks follow it (the scheduler
issues a coach the tick its newest row has reached), so one gateway's clock — ahead, behind,
jumping, or a week-old backlog — moves only its own coaches. Rows more than ``max_ahead_min``
ahead of the server's clock are refused (:class:`~trainclimate.service.store.commands.Backfill`,
reason ``ahead_of_clock``), so no coach's clock runs into the future either.

When a gateway stops, its coaches' clocks stop too, so nothing measured on them can say the feed
is down. Liveness is judged on the wall clock instead, by *arrivals*: each post or MQTT message
stamps its coach's ``last_seen_at`` (wall time). The server also measures each coach's clock's
**pace** — how many seconds of its clock pass per second of wall time, between an anchor (the
clock and the wall time when the measurement began) and its newest arrival: 1 for real gateways,
which report in real time, 120 for emulators at 120×. A live coach is **stale** when nothing has
arrived from it for ``stale_periods`` periods of its clock at its pace (10 min of wall time at
1×, 5 s at 120×). One gateway that stops turns its coaches stale; all of them stopping turns
every live coach stale, and the feed is **down** since the last arrival.

Until :data:`PACE_MIN_S` of wall time has been measured a coach's pace counts as the fleet's
(:attr:`Clocks.fleet_pace`: the median of the measured coaches' paces; 1, real time, the slowest,
without any), so a gateway that joins an accelerated fleet is judged at its speed from the start
and nothing is called stale too early. The measurement starts again after a silence of
the coach of :data:`PACE_RESET_S`, and when one arrival moves its clock forward by more than
:data:`PACE_JUMP` (a backlog caught up, a gateway's clock corrected): a jump is no pace, and a
coach that sends its week-old rows and then reports live is measured at its live pace.

Stamping an arrival touches only the coach's own ``coach_liveness`` row, never ``coaches``
(which the ticks lock) nor a row shared by all coaches: storing telemetry waits neither for a
tick nor for another coach's gateway.
"""

from __future__ import annotations

import functools
import statistics
from datetime import datetime, timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate.service.store.models import CoachLiveness
from trainclimate.service.store.upsert import insert_new

#: The live fleet's name.
LIVE = "live"
#: Wall time the pace must have been measured over before it counts; until then it is 1. [s]
PACE_MIN_S = 20.0
#: A silence of the coach this long (wall time) starts the pace's measurement anew. [s]
PACE_RESET_S = 600.0
#: An arrival that moves the coach's clock forward by more than this starts the pace's
#: measurement anew (a jump, not a pace). [clock time]
PACE_JUMP = timedelta(hours=1)


def note_arrival(session: Session, coach_id: str, newest: datetime, now: datetime) -> None:
    """Telemetry of ``coach_id`` up to ``newest`` (its rows' newest time) arrived at wall time
    ``now``: move the coach's clock forward to ``newest`` (never back), stamp the arrival and
    keep the pace's anchor. Locks only the coach's own ``coach_liveness`` row."""
    insert_new(
        session,
        CoachLiveness.__table__,
        [{"coach_id": coach_id, "time": newest, "anchor_time": newest, "anchor_at": now}],
        ["coach_id"],
    )
    row = session.scalar(
        select(CoachLiveness)
        .where(CoachLiveness.coach_id == coach_id)
        .with_for_update()
        .execution_options(populate_existing=True)
    )
    before = row.time
    row.time = max(row.time, newest)
    if (
        row.anchor_at is None
        or row.last_seen_at is None
        or (now - row.last_seen_at).total_seconds() > PACE_RESET_S
        or row.time - before > PACE_JUMP
    ):
        row.anchor_time, row.anchor_at = row.time, now
    row.last_seen_at = now


class Clocks(dict):
    """The live coaches' liveness rows (their clocks) by coach id, and the fleet's pace."""

    @functools.cached_property
    def fleet_pace(self) -> float:
        """The median :func:`pace` of the coaches whose pace is measured (1 without any): the
        pace a coach counts at until its own is measured. [clock s per wall s]"""
        paces = [pace(c) for c in self.values() if measured(c)]
        return statistics.median(paces) if paces else 1.0


def clocks(session: Session, coach_ids: list[str] | None = None) -> Clocks:
    """The live coaches' liveness rows (their clocks), by coach id (only ``coach_ids``, if
    given); a coach that never reported has none. Read without locking."""
    query = select(CoachLiveness)
    if coach_ids is not None:
        query = query.where(CoachLiveness.coach_id.in_(coach_ids))
    return Clocks((row.coach_id, row) for row in session.scalars(query))


def measured(clock: CoachLiveness | None) -> bool:
    """Whether the coach's pace has been measured over :data:`PACE_MIN_S` of wall time."""
    if clock is None or clock.anchor_at is None or clock.last_seen_at is None:
        return False
    return (clock.last_seen_at - clock.anchor_at).total_seconds() >= PACE_MIN_S


def pace(clock: CoachLiveness | None, prior: float = 1.0) -> float:
    """Seconds of a coach's clock per second of wall time (≥ 1); ``prior`` until measured over
    :data:`PACE_MIN_S`."""
    if not measured(clock):
        return prior
    wall = (clock.last_seen_at - clock.anchor_at).total_seconds()
    return max(1.0, (clock.time - clock.anchor_time).total_seconds() / wall)


def allowed_silence(
    clock: CoachLiveness | None, period: timedelta, stale_periods: int, prior: float = 1.0
) -> timedelta:
    """How long (wall time) a live coach may send nothing before it is stale:
    ``stale_periods`` periods of its clock at its :func:`pace` (``prior`` until measured)."""
    return stale_periods * period / pace(clock, prior)


def silent(
    last_seen_at: datetime | None,
    clock: CoachLiveness | None,
    now: datetime,
    period: timedelta,
    stale_periods: int,
    prior: float = 1.0,
) -> bool:
    """Whether a live coach last seen at ``last_seen_at`` (wall time; None: never), with its
    ``clock`` (its liveness row; its pace ``prior`` until measured, e.g. the fleet's), is stale
    at wall time ``now``."""
    return last_seen_at is None or now - last_seen_at > allowed_silence(
        clock, period, stale_periods, prior
    )
