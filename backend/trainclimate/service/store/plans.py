"""Trial plans per train (:mod:`trainclimate.analysis.trial_plan`): the plan in force, what it
makes of a tick, and what the API shows of it.

A train's plan changes are rows of ``train_plans``; the plan in force at t is the row with the
latest ``effective_from`` ≤ t (the newest of equals), ``fixed`` without one. A change made while
the train reports telemetry takes effect at a switch hour of its fleet clock — the start of the
first of the new plan's service days after the current one (:func:`effective_from`), never
mid-day; on a train that has reported nothing yet, at once. A train has at most one change
pending: a new one replaces it (:func:`~.commands.set_plan`).

The decision is pure (:func:`plan_days`, :func:`layer_states`): per train the service day of the
tick under the plan in force and the coach activated on it — coach 0 and 1 are the train's two
coaches by id. The scheduler applies it to the coaches it holds and records each day the first
time it applies it (``trial_days``, one row per train and date); from then on the stored
assignment is the one applied, so a day's assignment never changes, whatever later code would
compute. A change that moves the switch hour later leaves the old plan a few hours of a day whose
date is the new plan's first: that *partial* day is applied but not recorded.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date, datetime, timedelta

import pandas as pd
from sqlalchemy import delete, func, or_, select
from sqlalchemy.orm import Session

from trainclimate.analysis import trial_plan
from trainclimate.service.store.models import Coach, Telemetry, Train, TrainPlan, TrialDay, utcnow
from trainclimate.service.store.queries import EARLIEST, among, fleet_clock
from trainclimate.service.store.upsert import insert_new

FIXED = "fixed"
#: How many changes the plan view lists.
HISTORY = 20
DAY = timedelta(days=1)


@dataclass(frozen=True)
class PlanDay:
    """A train's service day under a plan: the day (the local date it starts on), the plan, its
    switch hour (local, h), the coach activated (None: neither), and whether it is a *partial*
    day (a few hours before a change whose first day has the same date: not recorded)."""

    train_id: str
    day: date
    plan: str
    switch_hour: int
    activated: str | None
    partial: bool = False


# --- the decision (pure) -------------------------------------------------------------------------
def terms(row: TrainPlan | None) -> tuple[str, int, int]:
    """(plan, switch hour [h], seed) of a plan row; ``fixed`` at the default hour without one."""
    if row is None:
        return FIXED, trial_plan.DEFAULT_SWITCH_HOUR, 0
    return row.plan, row.switch_hour, row.seed


@functools.lru_cache(maxsize=256)
def day_of(time: datetime, switch_hour: int) -> date:
    """:func:`trainclimate.analysis.trial_plan.service_day` of ``time`` (kept: a batch of ticks asks
    it of one tick for every train)."""
    return trial_plan.service_day(pd.Timestamp(time), switch_hour)


def first_day(row: TrainPlan) -> date:
    """The first service day of the change ``row``."""
    return day_of(row.effective_from, row.switch_hour)


def plan_day(
    train_id: str,
    row: TrainPlan | None,
    upcoming: TrainPlan | None,
    coaches: list[tuple[str, bool]],
    tick: datetime,
) -> PlanDay | None:
    """The service day ``tick`` falls in under the plan ``row`` (None: ``fixed``) and the coach
    it activates.

    Parameters
    ----------
    train_id : str
    row : TrainPlan or None
        The plan in force at ``tick``.
    upcoming : TrainPlan or None
        The change after ``tick``, if any (the day is partial when its date is the change's
        first day).
    coaches : list of (str, bool)
        The train's coaches by id with their layer state (``ddpc_active``).
    tick : datetime
        Timezone-aware.

    Returns
    -------
    PlanDay or None
        For ``fixed``, the coach activated now if exactly one is; for the other plans
        :func:`trainclimate.analysis.trial_plan.activated` of the day (coach 0 or 1, or neither).
        None for a plan other than ``fixed`` on a train without exactly two coaches (no pair: the
        layer stays as set).
    """
    plan, hour, seed = terms(row)
    day = day_of(tick, hour)
    partial = upcoming is not None and day >= first_day(upcoming)
    if plan == FIXED:
        active = [cid for cid, is_on in coaches if is_on]
        return PlanDay(train_id, day, plan, hour, active[0] if len(active) == 1 else None, partial)
    if len(coaches) != 2:
        return None
    k = trial_plan.activated(plan, day, seed)
    on = None if k == trial_plan.NEITHER else coaches[k][0]
    return PlanDay(train_id, day, plan, hour, on, partial)


def plan_days(
    schedules: dict[str, tuple[TrainPlan | None, TrainPlan | None]],
    coaches: dict[str, list[tuple[str, bool]]],
    tick: datetime,
) -> dict[str, PlanDay]:
    """:func:`plan_day` of every train of ``coaches`` (train → its coaches by id with their layer
    state) under its plan in force and the change after (``schedules``, :func:`plans_at`;
    absent: ``fixed``, none)."""
    days = (plan_day(t, *schedules.get(t, (None, None)), cs, tick) for t, cs in coaches.items())
    return {d.train_id: d for d in days if d is not None}


def same_day(day: PlanDay, other: PlanDay | None) -> bool:
    """Whether ``other`` is the day ``day`` under the same plan and switch hour."""
    key = (day.train_id, day.day, day.plan, day.switch_hour)
    return other is not None and (other.train_id, other.day, other.plan, other.switch_hour) == key


def applied(day: PlanDay, stored: PlanDay | None) -> PlanDay:
    """The assignment applied on ``day``: the stored one when it is that day under the same plan
    and switch hour (it never changes once stored), else ``day`` itself. A ``fixed`` day is
    never taken from the store: operators switch its coaches."""
    return stored if same_day(day, stored) and day.plan != FIXED else day


def layer_states(
    days: dict[str, PlanDay],
    stored: dict[str, PlanDay],
    coaches: dict[str, list[tuple[str, bool]]],
) -> dict[str, bool]:
    """Whether each coach's layer is on, as its train's plan has it (absent: as operators set it
    — a ``fixed`` plan, or no pair).

    Parameters
    ----------
    days : dict
        Train → its :class:`PlanDay` at the tick (:func:`plan_days`).
    stored : dict
        Train → the day's stored assignment, if any.
    coaches : dict
        Train → its coaches by id with their layer state.

    Returns
    -------
    dict
        Coach id → layer on.
    """
    out = {}
    for train_id, day in days.items():
        if day.plan == FIXED:
            continue
        on = applied(day, stored.get(train_id)).activated
        out.update({cid: cid == on for cid, _ in coaches[train_id]})
    return out


def effective_from(now: datetime, current: TrainPlan | None, switch_hour: int) -> datetime:
    """When a change to a plan with ``switch_hour`` (local, h) made at ``now`` takes effect: the
    start of its first service day after ``now`` that falls on a later date than the current
    plan's day at ``now`` — so the current day is never split, and no date is the first day of
    the change and a recorded day of the plan before it. UTC."""
    today = max(
        trial_plan.service_day(pd.Timestamp(now), switch_hour),
        trial_plan.service_day(pd.Timestamp(now), terms(current)[1]),
    )
    return trial_plan.day_start(today + DAY, switch_hour).to_pydatetime()


def next_switch(now: datetime, switch_hour: int) -> datetime:
    """The first start of a service day (``switch_hour`` local) after ``now``, UTC."""
    today = trial_plan.service_day(pd.Timestamp(now), switch_hour)
    return trial_plan.day_start(today + DAY, switch_hour).to_pydatetime()


# --- reads ---------------------------------------------------------------------------------------
def plans_at(
    session: Session, train_ids: list[str], at: datetime
) -> dict[str, tuple[TrainPlan | None, TrainPlan | None]]:
    """Each train's plan row in force at ``at`` (None: ``fixed``) and the change after ``at``
    (None: none), in one query; trains without either are left out."""
    newest = (
        select(TrainPlan.train_id, func.max(TrainPlan.effective_from).label("effective_from"))
        .where(among(TrainPlan.train_id, train_ids), TrainPlan.effective_from <= at)
        .group_by(TrainPlan.train_id)
        .subquery()
    )
    rows = session.scalars(
        select(TrainPlan)
        .outerjoin(newest, TrainPlan.train_id == newest.c.train_id)
        .where(
            among(TrainPlan.train_id, train_ids),
            or_(
                TrainPlan.effective_from == newest.c.effective_from,
                TrainPlan.effective_from > at,
            ),
        )
        .order_by(TrainPlan.effective_from, TrainPlan.id)
    )
    out: dict[str, tuple[TrainPlan | None, TrainPlan | None]] = {}
    wanted = set(train_ids)
    for row in rows:  # in force: the newest of the latest time; after: the earliest
        if row.train_id not in wanted:
            continue
        current, upcoming = out.get(row.train_id, (None, None))
        if row.effective_from <= at:
            out[row.train_id] = (row, upcoming)
        elif upcoming is None:
            out[row.train_id] = (current, row)
    return out


def names_in_force(session: Session, trains: Sequence[Train]) -> dict[str, str]:
    """The name of the plan in force at each train's fleet clock (a query per clock: one per
    fleet)."""
    by_clock: dict[datetime, list[str]] = {}
    now = utcnow()
    for train in trains:
        by_clock.setdefault(clock(session, train) or now, []).append(train.id)
    rows: dict[str, tuple[TrainPlan | None, TrainPlan | None]] = {}
    for at, ids in by_clock.items():
        rows |= plans_at(session, ids, at)
    return {t.id: terms(rows.get(t.id, (None, None))[0])[0] for t in trains}


def coaches_of(session: Session, train_ids: list[str]) -> dict[str, list[tuple[str, bool]]]:
    """Each train's coaches by id with their layer state (one query)."""
    out: dict[str, list[tuple[str, bool]]] = {t: [] for t in train_ids}
    rows = session.execute(
        select(Coach.train_id, Coach.id, Coach.ddpc_active)
        .where(Coach.train_id.in_(train_ids))
        .order_by(Coach.id)
    )
    for train_id, coach_id, active in rows:
        out[train_id].append((coach_id, bool(active)))
    return out


