"""What the API reads: coaches with their status, time series, setpoints and pair comparisons.

The pair comparison is in :mod:`.comparison`.

:func:`coach_states` reads what a coach's view is computed from, in a few index probes: the state
its answer is kept under in :class:`~trainclimate.service.store.cache.ReadCache`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from datetime import UTC, datetime, timedelta, tzinfo
from typing import Any

import numpy as np
import pandas as pd
from sqlalchemy import func, select, true
from sqlalchemy.orm import Session
from sqlalchemy.sql.expression import ColumnElement

from trainclimate.coach.setpoint import COMFORT_BAND_K, U_BAND_K
from trainclimate.service.store import liveness
from trainclimate.service.store.comfort import comfort_now
from trainclimate.service.store.models import (
    Coach,
    CoachFeed,
    CoachLiveness,
    FleetClock,
    Override,
    Setpoint,
    Telemetry,
    Train,
)
from trainclimate.service.store.records import (
    CoachView,
    NoSetpoint,
    Replica,
    SetpointHistory,
    SetpointView,
    TimeSeries,
)
from trainclimate.service.store.telemetry import load_frame

#: A coach's status from the reason of its newest setpoint (any other reason: ``fallback``).
#: Before it come, in this order: ``no-data`` (nothing reported), ``stale`` (no telemetry in
#: time), ``disconnected`` (the newest telemetry row says the link to the HVAC is down: it holds
#: T_rule whatever was issued), ``override`` and ``warm-up`` (no setpoint yet).
STATUS = {
    "ok": "ok",
    "warmup": "warm-up",
    "stale": "stale",
    "override": "override",
    "inactive": "inactive",
    "not_regular": "not-regular",
    "no_model": "preparing",
}
#: Every status a coach view can have, those decided before the setpoint's reason first.
STATUSES = (
    "no-data",
    "stale",
    "disconnected",
    "override",
    "warm-up",
    "ok",
    "inactive",
    "not-regular",
    "preparing",
    "fallback",
)
#: The view's reason of a ``disconnected`` coach (in place of its newest setpoint's).
CONNECTION_LOST = "connection_lost"


#: The time ranges the API reads (far outside, dates overflow in the arithmetic behind a read).
EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
LATEST = datetime(2200, 1, 1, tzinfo=UTC)


class NotFoundError(LookupError):
    """A coach, train or record that does not exist (→ 404)."""


class RequestError(ValueError):
    """A request the API cannot carry out as asked: a bad range, a value outside its band (→ 422).
    Only this is mapped to 422: any other ValueError is a bug and answers 500."""


def coach_or_404(session: Session, coach_id: str) -> Coach:
    """The coach ``coach_id``; :class:`NotFoundError` if there is none."""
    coach = session.get(Coach, coach_id)
    if coach is None:
        raise NotFoundError(f"no coach {coach_id!r}")
    return coach


def train_or_404(session: Session, train_id: str) -> Train:
    """The train ``train_id``; :class:`NotFoundError` if there is none."""
    train = session.get(Train, train_id)
    if train is None:
        raise NotFoundError(f"no train {train_id!r}")
    return train


def fleet_clock(session: Session, coach: Coach) -> datetime | None:
    """The coach's clock: its fleet's simulated time (the demo), or a live coach's own — the
    newest time of its telemetry (:mod:`.liveness`); None before any."""
    if coach.fleet == liveness.LIVE:
        own = session.get(CoachLiveness, coach.id)
        if own is not None:
            return own.time
    else:
        clock = session.get(FleetClock, coach.fleet)
        if clock is not None:
            return clock.time
    return session.scalar(select(func.max(Telemetry.time)).where(Telemetry.coach_id == coach.id))


def newest_setpoint(session: Session, coach: Coach) -> Setpoint | None:
    """The coach's setpoint of its latest tick, or None before its first."""
    return session.scalar(
        select(Setpoint)
        .where(Setpoint.coach_id == coach.id)
        .order_by(Setpoint.tick.desc())
        .limit(1)
    )


