"""The guard: a pair whose own outcome says the layer costs energy goes back to T_rule.

No model foresees everything (a coach's HVAC rules, a season the predictor never saw), so each
train's pair watches what the layer really does to it. Once per service day and train — at the
first tick the scheduler issues on the day — the pair's trial estimate (:mod:`.pair_trial`, the
same figures as the pair comparison: crossover where the plan alternates the coaches, corrected
by reference days, else the naive figure without an interval) is computed over the 30-minute
windows of the :data:`LOOKBACK_DAYS` service days before the day, from the operator's last
re-enabling on. When its 95 % interval lies entirely below 0 on ``guard_days`` consecutive
evaluations (the rule, free of the database: :mod:`trainclimate.analysis.guard`), the guard
*trips*: from then on every coach of the train whose layer is on gets T_rule, with source
``rule`` and reason ``costing_energy`` (:func:`.policy.decide`), and the train is on the
attention list with the figures. An interval that contains 0, or no interval at
all (a ``fixed`` plan without reference days is confounded with the coaches), never trips it.

The guard stays tripped until an operator re-enables the layer (:func:`reset`, audited): the
estimate then counts only windows after the re-enabling, so the same days cannot trip it again.
While tripped, the pair runs on T_rule with the layer off: its windows are reference windows of
the trial (both coaches on T_rule), which measure the coaches' own ratio.

The state is one row per train (``pair_guards``): the day last evaluated, so the estimate is
computed at most once per service day whatever the replicas and restarts, and every tick only
reads the trains' rows (one statement per batch).
"""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pandas as pd
from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate.analysis import trial_plan
from trainclimate.analysis.guard import costs_energy, figures, step
from trainclimate.service.store import pair_labels, pair_trial, pair_windows, queries
from trainclimate.service.store.models import PairGuard
from trainclimate.service.store.plans import PlanDay
from trainclimate.service.store.upsert import insert_new

#: The service days before the evaluated one whose windows the estimate counts. [days]
LOOKBACK_DAYS = 14
#: The estimate's window, as the pair comparison's default. [min]
WINDOW_MIN = 30.0


def tripped(session: Session, train_ids: list[str]) -> dict[str, dict]:
    """The trains of ``train_ids`` whose guard has tripped, with the figures it tripped on (one
    statement)."""
    rows = session.execute(
        select(PairGuard.train_id, PairGuard.figures).where(
            PairGuard.train_id.in_(train_ids), PairGuard.tripped_at.is_not(None)
        )
    )
    return {t: f or {} for t, f in rows}


def check(
    session: Session,
    days: dict[str, PlanDay],
    pairs: dict[str, list[tuple[str, bool]]],
    tick: datetime,
    guard_days: int,
) -> dict[str, dict]:
    """Evaluate the guard of every train of ``days`` not evaluated on its service day yet, and
    return the trains whose guard has tripped (train → figures).

    Parameters
    ----------
    days : dict
        Train → its service day at the tick (:func:`.plans.plan_days`).
    pairs : dict
        Train → its coaches by id with their layer state (:func:`.plans.coaches_of`).
    tick : datetime
        The tick being issued (a guard trips at it).
    guard_days : int
        See :func:`trainclimate.analysis.guard.step`.
    """
    due = {t: d for t, d in days.items() if len(pairs.get(t, ())) == 2 and not d.partial}
    checked = dict(
        session.execute(
            select(PairGuard.train_id, PairGuard.checked_day).where(
                PairGuard.train_id.in_(list(due))
            )
        ).all()
    )
    due = {t: d for t, d in due.items() if checked.get(t) is None or checked[t] < d.day}
    if due:
        _evaluate(session, due, pairs, tick, guard_days)
    return tripped(session, list(days))


def _evaluate(
    session: Session,
    due: dict[str, PlanDay],
    pairs: dict[str, list[tuple[str, bool]]],
    tick: datetime,
    guard_days: int,
) -> None:
    """Evaluate the ``due`` trains' guards: their rows created if new and locked (another replica
    may be at it: a row it evaluated for the day is skipped), the estimates computed together."""
    insert_new(
        session, PairGuard.__table__, [{"train_id": t, "below_days": 0} for t in due], ["train_id"]
    )
    rows = session.scalars(
        select(PairGuard)
        .where(PairGuard.train_id.in_(list(due)))
        .order_by(PairGuard.train_id)
        .with_for_update()
        .execution_options(populate_existing=True)
    ).all()
    rows = [g for g in rows if g.checked_day is None or g.checked_day < due[g.train_id].day]
    ranges = {}
    for g in rows:
        day = due[g.train_id]
        end = trial_plan.day_start(day.day, day.switch_hour)
        start = end - pd.Timedelta(days=LOOKBACK_DAYS)
        if g.counts_from is not None and g.counts_from > start:
            start = pd.Timestamp(g.counts_from)
        first, n = queries.counted_range(start, end, None, WINDOW_MIN)
        c0, c1 = (c for c, _ in pairs[g.train_id])
        hi = first + timedelta(minutes=WINDOW_MIN * n)
        ranges[g.train_id] = (c0, c1, first, n, hi)
    todo = [(c0, c1, first.to_pydatetime(), hi.to_pydatetime())
            for c0, c1, first, n, hi in ranges.values() if n > 0]  # fmt: skip
    data = pair_windows.pair_data(session, todo, WINDOW_MIN) if todo else {}
    for g in rows:
        day = due[g.train_id]
        g.checked_day = day.day
        if g.tripped_at is not None:
            continue  # tripped until an operator re-enables the layer
        c0, c1, first, n, hi = ranges[g.train_id]
        empty = (np.zeros((0, len(pair_labels.SUMS))), np.zeros((0, 2, len(pair_labels.COUNTS))))
        grid, counts = data.get(c0, empty)
        result = pair_trial.pair_result(grid, counts, first, WINDOW_MIN, day.switch_hour)
        estimate = result["estimate"]
        g.figures = figures(estimate, first, hi)
        g.below_days, trips = step(g.below_days, costs_energy(estimate), guard_days)
        if trips:
            g.tripped_at = tick
            g.coach_id = day.activated or next((c for c, on in pairs[g.train_id] if on), c0)


def view(session: Session, train_id: str) -> dict:
    """A train's guard as the API shows it: ``state`` (``watching``, ``tripped``), the day last
    evaluated, the consecutive evaluations below 0, the last evaluation's figures, when it
    tripped and the coach activated then, and the last re-enabling."""
    g = session.get(PairGuard, train_id)
    if g is None:
        g = PairGuard(train_id=train_id, below_days=0)
    return {
        "train_id": train_id,
        "state": "tripped" if g.tripped_at is not None else "watching",
        "checked_day": g.checked_day,
        "below_days": g.below_days or 0,
        "figures": g.figures,
        "tripped_at": g.tripped_at,
        "coach_id": g.coach_id,
        "counts_from": g.counts_from,
        "reset_by": g.reset_by,
        "reset_at": g.reset_at,
    }


def reset(session: Session, train_id: str, now: datetime, who: str) -> PairGuard | None:
    """Re-enable the layer on a train whose guard has tripped: it watches again, counting only
    windows from ``now`` (the train's clock) on. Returns the row, re-enabled; None (and nothing
    changed) when the guard has not tripped."""
    g = session.scalar(select(PairGuard).where(PairGuard.train_id == train_id).with_for_update())
    if g is None or g.tripped_at is None:
        return None
    g.tripped_at, g.coach_id, g.below_days = None, None, 0
    g.counts_from, g.reset_by, g.reset_at = now, who, now
    return g