def record(session: Session, days: list[PlanDay]) -> dict[str, PlanDay]:
    """Store each day's assignment unless its (train, day) is stored already — by another
    replica, or earlier under another plan — and return what is stored for them (two
    statements)."""
    rows = [
        {
            "train_id": d.train_id,
            "day": d.day,
            "plan": d.plan,
            "switch_hour": d.switch_hour,
            "activated_coach_id": d.activated,
        }
        for d in days
    ]
    insert_new(session, TrialDay.__table__, rows, ["train_id", "day"])
    wanted = {(d.train_id, d.day) for d in days}
    stored = session.scalars(
        select(TrialDay).where(
            TrialDay.train_id.in_({d.train_id for d in days}),
            TrialDay.day.in_({d.day for d in days}),
        )
    )
    return {r.train_id: as_day(r) for r in stored if (r.train_id, r.day) in wanted}


def as_day(row: TrialDay) -> PlanDay:
    """A stored day as a :class:`PlanDay`."""
    return PlanDay(row.train_id, row.day, row.plan, row.switch_hour, row.activated_coach_id)


def clock(session: Session, train: Train) -> datetime | None:
    """The train's fleet clock (its first coach's, :func:`~.queries.fleet_clock`); None before
    anything of its fleet has reported."""
    return fleet_clock(session, train.coaches[0]) if train.coaches else None