def coach_view(session: Session, coach: Coach, period: timedelta, stale_periods: int) -> CoachView:
    """A coach with its newest setpoint, telemetry and override, its status and its comfort now.

    Parameters
    ----------
    coach : Coach
        The coach.
    period : datetime.timedelta
        The sampling period of the ticks.
    stale_periods : int
        A demo coach whose newest row is more than this many periods behind its fleet's clock is
        ``stale`` (a live coach's silence is judged by :func:`with_liveness`).

    Returns
    -------
    CoachView
        The fields of the API's ``CoachOut``. ``status`` is the first that applies of: ``no-data``
        (no setpoint and no telemetry), ``stale`` (no telemetry in time), ``disconnected`` (the
        newest row says the link to the HVAC is down: the HVAC holds T_rule, whatever was
        issued; ``reason`` is then :data:`CONNECTION_LOST`), ``override``, ``warm-up`` (no
        setpoint yet) and the newest setpoint's reason mapped by :data:`STATUS` (else
        ``fallback``). ``t_ref_c`` is the T_ref issued at the newest tick [°C];
        ``t_ref_applied`` whether the coach's HVAC receives it: False when its newest row says
        the link is down (it holds T_rule, ``t_rule_c``), None when that is unknown (no T_ref
        issued, or no telemetry in time), else True. ``comfort`` is
        :func:`.comfort.comfort_now` of the newest row, None without telemetry in time (what
        its decks are now is unknown).
    """
    setpoint = newest_setpoint(session, coach)
    row = session.scalar(
        select(Telemetry)
        .where(Telemetry.coach_id == coach.id)
        .order_by(Telemetry.time.desc())
        .limit(1)
    )
    clock = fleet_clock(session, coach)
    override = None
    if clock is not None:
        override = session.scalar(
            select(Override)
            .where(Override.coach_id == coach.id, Override.cancelled_at.is_(None))
            .where(Override.starts_at <= clock, Override.ends_at > clock)
            .order_by(Override.created_at.desc())
            .limit(1)
        )
    # a live coach's silence is judged on the wall clock (with_liveness), the demo's on its clock
    unseen = row is None or (
        coach.fleet != liveness.LIVE
        and clock is not None
        and row.time < clock - stale_periods * period
    )
    if setpoint is None and row is None:
        status = "no-data"
    elif unseen:
        status = "stale"
    elif not row.connected:
        status = "disconnected"
    elif override is not None:
        status = "override"
    elif setpoint is None:
        status = "warm-up"
    else:
        status = STATUS.get(setpoint.reason, "fallback")
    t_room = [row.t_room_up_c, row.t_room_mid_c, row.t_room_low_c] if row else None
    t_ref = setpoint.t_ref_c if setpoint else None
    return {
        "id": coach.id,
        "train_id": coach.train_id,
        "fleet": coach.fleet,
        "ddpc_active": coach.ddpc_active,
        "mode": row.mode if row else None,
        "status": status,
        "reason": CONNECTION_LOST
        if status == "disconnected"
        else (setpoint.reason if setpoint else None),
        # the setpoint's T_rule, else the newest row's (a tick before any row has none)
        "t_rule_c": next(
            (
                v
                for v in (setpoint.t_rule_c if setpoint else None, row.t_rule_c if row else None)
                if v is not None
            ),
            None,
        ),
        "t_ref_c": t_ref,
        "t_ref_applied": None if t_ref is None or unseen else bool(row.connected),
        "comfort_band_k": COMFORT_BAND_K,
        "setpoint_band_k": U_BAND_K,
        "t_room_c": t_room,
        "comfort": None if unseen else comfort_now(t_room, row.t_rule_c, row.mode, COMFORT_BAND_K),
        "last_tick": setpoint.tick if setpoint else None,
        "last_solve_ms": setpoint.solve_time_ms if setpoint else None,
        "override_until": override.ends_at if override else None,
        "clock": clock,
        "last_seen_at": last_seen(session, coach),
    }


