"""Trial plans applied by the scheduler, driven directly (``Scheduler.tick_fleet`` by hand) on a
small live fleet, on SQLite and on PostgreSQL.

Checked: under ``alternate`` the coach that gets DDPC setpoints changes exactly at the switch hour
(03:00 Zurich, 02:00 UTC in November), over two service days, each switch logged and each day
recorded once in ``trial_days``; a ``randomized`` plan's days are stored, balanced in blocks of two,
and once stored are what is applied, whatever the code would compute later; a change made mid-day
leaves the layer alone until the next switch hour; a train with one coach is left as it is; and the
plans of a whole batch cost the same few statements however many trains it holds.
"""

from __future__ import annotations

import logging
from datetime import UTC, date, datetime, timedelta

import pytest
from sqlalchemy import event, select

from helpers.service import (
    flat_row,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.analysis import trial_plan
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store import commands, plans
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import Coach, Setpoint, Train, TrialDay
from trainclimate.service.store.tokens import Principal

OPERATOR = Principal("plan-test", "operator")
#: 03:00 in Zurich on 2024-11-28 (CET, UTC+1): the start of service day 2024-11-28, whose
#: ordinal is even (alternate: coach 0).
SWITCH = datetime(2024, 11, 28, 2, 0, tzinfo=UTC)
DAY = timedelta(days=1)
MIN = timedelta(minutes=1)


def add_train(db: Database, train: str, coaches: list[str], active: list[str]) -> None:
    with db.transaction() as session:
        session.add(Train(id=train, name=train))
        session.flush()
        for cid in coaches:
            session.add(Coach(id=cid, train_id=train, fleet="live", ddpc_active=cid in active))


def feed(db: Database, coaches: list[str], first: datetime, last: datetime) -> None:
    """Flat 1-minute rows stamped ``first`` … ``last`` for every coach (as the live feed
    stores them)."""
    minutes = int((last - first) / MIN)
    with db.transaction() as session:
        for cid in coaches:
            rows = [flat_row(first + i * MIN) for i in range(minutes + 1)]
            commands.ingest(session, cid, rows)


def set_plan(db: Database, train: str, plan: str, **kw) -> dict:
    with db.transaction() as session:
        return commands.set_plan(session, OPERATOR, train, plan, reason="a trial", **kw)


def issued(db: Database, tick: datetime) -> dict[str, tuple[str, str]]:
    with db.transaction() as session:
        rows = session.scalars(select(Setpoint).where(Setpoint.tick == tick))
        return {sp.coach_id: (sp.source, sp.reason) for sp in rows}


def trial_days(db: Database) -> list[tuple]:
    with db.transaction() as session:
        rows = session.scalars(select(TrialDay).order_by(TrialDay.train_id, TrialDay.day))
        return [(r.train_id, r.day, r.plan, r.switch_hour, r.activated_coach_id) for r in rows]


def layers(db: Database) -> dict[str, bool]:
    with db.transaction() as session:
        return {c.id: c.ddpc_active for c in session.scalars(select(Coach))}


def test_alternate_switches_the_ddpc_coach_exactly_at_the_switch_hour(
    database_with_model, settings, caplog
):
    """Two service days: the ticks before 03:00 belong to the day before (its coach runs DDPC,
    the other follows T_rule as ``inactive``), the tick at 03:00 to the new day."""
    add_train(database_with_model, "T", ["T-A", "T-B"], active=["T-A"])
    view = set_plan(database_with_model, "T", "alternate")  # nothing reported yet: in force at once
    assert view["plan"] == "alternate" and view["pending"] is None
    assert "in force at once" in view["message"]
    scheduler = Scheduler(database_with_model, settings)
    expected = {}
    for switch in (SWITCH, SWITCH + DAY):
        feed(
            database_with_model,
            ["T-A", "T-B"],
            switch - timedelta(minutes=75),
            switch + timedelta(minutes=10),
        )
        for minutes in (-10, -5, 0, 5, 10):
            tick = switch + timedelta(minutes=minutes)
            with caplog.at_level(logging.INFO, logger="trainclimate.service.scheduler"):
                assert scheduler.tick_fleet("live", tick) == 2
            day = trial_plan.service_day(tick, 3)
            on = ["T-A", "T-B"][day.toordinal() % 2]
            expected[tick] = {
                c: ("ddpc", "ok") if c == on else ("rule", "inactive") for c in ("T-A", "T-B")
            }
    assert {t: issued(database_with_model, t) for t in expected} == expected
    # 11-27 (odd: B), 11-28 (even: A), 11-29 (odd: B), each recorded once
    assert trial_days(database_with_model) == [
        ("T", date(2024, 11, 27), "alternate", 3, "T-B"),
        ("T", date(2024, 11, 28), "alternate", 3, "T-A"),
        ("T", date(2024, 11, 29), "alternate", 3, "T-B"),
    ]
    switched = [r.getMessage() for r in caplog.records if "plan of train T" in r.getMessage()]
    assert switched == [
        f"tick {SWITCH - 10 * MIN}: the alternate plan of train T deactivates coach T-A "
        "(service day 2024-11-27)",
        f"tick {SWITCH - 10 * MIN}: the alternate plan of train T activates coach T-B "
        "(service day 2024-11-27)",
        f"tick {SWITCH}: the alternate plan of train T activates coach T-A "
        "(service day 2024-11-28)",
        f"tick {SWITCH}: the alternate plan of train T deactivates coach T-B "
        "(service day 2024-11-28)",
        f"tick {SWITCH + DAY}: the alternate plan of train T deactivates coach T-A "
        "(service day 2024-11-29)",
        f"tick {SWITCH + DAY}: the alternate plan of train T activates coach T-B "
        "(service day 2024-11-29)",
    ]
    with database_with_model.transaction() as session:
        assert plans.view(session, session.get(Train, "T"))["activated_today"] == "T-B"


def test_randomized_days_are_stored_balanced_and_kept(database_with_model, settings, monkeypatch):
    """One tick a day for eight service days (no telemetry: the ticks fall back, the plan still
    sets the layer): each block of two days (ordinals 2k, 2k + 1) has each coach once, as
    ``trial_plan.activated`` draws it; a day once stored is applied as stored, even when the code
    would now draw another coach."""
    add_train(database_with_model, "R", ["R-A", "R-B"], active=["R-A"])
    set_plan(database_with_model, "R", "randomized", seed=7)
    scheduler = Scheduler(database_with_model, settings)
    first = SWITCH + timedelta(hours=10)  # 12:00 on 2024-11-28
    for k in range(8):
        assert scheduler.tick_fleet("live", first + k * DAY) == 2
        on = [c for c, active in layers(database_with_model).items() if active]
        assert on == [trial_days(database_with_model)[-1][4]]
    days = trial_days(database_with_model)
    assert [d[1] for d in days] == [date(2024, 11, 28) + k * DAY for k in range(8)]
    coach = {"R-A": 0, "R-B": 1}
    drawn = [coach[d[4]] for d in days]
    assert drawn == [trial_plan.activated("randomized", d[1], 7) for d in days]
    ordinal = date(2024, 11, 28).toordinal()
    assert ordinal % 2 == 0  # the days pair into blocks from the first
    assert all(sorted(drawn[i : i + 2]) == [0, 1] for i in range(0, 8, 2)), drawn
    assert drawn != [0, 1] * 4 and drawn != [1, 0] * 4  # not the alternate plan

    # the code changes (another draw): the day stored goes on as stored; a new scheduler (a
    # restart) reads it back from the database
    last = days[-1]
    monkeypatch.setattr(trial_plan, "activated", lambda plan, day, seed=0, fixed=0: 1 - drawn[-1])
    restarted = Scheduler(database_with_model, settings)
    assert restarted.tick_fleet("live", first + 7 * DAY + timedelta(minutes=5)) == 2
    assert [c for c, active in layers(database_with_model).items() if active] == [last[4]]
    assert trial_days(database_with_model) == days
    # the next day is drawn by the code of the day
    assert restarted.tick_fleet("live", first + 8 * DAY) == 2
    assert trial_days(database_with_model)[-1][4] == ["R-A", "R-B"][1 - drawn[-1]]


def test_a_change_made_mid_day_takes_effect_at_the_next_switch_hour(database_with_model, settings):
    """The train reports telemetry; at 10:00 Zurich an operator sets ``reference`` (switch hour
    5). The layer stays as it was — and may still be switched by hand — until 05:00 Zurich the
    next day; from then on neither coach runs it, and the manual switch is refused."""
    add_train(database_with_model, "M", ["M-A", "M-B"], active=["M-A"])
    noon = SWITCH + timedelta(hours=7)  # 10:00 Zurich
    feed(database_with_model, ["M-A", "M-B"], noon - 70 * MIN, noon)
    view = set_plan(database_with_model, "M", "reference", switch_hour=5)
    effective = datetime(2024, 11, 29, 4, 0, tzinfo=UTC)  # 05:00 Zurich
    assert view["plan"] == "fixed" and view["pending"]["plan"] == "reference"
    assert datetime.fromisoformat(view["pending"]["effective_from"]) == effective
    assert "2024-11-29 05:00 Zurich time (switch hour 5), not mid-day" in view["message"]
    scheduler = Scheduler(database_with_model, settings)
    for tick in (noon, effective - 5 * MIN):
        assert scheduler.tick_fleet("live", tick) == 2
        assert layers(database_with_model) == {"M-A": True, "M-B": False}
    with (
        database_with_model.transaction() as session
    ):  # fixed is still in force: the layer may be switched
        commands.set_controller(session, OPERATOR, "M-B", True, "before the trial")
    assert scheduler.tick_fleet("live", effective) == 2
    assert layers(database_with_model) == {"M-A": False, "M-B": False}
    assert trial_days(database_with_model) == [
        ("M", date(2024, 11, 28), "fixed", 3, "M-A"),
        ("M", date(2024, 11, 29), "reference", 5, None),
    ]
    feed(
        database_with_model, ["M-A"], effective - 4 * MIN, effective
    )  # the clock reaches the switch
    with (
        pytest.raises(commands.ConflictError, match="runs a reference plan"),
        database_with_model.transaction() as session,
    ):
        commands.set_controller(session, OPERATOR, "M-A", True, "by hand")


def test_a_train_without_a_pair_and_trains_without_a_plan_are_left_alone(
    database_with_model, settings
):
    add_train(
        database_with_model, "F", ["F-A", "F-B"], active=["F-A", "F-B"]
    )  # fixed (no plan): as set
    add_train(database_with_model, "S", ["S-A"], active=[])
    scheduler = Scheduler(database_with_model, settings)
    assert scheduler.tick_fleet("live", SWITCH) == 3
    assert layers(database_with_model) == {"F-A": True, "F-B": True, "S-A": False}
    # a fixed day without exactly one coach activated is recorded without one; no pair, nothing
    assert trial_days(database_with_model) == [("F", date(2024, 11, 28), "fixed", 3, None)]
    with pytest.raises(commands.ConflictError, match="train S has 1 coach"):
        set_plan(database_with_model, "S", "alternate")


def test_the_plans_of_a_batch_cost_a_few_statements(database_with_model, settings):
    """A tick of 40 trains under alternate, in one batch: the plans are read in one query, the
    coaches of their trains in one, the days recorded and read back in two — and on the next
    tick of the same day, only the two reads."""
    trains = [f"B{i:02d}" for i in range(40)]
    for t in trains:
        add_train(database_with_model, t, [f"{t}-A", f"{t}-B"], active=[f"{t}-A"])
        set_plan(database_with_model, t, "alternate")
    scheduler = Scheduler(database_with_model, settings)
    statements: list[str] = []

    def seen(conn, cursor, statement, *args):
        statements.append(statement)

    engine = database_with_model.engine
    event.listen(engine, "before_cursor_execute", seen)
    try:
        assert scheduler.tick_fleet("live", SWITCH + timedelta(hours=10)) == 80
        first = [s for s in statements if "train_plans" in s or "trial_days" in s]
        statements.clear()
        assert scheduler.tick_fleet("live", SWITCH + timedelta(hours=10, minutes=5)) == 80
        second = [s for s in statements if "train_plans" in s or "trial_days" in s]
    finally:
        event.remove(engine, "before_cursor_execute", seen)
    assert len(first) == 3 and len(second) == 1  # plans; days inserted, read back | plans only
    assert len(trial_days(database_with_model)) == 40