def reported(session: Session, train: Train) -> bool:
    """Whether any coach of the train has reported telemetry."""
    ids = [c.id for c in train.coaches]
    return (
        session.scalar(select(Telemetry.id).where(Telemetry.coach_id.in_(ids)).limit(1)) is not None
    )


def pending(session: Session, train_id: str, now: datetime) -> list[TrainPlan]:
    """The train's changes not in force at ``now``, oldest first."""
    return list(
        session.scalars(
            select(TrainPlan)
            .where(TrainPlan.train_id == train_id, TrainPlan.effective_from > now)
            .order_by(TrainPlan.id)
        )
    )


def forget_days(session: Session, train_id: str, since: date) -> None:
    """Drop the train's recorded days from ``since`` on (for a change in force at once on a train
    that has reported nothing: no day of it holds a measurement)."""
    session.execute(delete(TrialDay).where(TrialDay.train_id == train_id, TrialDay.day >= since))


# --- what the API shows --------------------------------------------------------------------------
def local(time: datetime) -> str:
    """``time`` as Zurich wall time in words: ``2024-11-29 03:00 Zurich time``."""
    return pd.Timestamp(time).tz_convert(trial_plan.LOCAL_TZ).strftime("%Y-%m-%d %H:%M Zurich time")


def named(plan: str) -> str:
    """``an alternate plan``, ``a fixed plan`` …"""
    return f"{'an' if plan[0] in 'aeiou' else 'a'} {plan} plan"