def last_seen(session: Session, coach: Coach) -> datetime | None:
    """When the live coach's telemetry last arrived (wall time; None: never, or not live)."""
    own = session.get(CoachLiveness, coach.id) if coach.fleet == liveness.LIVE else None
    return own.last_seen_at if own is not None else None


def with_liveness(
    view: CoachView,
    clock: CoachLiveness | None,
    now: datetime,
    period: timedelta,
    stale_periods: int,
    prior: float = 1.0,
) -> CoachView:
    """The :func:`coach_view` ``view`` with a live coach's status judged by arrivals (wall time
    ``now``; ``clock`` its liveness row, :mod:`.liveness`): ``stale`` when nothing has arrived
    from it for ``stale_periods`` periods at its clock's pace (``prior`` until measured, the
    fleet's: :attr:`.liveness.Clocks.fleet_pace`; whatever its newest row said:
    ``disconnected`` too; its ``t_ref_applied`` and ``comfort`` then unknown, None); while its
    telemetry arrives, a tick decided ``stale`` (its rows behind its clock) shows as
    ``fallback``: its gateway is alive. Kept apart from the view, which is cached while its data
    is unchanged: silence changes nothing stored (its ``last_seen_at`` is taken from
    ``clock``)."""
    if view["fleet"] != liveness.LIVE:
        return view
    view = {**view, "last_seen_at": clock.last_seen_at if clock is not None else None}
    if view["status"] == "no-data":
        return view
    if liveness.silent(view["last_seen_at"], clock, now, period, stale_periods, prior):
        return {**view, "status": "stale", "t_ref_applied": None, "comfort": None}
    if view["status"] == "stale":
        return {**view, "status": "fallback"}
    return view


def live_clocks(session: Session) -> liveness.Clocks:
    """The live coaches' own clocks and arrivals (:func:`.liveness.clocks`), by coach id."""
    return liveness.clocks(session)


def coach_states(session: Session, coach_id: str | None = None) -> list[tuple[str, tuple]]:
    """Every coach's id, by id (or only ``coach_id``: :class:`NotFoundError` if there is none),
    with, read in the same statement, the state its :func:`coach_view` is computed from: the coach's
    own columns, its last tick, its newest and oldest telemetry times as its feed
    keeps them (:class:`~.models.CoachFeed`, one row per coach: no look-up in the telemetry),
    its fleet's clock, and how many overrides it has and how many of them were cancelled. The
    view reads the same coach row; setpoints and telemetry are only inserted, clocks only
    advance, and an override is only ever cancelled once, so a coach whose state is unchanged
    has an unchanged view. Setpoints are inserted by the live loop only, in the transaction that
    moves the coach's last tick up to theirs (:mod:`~trainclimate.service.scheduler`): the last
    tick is the newest setpoint's (a look-up of it per coach cost 15 of the statement's 19 ms
    at 900 coaches, measured). In particular the newest telemetry row — whose ``connected`` decides
    ``disconnected`` and whose decks decide ``comfort`` — is never rewritten (a resent minute is
    skipped): a new one changes the newest time; the retention, which deletes rows, reads the
    oldest again (:func:`.rollups.recount_firsts`). Plain columns, not the coach's ORM object:
    at 900 coaches the objects cost 13 of the statement's 38 ms, measured, and a view kept in the
    read cache does not need one (:func:`coach_rows` loads those that do)."""
    clock = select(FleetClock.time).where(FleetClock.name == Coach.fleet)
    overrides = select(func.count()).select_from(Override).where(Override.coach_id == Coach.id)
    cancelled = select(func.count(Override.cancelled_at)).where(Override.coach_id == Coach.id)
    query = (
        select(
            Coach.id,
            Coach.train_id,
            Coach.fleet,
            Coach.ddpc_active,
            Coach.last_tick,
            CoachFeed.newest,
            CoachFeed.first,
            clock.scalar_subquery(),
            overrides.scalar_subquery(),
            cancelled.scalar_subquery(),
        )
        .outerjoin(CoachFeed, CoachFeed.coach_id == Coach.id)
        .order_by(Coach.id)
    )
    if coach_id is not None:
        query = query.where(Coach.id == coach_id)
    rows = session.execute(query).all()
    if coach_id is not None and not rows:
        raise NotFoundError(f"no coach {coach_id!r}")
    return [(cid, tuple(state)) for cid, *state in rows]


