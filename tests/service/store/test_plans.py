"""The trial plans' decision, without a database: the service day and coach a plan makes of a
tick, the layer states it sets (the stored day winning over a new draw), when a change takes
effect (never mid-day, never on a date the plan before it has recorded), and the partial day a
later switch hour leaves the plan before it."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from types import SimpleNamespace

import pandas as pd
import pytest

from trainclimate.analysis import trial_plan
from trainclimate.service.store import plans
from trainclimate.service.store.plans import PlanDay

PAIR = [("X-A", True), ("X-B", False)]
#: 2024-11-28 12:00 Zurich time (CET): service day 2024-11-28, an even ordinal.
NOON = datetime(2024, 11, 28, 11, 0, tzinfo=UTC)


def row(plan: str, hour: int = 3, seed: int = 0, effective: datetime = NOON - timedelta(days=9)):
    """A plan row as the decision reads it."""
    return SimpleNamespace(plan=plan, switch_hour=hour, seed=seed, effective_from=effective)


def local(text: str) -> datetime:
    """Zurich wall time ``YYYY-MM-DD HH:MM`` in UTC."""
    return pd.Timestamp(text, tz="Europe/Zurich").tz_convert("UTC").to_pydatetime()


def test_the_day_and_coach_of_each_plan():
    assert plans.plan_day("X", None, None, PAIR, NOON) == PlanDay(
        "X", date(2024, 11, 28), "fixed", 3, "X-A"
    )
    both = [("X-A", True), ("X-B", True)]
    assert plans.plan_day("X", row("fixed"), None, both, NOON).activated is None
    assert plans.plan_day("X", row("alternate"), None, PAIR, NOON).activated == "X-A"
    tomorrow = NOON + timedelta(days=1)
    assert plans.plan_day("X", row("alternate"), None, PAIR, tomorrow).activated == "X-B"
    assert plans.plan_day("X", row("reference"), None, PAIR, NOON).activated is None
    drawn = trial_plan.activated("randomized", date(2024, 11, 28), 5)
    assert (
        plans.plan_day("X", row("randomized", seed=5), None, PAIR, NOON).activated
        == (PAIR[drawn][0])
    )
    # the service day starts at the switch hour, local time
    assert plans.plan_day("X", row("alternate"), None, PAIR, local("2024-11-29 02:55")).day == (
        date(2024, 11, 28)
    )
    assert plans.plan_day("X", row("alternate", 5), None, PAIR, local("2024-11-29 04:55")).day == (
        date(2024, 11, 28)
    )
    # no pair: no plan but fixed has a day
    assert plans.plan_day("X", row("alternate"), None, PAIR[:1], NOON) is None
    assert plans.plan_day("X", None, None, PAIR[:1], NOON).activated == "X-A"


def test_the_layer_states_follow_the_plan_and_the_stored_day():
    pairs = {"X": PAIR, "F": [("F-A", True), ("F-B", True)]}
    days = plans.plan_days({"X": (row("alternate"), None)}, pairs, NOON + timedelta(days=1))
    assert days["X"].activated == "X-B" and days["F"].plan == "fixed"
    assert plans.layer_states(days, {}, pairs) == {"X-A": False, "X-B": True}  # fixed: left
    stored = {"X": PlanDay("X", days["X"].day, "alternate", 3, "X-A")}
    assert plans.layer_states(days, stored, pairs) == {"X-A": True, "X-B": False}
    # a stored day of another plan or hour is not this day's
    other = {"X": PlanDay("X", days["X"].day, "randomized", 3, "X-A")}
    assert plans.layer_states(days, other, pairs) == {"X-A": False, "X-B": True}


@pytest.mark.parametrize(
    ("now", "current", "hour", "effective"),
    [
        ("2024-11-28 10:00", None, 3, "2024-11-29 03:00"),  # the next switch hour
        ("2024-11-28 02:00", None, 3, "2024-11-28 03:00"),  # before today's: today's
        ("2024-11-28 10:00", None, 5, "2024-11-29 05:00"),  # a later hour
        ("2024-11-29 04:00", None, 5, "2024-11-30 05:00"),  # not 05:00 today: 11-29 has begun
        ("2024-11-28 10:00", 5, 3, "2024-11-29 03:00"),  # an earlier hour: the day shortens
        ("2024-11-29 04:00", 5, 3, "2024-11-30 03:00"),  # not mid-day of the old plan
    ],
)
def test_a_change_takes_effect_at_a_new_day_on_a_new_date(now, current, hour, effective):
    old = row("alternate", current) if current is not None else None
    at = plans.effective_from(local(now), old, hour)
    assert at == local(effective)
    first = plans.first_day(row("reference", hour, effective=at))
    assert first > plans.day_of(local(now), plans.terms(old)[1])


def test_the_plan_before_a_later_switch_hour_has_a_partial_day():
    """Fixed (03:00) until a reference plan from 05:00 on 11-29: the fixed plan's day 11-29
    (03:00–05:00) shares its date with the reference plan's first day, so it is not recorded."""
    upcoming = row("reference", 5, effective=local("2024-11-29 05:00"))
    before = plans.plan_day("X", None, upcoming, PAIR, local("2024-11-29 02:55"))
    stub = plans.plan_day("X", None, upcoming, PAIR, local("2024-11-29 03:00"))
    assert (before.day, before.partial) == (date(2024, 11, 28), False)
    assert (stub.day, stub.partial) == (date(2024, 11, 29), True)