def change(row: TrainPlan | None) -> dict:
    """A plan row as the API and the audit log show it (times ISO 8601); the default ``fixed``
    without one."""
    plan, hour, seed = terms(row)
    return {
        "plan": plan,
        "switch_hour": hour,
        "seed": seed,
        "reason": row.reason if row else None,
        "effective_from": row.effective_from.isoformat() if row else None,
        "created_by": row.created_by if row else None,
        "created_at": row.created_at.isoformat() if row else None,
    }


def view(session: Session, train: Train, message: str | None = None) -> dict:
    """The train's plan as ``GET /trains/{id}/plan`` answers it: the plan in force, the change
    pending, today's activated coach (from the stored day once the scheduler applied it), when
    the next service day starts, the recent changes and ``message`` (default: the state in
    words)."""
    now = clock(session, train) or utcnow()
    current, upcoming = plans_at(session, [train.id], now).get(train.id, (None, None))
    coaches = [(c.id, c.ddpc_active) for c in train.coaches]
    today = plan_day(train.id, current, upcoming, coaches, now)
    if today is not None:
        stored = session.get(TrialDay, (train.id, today.day))
        today = applied(today, as_day(stored) if stored is not None else None)
    history = session.scalars(
        select(TrainPlan)
        .where(TrainPlan.train_id == train.id)
        .order_by(TrainPlan.id.desc())
        .limit(HISTORY)
    ).all()
    hour = terms(current)[1]
    out = {
        "train_id": train.id,
        **change(current),
        "pending": change(upcoming) if upcoming is not None else None,
        "service_day": today.day if today else trial_plan.service_day(pd.Timestamp(now), hour),
        "activated_today": today.activated if today else None,
        "clock": now,
        "next_switch": next_switch(now, hour),
        "history": [change(r) for r in history],
    }
    out["message"] = message or state_message(out)
    return out


def state_message(v: dict) -> str:
    """The plan view ``v`` in words."""
    start = v["effective_from"] and pd.Timestamp(v["effective_from"])
    since = f" since {local(start)}" if start and start > EARLIEST else ""
    on = v["activated_today"]
    if v["plan"] == FIXED:
        who = f"{on} runs the layer" if on else "not exactly one coach runs the layer"
        text = f"the fixed plan is in force{since}: operators switch the layer per coach ({who})"
    else:
        who = f"{on} runs the layer today" if on else "neither coach runs the layer today"
        text = f"the {v['plan']} plan is in force{since}: {who}"
    if v["pending"]:
        at = local(pd.Timestamp(v["pending"]["effective_from"]))
        text += f"; it changes to the {v['pending']['plan']} plan at {at}"
    return f"{text}; the next service day starts at {local(v['next_switch'])}."


def change_message(
    train_id: str, row: TrainPlan, at_once: bool, current: str, replaced: TrainPlan | None
) -> str:
    """What the change ``row`` does, in words: in force at once (``at_once``: the train has
    reported nothing yet), or from the next switch hour, ``current`` (a plan) staying in force
    until then; and the pending change it ``replaced``, if any."""
    if at_once:
        why = f"train {train_id} has reported no telemetry yet"
        text = f"the {row.plan} plan is in force at once: {why}"
    else:
        text = (
            f"the {row.plan} plan takes effect at the start of the next service day, "
            f"{local(row.effective_from)} (switch hour {row.switch_hour}), not mid-day: the "
            f"{current} plan stays in force until then"
        )
    if replaced is not None:
        text += f"; it replaces the pending change to the {replaced.plan} plan"
    return text + "."