def coach_rows(session: Session, ids: list[str]) -> dict[str, Coach]:
    """The coaches ``ids`` by id, in one statement."""
    wanted = set(ids)
    if not wanted:
        return {}
    found = session.scalars(select(Coach).where(among(Coach.id, wanted)))
    return {c.id: c for c in found if c.id in wanted}


def time_range(
    session: Session, coach: Coach, start: datetime | None, end: datetime | None
) -> tuple[datetime, datetime]:
    """[start, end], by default the last 24 h of the coach's clock."""
    clock = fleet_clock(session, coach) or pd.Timestamp.now(tz="UTC").to_pydatetime()
    return checked_range(end or clock, start, timedelta(hours=24))


def checked_range(
    end: datetime, start: datetime | None, default: timedelta
) -> tuple[datetime, datetime]:
    """[start, end] in UTC, ``start`` by default ``default`` before ``end``;
    :class:`RequestError` unless it lies in :data:`EARLIEST` … :data:`LATEST`, is not empty and
    spans at most 31 days."""
    try:
        end = end.astimezone(UTC)
        start = (start or end - default).astimezone(UTC)
    except OverflowError:
        raise RequestError(f"start and end must lie in {EARLIEST:%Y} … {LATEST:%Y}") from None
    if start < EARLIEST or end > LATEST:
        raise RequestError(f"start and end must lie in {EARLIEST:%Y} … {LATEST:%Y}")
    if start >= end:
        raise RequestError("start must be before end")
    if end - start > timedelta(days=31):
        raise RequestError("at most 31 days at a time")
    return start, end


def _none(values: Iterable[float | None]) -> list[float | None]:
    return [
        None if v is None or (isinstance(v, float) and not np.isfinite(v)) else v for v in values
    ]


def timeseries(session: Session, coach: Coach, start: datetime, end: datetime) -> TimeSeries:
    """The coach's telemetry in (start, end] with the source of the setpoint in force."""
    frame = load_frame(session, coach.id, start, end)
    ticks = session.execute(
        select(Setpoint.tick, Setpoint.source)
        .where(Setpoint.coach_id == coach.id, Setpoint.tick <= end)
        .where(Setpoint.tick > start - timedelta(hours=1))
        .order_by(Setpoint.tick)
    ).all()
    if len(frame) and ticks:
        sp = pd.DataFrame(ticks, columns=["tick", "source"])
        sp["tick"] = pd.to_datetime(sp["tick"], utc=True)
        # a row stamped t covers the minute (t − 1 min, t]: the setpoint issued at tick t acts
        # from t on, so the row at t still ran under the one before
        joined = pd.merge_asof(
            frame.reset_index()[["time"]],
            sp,
            left_on="time",
            right_on="tick",
            direction="backward",
            allow_exact_matches=False,
        )
        source = [None if pd.isna(s) else s for s in joined["source"]]
    else:
        source = [None] * len(frame)
    return {
        "time": [t.to_pydatetime() for t in frame.index],
        "t_room_c": [
            _none(r)
            for r in frame[["t_room_up_c", "t_room_mid_c", "t_room_low_c"]].itertuples(index=False)
        ],
        "t_ref_c": _none(frame["t_ref_c"]),
        "t_rule_c": _none(frame["t_rule_c"]),
        "t_amb_c": _none(frame["t_amb_c"]),
        "ghi_w_m2": _none(frame["ghi_w_m2"]),
        "power_kw": _none(frame["power_kw"]),
        "floor_power_kw": _none(frame["floor_power_kw"]),
        "occupancy_pct": _none(frame["occupancy_pct"]),
        "speed_kmh": _none(frame["speed_kmh"]),
        "mode": list(frame["mode"]),
        "connected": [bool(c) for c in frame["connected"]],
        "source": source,
    }


def setpoint_history(
    session: Session, coach: Coach, start: datetime, end: datetime
) -> SetpointHistory:
    """The coach's setpoints with ticks in (start, end], oldest first, one list per field."""
    rows = session.scalars(
        select(Setpoint)
        .where(Setpoint.coach_id == coach.id, Setpoint.tick > start, Setpoint.tick <= end)
        .order_by(Setpoint.tick)
    ).all()
    return {
        "tick": [r.tick for r in rows],
        "t_ref_c": [r.t_ref_c for r in rows],
        "t_rule_c": [r.t_rule_c for r in rows],
        "source": [r.source for r in rows],
        "reason": [r.reason for r in rows],
        "solve_time_ms": [r.solve_time_ms for r in rows],
        "predicted": [r.predicted for r in rows],
    }


def current_setpoint(
    session: Session, coach: Coach, period: timedelta, stale_periods: int
) -> SetpointView | NoSetpoint:
    """The newest setpoint, valid until ``stale_periods`` periods after its tick — if it still
    is on the coach's clock (:func:`expired`); else, as before any, all None: the gateway keeps
    its HVAC's T_rule."""
    sp = newest_setpoint(session, coach)
    view = None if sp is None else setpoint_view(coach.id, sp, stale_periods * period)
    if view is None or expired(view, fleet_clock(session, coach)):
        return {
            "coach_id": coach.id,
            "tick": None,
            "t_ref_c": None,
            "t_rule_c": None,
            "source": None,
            "reason": None,
            "valid_until": None,
        }
    return view


def expired(view: SetpointView, clock: datetime | None) -> bool:
    """Whether the setpoint ``view`` (:func:`setpoint_view`) is no longer valid at ``clock``
    (its coach's clock now; None: unknown, taken as valid): a setpoint decided by a replica
    that was paused, published or served after its validity, would hold the coach at a stale
    T_ref."""
    return clock is not None and clock >= view["valid_until"]


def setpoint_view(coach_id: str, sp: Setpoint | dict, valid_for: timedelta) -> SetpointView:
    """What a coach's gateway is told of setpoint ``sp`` (a :class:`Setpoint` or its row as a
    dict), valid for ``valid_for`` after its tick — by ``GET /coaches/{id}/setpoint`` and on the
    coach's MQTT setpoint topic."""
    get: Callable[[str], Any] = sp.get if isinstance(sp, dict) else lambda name: getattr(sp, name)
    return {
        "coach_id": coach_id,
        "tick": get("tick"),
        "t_ref_c": get("t_ref_c"),
        "t_rule_c": get("t_rule_c"),
        "source": get("source"),
        "reason": get("reason"),
        "valid_until": get("tick") + valid_for,
    }


def pair_coaches(train: Train) -> tuple[Coach, Coach] | None:
    """The train's pair, ordered by id (coach 0, coach 1): its first activated and first
    deactivated coach, or — when no coach or every coach is activated (a reference day of a
    trial) — its first two coaches; None with fewer than two coaches."""
    return pick_pair(train.coaches)


def pick_pair(coaches: list):
    """:func:`pair_coaches` of a train's ``coaches`` (by id; anything with ``id`` and
    ``ddpc_active``)."""
    if len(coaches) == 2 and coaches[0].ddpc_active != coaches[1].ddpc_active:
        a, b = coaches  # the usual train, one coach of each (a fleet summary asks 450 times)
        return (a, b) if a.id < b.id else (b, a)
    on = [c for c in coaches if c.ddpc_active]
    off = [c for c in coaches if not c.ddpc_active]
    if on and off:
        pair = [on[0], off[0]]
    elif len(coaches) >= 2:
        pair = list(coaches[:2])
    else:
        return None
    c0, c1 = sorted(pair, key=lambda c: c.id)
    return c0, c1


def pair_or_422(train: Train) -> tuple[Coach, Coach]:
    """:func:`pair_coaches`, or :class:`RequestError` when the train has none."""
    pair = pair_coaches(train)
    if pair is None:
        raise RequestError(f"train {train.id} has no pair of coaches to compare")
    return pair


def counted_range(
    start: datetime, end: datetime, earliest: datetime | None, window_min: float
) -> tuple[pd.Timestamp, int]:
    """The first window's start and the number of whole windows a pair comparison over
    (start, end] counts: from the first window boundary after ``start`` — moved up to the
    pair's ``earliest`` row's minute when its data begins later — up to ``end``.

    Parameters
    ----------
    start, end : datetime
        The range asked for (timezone-aware).
    earliest : datetime or None
        The pair's first telemetry row (None: none).
    window_min : float
        Window length. [min]

    Returns
    -------
    (pandas.Timestamp, int)
        The first window's start (a whole number of windows since 1970, UTC) and how many
        whole windows follow it up to ``end`` (0 if none fits).
    """
    if earliest is not None and earliest - timedelta(minutes=1) > start:
        start = earliest - timedelta(minutes=1)  # nothing to compare before the pair's data
    return _whole_windows(start, start.tzinfo, end, window_min)


@functools.lru_cache(maxsize=256)
def _whole_windows(
    start: datetime, tz: tzinfo | None, end: datetime, window_min: float
) -> tuple[pd.Timestamp, int]:
    """:func:`counted_range` from ``start`` (in its time zone ``tz``, part of the key: equal
    times in two zones are equal keys); kept, since a summary's trains mostly share their range
    (a Timestamp in a time zone costs tens of µs)."""
    window_us = round(window_min * 60e6)
    first_us = -(-_epoch_us(start) // window_us) * window_us  # the boundary at or after start
    n = (_epoch_us(end) - first_us) // window_us
    return pd.Timestamp(first_us, unit="us", tz="UTC").tz_convert(pd.Timestamp(start).tz), max(
        0, int(n)
    )


#: Above this many ids, :func:`among` reads every row instead of naming them.
AMONG_MAX = 200


def among(column, ids) -> ColumnElement[bool]:
    """``column IN ids`` — or no condition at all when there are more than :data:`AMONG_MAX`
    ids: a statement with thousands of parameters costs more to build and plan than reading
    every row of a table with one row per coach. Callers keep only the rows of ``ids``."""
    ids = list(ids)
    return column.in_(ids) if len(ids) <= AMONG_MAX else true()


def _epoch_us(t: datetime) -> int:
    """Microseconds since 1970 of the timezone-aware ``t`` (exact)."""
    return (t - _EPOCH) // timedelta(microseconds=1)


_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def replicas(session: Session, since: datetime) -> list[Replica]:
    """The service replicas that decided setpoints since ``since`` (by when the setpoints were
    made, wall time): per replica its ``coaches`` (sorted ids), ``ticks`` and the first and last
    time it was seen; busiest first. Setpoints from before replicas were recorded count under
    ``unknown``."""
    rows = session.execute(
        select(
            Setpoint.replica,
            Setpoint.coach_id,
            func.count(),
            func.min(Setpoint.created_at),
            func.max(Setpoint.created_at),
        )
        .where(Setpoint.created_at >= since)
        .group_by(Setpoint.replica, Setpoint.coach_id)
    ).all()
    out: dict[str, Replica] = {}
    for replica, coach_id, ticks, first, last in rows:
        r = out.setdefault(
            replica or "unknown",
            {
                "replica": replica or "unknown",
                "coaches": [],
                "ticks": 0,
                "first_seen": first,
                "last_seen": last,
            },
        )
        r["coaches"].append(coach_id)
        r["ticks"] += ticks
        r["first_seen"], r["last_seen"] = min(r["first_seen"], first), max(r["last_seen"], last)
    for r in out.values():
        r["coaches"].sort()
    return sorted(out.values(), key=lambda r: (-r["ticks"], r["replica"]))
