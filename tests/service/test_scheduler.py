"""The scheduler, driven directly and deterministically (no threads but the ones a test starts):
a database migrated with a model, coaches and telemetry, and ``Scheduler.tick_fleet`` /
``run_live_once`` / ``run_live`` called by hand — on SQLite and on PostgreSQL.

Checked: a tick is issued once per coach (a second call, a second scheduler, or two replicas
racing on it issue nothing more; the unique (coach, tick) holds in the database); the order of
decisions (warm-up, inactive, stale, override, DDPC after ρ = 12 samples); one coach's exception
gives it a fallback and leaves the others theirs; each setpoint is counted in its window in the
tick's transaction; a restarted scheduler continues from the stored history; the live loop issues
only the current tick and survives the database going away.
"""

from __future__ import annotations

import logging
import threading

import pytest
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError, OperationalError

from helpers.service import (
    at,
    flat_rows,
    shared_coach_model,  # noqa: F401  (autouse)
    sim_rows,
)
from trainclimate.service import scheduler as scheduler_module
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store import commands, liveness, setpoint_rollups
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import (
    Coach,
    FleetClock,
    Override,
    PredictorModel,
    Setpoint,
    SetpointRollup,
    Train,
)
from trainclimate.service.store.tokens import Principal

OPERATOR = Principal("loop-test", "operator")


def add_coaches(db: Database, ids, *, active: bool = True, train: str = "T", fleet: str = "live"):
    with db.transaction() as session:
        if session.get(Train, train) is None:
            session.add(Train(id=train, name=train))
            session.flush()
        for cid in ids:
            session.add(Coach(id=cid, train_id=train, fleet=fleet, ddpc_active=active))


def ingest(db: Database, coach_id: str, rows: list[dict]) -> int:
    """Store rows as ``POST /telemetry`` does (advancing the coach's clock)."""
    with db.transaction() as session:
        stored, _ = commands.ingest(session, coach_id, rows)
    return stored


def setpoints(db: Database, tick=None) -> list[Setpoint]:
    with db.transaction() as session:
        q = select(Setpoint).order_by(Setpoint.tick, Setpoint.coach_id)
        if tick is not None:
            q = q.where(Setpoint.tick == tick)
        return list(session.scalars(q))


def by_coach(db: Database, tick) -> dict[str, Setpoint]:
    return {sp.coach_id: sp for sp in setpoints(db, tick)}


def rollups(db: Database) -> dict[tuple[str, int], tuple[int, ...]]:
    """The setpoint rollups: (coach, window) → (ticks, ddpc, inactive, fallback)."""
    with db.transaction() as session:
        return {
            (r.coach_id, r.window): (r.ticks, r.ddpc, r.inactive, r.fallback)
            for r in session.scalars(select(SetpointRollup))
        }


def test_a_tick_is_issued_once(database_with_model, settings):
    add_coaches(database_with_model, ["A", "B", "C"])
    for i, cid in enumerate("ABC"):
        assert ingest(database_with_model, cid, sim_rows(i, 1, 60)) == 60
    scheduler = Scheduler(database_with_model, settings)
    assert scheduler.tick_fleet("live", at(60)) == 3
    assert scheduler.tick_fleet("live", at(60)) == 0
    assert (
        Scheduler(database_with_model, settings).tick_fleet("live", at(60)) == 0
    )  # another replica, later
    assert scheduler.tick_fleet("live", at(55)) == 0  # older than the last: never issued late
    assert scheduler.tick_fleet("demo", at(65)) == 0  # no coach in that fleet
    rows = setpoints(database_with_model)
    assert [(sp.coach_id, sp.tick) for sp in rows] == [(c, at(60)) for c in "ABC"]
    with database_with_model.transaction() as session:
        assert {c.last_tick for c in session.scalars(select(Coach))} == {at(60)}
    # the database itself refuses a second setpoint for a (coach, tick)
    with pytest.raises(IntegrityError), database_with_model.transaction() as session:
        session.add(Setpoint(coach_id="A", tick=at(60), source="rule", reason="inactive"))
    assert len(setpoints(database_with_model)) == 3


def test_replicas_racing_on_a_tick_issue_it_once(database_with_model, settings, monkeypatch):
    """Two schedulers (like two replicas of the service) start the same tick at the same moment,
    in small batches, with decisions slow enough for them to overlap."""
    ids = [f"R{i}" for i in range(6)]
    add_coaches(database_with_model, ids, active=False)
    for cid in ids:
        ingest(database_with_model, cid, flat_rows(1, 20))
    decide = Scheduler.decide

    def slow(self, *args, **kwargs):
        threading.Event().wait(0.02)
        return decide(self, *args, **kwargs)

    monkeypatch.setattr(Scheduler, "decide", slow)
    for minute in (10, 15, 20):
        replicas = [
            Scheduler(database_with_model, settings),
            Scheduler(database_with_model, settings),
        ]
        start = threading.Barrier(len(replicas))
        issued: list[int | None] = [None] * len(replicas)
        errors: list[BaseException] = []

        def run(i: int, replicas=replicas, start=start, issued=issued, errors=errors, m=minute):
            start.wait()
            try:
                issued[i] = replicas[i].tick_fleet("live", at(m), batch=2)
            except BaseException as exc:
                errors.append(exc)

        threads = [threading.Thread(target=run, args=(i,)) for i in range(len(replicas))]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
        assert errors == []
        assert sum(issued) == len(ids), issued
        per_coach = [sp.coach_id for sp in setpoints(database_with_model, at(minute))]
        assert sorted(per_coach) == ids
    with database_with_model.transaction() as session:
        assert session.scalar(select(func.count()).select_from(Setpoint)) == 3 * len(ids)


def test_each_replica_claims_the_coaches_it_holds_first(database_with_model, settings):
    """Replica a ticks D, E, F and replica b A, B, C; at the next tick a batch of three takes
    a's own D, E, F — not A, B, C first by id — and the coaches record who holds them. Once b
    ticks A, B, C, a drops its controllers of them, which it built when it held them before."""
    add_coaches(database_with_model, list("ABCDEF"))
    for i, cid in enumerate("ABCDEF"):
        ingest(database_with_model, cid, sim_rows(i % 3, 1, 65))
    a = Scheduler(database_with_model, settings.model_copy(update={"replica_name": "a"}))
    b = Scheduler(database_with_model, settings.model_copy(update={"replica_name": "b"}))
    assert a.tick_fleet("live", at(55), coaches=list("ABCDEF")) == 6  # a holds every coach
    assert set(a._controllers) == set("ABCDEF")
    assert b.tick_fleet("live", at(60), coaches=list("ABC")) == 3
    assert a.tick_fleet("live", at(60), coaches=list("DEF")) == 3
    assert set(a._controllers) == set("DEF")  # A, B, C are b's now
    with database_with_model.transaction() as session:
        held = {c.id: c.held_by for c in session.scalars(select(Coach))}
    assert held == {**dict.fromkeys("ABC", "b"), **dict.fromkeys("DEF", "a")}
    assert a._tick_batch("live", at(65), 3, False) == 3
    assert sorted(by_coach(database_with_model, at(65))) == list("DEF")
    assert b._tick_batch("live", at(65), 3, False) == 3
    assert {sp.replica for sp in by_coach(database_with_model, at(65)).values()} == {"a", "b"}
    assert {c: sp.replica for c, sp in by_coach(database_with_model, at(65)).items()} == held


def test_warm_up_then_ddpc_after_rho_samples(database_with_model, settings):
    """ρ = 12 samples: the tick at T0 + 55 min has 11 (T0 + 5 … 55; T0 has no row before it),
    the one at T0 + 60 min the twelve the controller needs."""
    add_coaches(database_with_model, ["A"])
    rows = sim_rows(0, 1, 60)
    ingest(database_with_model, "A", rows)
    scheduler = Scheduler(database_with_model, settings)
    assert scheduler.tick_fleet("live", at(55)) == 1
    warm = by_coach(database_with_model, at(55))["A"]
    rule = rows[54]["t_rule_c"]
    assert (warm.source, warm.reason, warm.detail) == ("rule", "warmup", "11 of 12 samples")
    assert warm.t_ref_c == pytest.approx(rule) and warm.t_rule_c == pytest.approx(rule)
    assert scheduler.tick_fleet("live", at(60)) == 1
    sp = by_coach(database_with_model, at(60))["A"]
    assert (sp.source, sp.reason) == ("ddpc", "ok"), sp.detail
    assert sp.t_rule_c == pytest.approx(rows[59]["t_rule_c"])
    assert abs(sp.t_ref_c - sp.t_rule_c) <= 2.0 + 1e-9  # the band
    assert abs(sp.t_ref_c - rows[59]["t_ref_c"]) <= 0.5 + 1e-9  # the rate limit from u(t-1)
    with database_with_model.transaction() as session:
        model_id = session.scalar(select(PredictorModel.id).where(PredictorModel.version == 1))
    assert sp.model_id == model_id and sp.solve_time_ms is not None and sp.solve_time_ms > 0
    assert len(sp.predicted["u_plan_c"]) == 7 and len(sp.predicted["y_pred_c"]) == 6


def test_inactive_stale_and_missing_coaches(database_with_model, settings):
    """At the tick T0 + 60 min: a fresh inactive coach follows T_rule; one whose newest row is
    9 min old is still fresh; one whose newest row is 10 min old (two periods) is stale and falls
    back to its last T_rule; one that never reported is stale with nothing to set; the active
    coach beside them runs DDPC."""
    add_coaches(database_with_model, ["on"])
    add_coaches(database_with_model, ["off", "edge", "stale", "never"], active=False)
    ingest(database_with_model, "on", sim_rows(0, 1, 60))
    ingest(database_with_model, "off", flat_rows(1, 60, t_rule_c=21.0, t_ref_c=21.0))
    ingest(database_with_model, "edge", flat_rows(1, 51, t_rule_c=21.5, t_ref_c=21.5))
    ingest(database_with_model, "stale", flat_rows(1, 50, t_rule_c=20.5, t_ref_c=20.5))
    assert Scheduler(database_with_model, settings).tick_fleet("live", at(60)) == 5
    got = {
        c: (sp.source, sp.reason, sp.t_ref_c, sp.t_rule_c)
        for c, sp in by_coach(database_with_model, at(60)).items()
    }
    assert got["off"] == ("rule", "inactive", 21.0, 21.0)
    assert got["edge"] == ("rule", "inactive", 21.5, 21.5)
    assert got["stale"] == ("fallback", "stale", 20.5, 20.5)
    assert got["never"] == ("fallback", "stale", None, None)
    assert got["on"][:2] == ("ddpc", "ok")
    # each counted in its window as it was stored
    w = round(at(60).timestamp()) // 1800
    assert rollups(database_with_model) == {
        ("on", w): (1, 1, 0, 0),
        ("off", w): (1, 0, 1, 0),
        ("edge", w): (1, 0, 1, 0),
        ("stale", w): (1, 0, 0, 1),
        ("never", w): (1, 0, 0, 1),
    }


def test_one_coach_raising_does_not_stop_the_others(
    database_with_model, settings, monkeypatch, caplog
):
    add_coaches(database_with_model, ["A", "B", "C"])
    for i, cid in enumerate("ABC"):
        ingest(database_with_model, cid, sim_rows(i, 1, 60))
    decide = Scheduler.decide

    def broken(self, coach, *args, **kwargs):
        if coach.id == "B":
            raise RuntimeError("corrupt state of coach B")
        return decide(self, coach, *args, **kwargs)

    monkeypatch.setattr(Scheduler, "decide", broken)
    with caplog.at_level(logging.ERROR, logger="trainclimate.service.scheduler"):
        assert Scheduler(database_with_model, settings).tick_fleet("live", at(60)) == 3
    got = by_coach(database_with_model, at(60))
    assert (got["B"].source, got["B"].reason, got["B"].t_ref_c) == ("fallback", "error", None)
    assert "corrupt state of coach B" in got["B"].detail
    assert [(got[c].source, got[c].reason) for c in "AC"] == [("ddpc", "ok")] * 2
    assert "tick" in caplog.text and "coach B failed" in caplog.text


def test_an_override_in_force_sets_t_ref(database_with_model, settings):
    """An override made through the command (within T_rule ± 2 K) sets T_ref to its value; one
    outside the band (T_rule moved since) is clipped to it; a cancelled or expired one is not used.
    """
    add_coaches(database_with_model, ["A", "B", "C"])
    for i, cid in enumerate("ABC"):
        ingest(database_with_model, cid, sim_rows(i, 1, 57))
    rule = {cid: sim_rows(i, 57, 57)[0]["t_rule_c"] for i, cid in enumerate("ABC")}
    with database_with_model.transaction() as session:  # now = the live clock, T0 + 57 min
        a = commands.create_override(session, OPERATOR, "A", rule["A"] + 1.5, 30, "too cold")
        assert (a.starts_at, a.ends_at) == (at(57), at(87))
        session.add(
            Override(
                coach_id="B",
                t_ref_c=rule["B"] + 3.7,
                starts_at=at(57),
                ends_at=at(120),
                reason="set when T_rule was higher",
                created_by="loop-test",
            )
        )
        session.add(  # cancelled
            Override(
                coach_id="C",
                t_ref_c=rule["C"] - 1.0,
                starts_at=at(50),
                ends_at=at(120),
                reason="cancelled",
                created_by="loop-test",
                cancelled_at=at(55),
                cancelled_by="loop-test",
            )
        )
    for i, cid in enumerate("ABC"):
        ingest(database_with_model, cid, sim_rows(i, 58, 90))
    scheduler = Scheduler(database_with_model, settings)
    scheduler.tick_fleet("live", at(60))
    got = by_coach(database_with_model, at(60))
    assert (got["A"].source, got["A"].reason) == ("override", "override")
    assert got["A"].t_ref_c == pytest.approx(rule["A"] + 1.5, abs=1e-12)
    assert got["A"].detail == f"override #{a.id}"
    assert got["B"].source == "override"
    assert got["B"].t_ref_c == pytest.approx(got["B"].t_rule_c + 2.0, abs=1e-12)  # clipped
    assert got["C"].source == "ddpc"
    scheduler.tick_fleet("live", at(85))  # A's override ends at T0 + 87 min
    assert by_coach(database_with_model, at(85))["A"].source == "override"
    scheduler.tick_fleet("live", at(90))
    assert (
        by_coach(database_with_model, at(90))["A"].source == "ddpc"
    )  # expired; the lead-in is all there


def test_a_restarted_scheduler_continues_from_the_stored_history(database_with_model, settings):
    add_coaches(database_with_model, ["A", "B"])
    ingest(database_with_model, "A", sim_rows(0, 1, 60))
    ingest(database_with_model, "B", sim_rows(1, 1, 60))
    first = Scheduler(database_with_model, settings)
    for minute in range(5, 61, 5):
        assert first.tick_fleet("live", at(minute)) == 2
    sources = [(sp.tick, sp.source) for sp in setpoints(database_with_model) if sp.coach_id == "A"]
    assert sources == [(at(m), "rule") for m in range(5, 56, 5)] + [(at(60), "ddpc")]
    # the process stops; a new one starts with no controller state at all
    ingest(database_with_model, "A", sim_rows(0, 61, 65))
    ingest(database_with_model, "B", sim_rows(1, 61, 65))
    second = Scheduler(database_with_model, settings)
    assert second._controllers == {}
    assert second.tick_fleet("live", at(60)) == 0  # already issued before the restart
    assert second.tick_fleet("live", at(65)) == 2
    got = by_coach(database_with_model, at(65))
    assert [(got[c].source, got[c].reason) for c in "AB"] == [("ddpc", "ok")] * 2
    assert len(setpoints(database_with_model)) == 2 * 13


def test_run_live_once_issues_each_coach_the_tick_of_its_own_clock(
    database_with_model, settings, caplog
):
    scheduler = Scheduler(database_with_model, settings)
    assert scheduler.run_live_once() == 0  # nothing reported: no clock
    add_coaches(database_with_model, ["A", "B"])
    add_coaches(database_with_model, ["D-A"], train="D", fleet="demo")
    ingest(database_with_model, "A", sim_rows(0, 1, 62))
    ingest(database_with_model, "B", sim_rows(1, 1, 60))
    with database_with_model.transaction() as session:
        assert {c: r.time for c, r in liveness.clocks(session).items()} == {
            "A": at(62),
            "B": at(60),
        }
        assert session.get(FleetClock, "live") is None  # no clock shared by the live coaches
    assert scheduler.run_live_once() == 2
    assert [(sp.coach_id, sp.tick) for sp in setpoints(database_with_model)] == [
        ("A", at(60)),
        ("B", at(60)),
    ]
    assert scheduler.run_live_once() == 0
    ingest(database_with_model, "A", sim_rows(0, 63, 64))
    assert scheduler.run_live_once() == 0  # still the tick of T0 + 60 min
    ingest(
        database_with_model, "A", sim_rows(0, 65, 75)
    )  # A's clock jumps two periods: only its newest tick
    assert scheduler.run_live_once() == 1
    ingest(database_with_model, "A", sim_rows(0, 76, 79))
    assert scheduler.run_live_once() == 0  # B's clock still at T0 + 60: its ticks wait for it
    ingest(
        database_with_model, "B", sim_rows(1, 61, 77)
    )  # B's late rows arrive: its newest tick, on its data
    assert scheduler.run_live_once() == 1
    assert [(sp.coach_id, sp.tick) for sp in setpoints(database_with_model)] == [
        ("A", at(60)),
        ("B", at(60)),
        ("A", at(75)),
        ("B", at(75)),
    ]
    got = by_coach(database_with_model, at(75))
    assert (got["A"].source, got["B"].source) == ("ddpc", "ddpc")
    # the gap in the record is said, not silent
    skipped = [r.getMessage() for r in caplog.records if "skipped" in r.getMessage()]
    assert len(skipped) == 2 and all(
        m.endswith("(the service was down or behind its clock)") for m in skipped
    )


def test_a_gateway_ahead_moves_only_its_own_coaches_ticks(database_with_model, settings):
    """A gateway an hour ahead of the others (within what the server's clock allows, or an
    emulator started later) ticks its own coaches an hour ahead; the other coaches keep their
    ticks, decided on their own rows — never ``stale`` for being behind it, never frozen."""
    add_coaches(database_with_model, ["A", "B"])
    ingest(database_with_model, "A", sim_rows(0, 1, 120))  # an hour ahead of B
    ingest(database_with_model, "B", sim_rows(1, 1, 60))
    scheduler = Scheduler(database_with_model, settings)
    assert scheduler.run_live_once() == 2
    for minute in range(61, 91):  # B reports on, minute by minute; A stays where it is
        ingest(database_with_model, "B", sim_rows(1, minute, minute))
        scheduler.run_live_once()
    ticks = [
        (sp.tick, sp.source, sp.reason)
        for sp in setpoints(database_with_model)
        if sp.coach_id == "B"
    ]
    assert [t for t, _, _ in ticks] == [at(m) for m in range(60, 91, 5)]
    assert all(source == "ddpc" and reason == "ok" for _, source, reason in ticks), ticks
    assert [sp.tick for sp in setpoints(database_with_model) if sp.coach_id == "A"] == [at(120)]


def test_run_live_survives_the_database_going_away(
    database_with_model, settings, monkeypatch, caplog
):
    add_coaches(database_with_model, ["A"])
    ingest(database_with_model, "A", sim_rows(0, 1, 55))
    scheduler = Scheduler(database_with_model, settings)
    assert scheduler.run_live_once() == 1
    ingest(database_with_model, "A", sim_rows(0, 56, 60))
    calls = {"transactions": 0}
    transaction = database_with_model.transaction

    def flaky():
        calls["transactions"] += 1
        if calls["transactions"] == 1:
            raise OperationalError("SELECT 1", {}, Exception("server closed the connection"))
        return transaction()

    monkeypatch.setattr(database_with_model, "transaction", flaky)

    class TwoIterations(threading.Event):
        def __init__(self):
            super().__init__()
            self.waits = 0

        def wait(self, timeout=None):
            self.waits += 1
            if self.waits == 2:
                self.set()
            return self.is_set()

    stop = TwoIterations()
    with caplog.at_level(logging.WARNING, logger="trainclimate.service.scheduler"):
        scheduler.run_live(stop)  # returns: it neither died nor hung
    assert stop.waits == 2
    assert "database unavailable, retrying" in caplog.text
    assert "server closed the connection" in caplog.text
    # the first iteration failed and changed nothing; the second issued the tick, once
    assert [(sp.tick, sp.source) for sp in setpoints(database_with_model)] == [
        (at(55), "rule"),
        (at(60), "ddpc"),
    ]


def test_the_tick_transaction_is_all_or_nothing(database_with_model, settings, monkeypatch):
    """A failure while storing a batch's setpoints leaves no setpoint and no claimed coach: the
    next try issues the tick."""
    add_coaches(database_with_model, ["A", "B"], active=False)
    for cid in "AB":
        ingest(database_with_model, cid, flat_rows(1, 10))
    scheduler = Scheduler(database_with_model, settings)
    row = scheduler_module._row

    def row_then_fail(coach_id, *args):
        if coach_id == "B":
            raise OperationalError("INSERT", {}, Exception("connection lost"))
        return row(coach_id, *args)

    monkeypatch.setattr(scheduler_module, "_row", row_then_fail)
    with pytest.raises(OperationalError):
        scheduler.tick_fleet("live", at(10))
    assert setpoints(database_with_model) == []
    with database_with_model.transaction() as session:
        assert {c.last_tick for c in session.scalars(select(Coach))} == {None}
    monkeypatch.setattr(scheduler_module, "_row", row)
    assert scheduler.tick_fleet("live", at(10)) == 2
    assert [sp.coach_id for sp in setpoints(database_with_model, at(10))] == ["A", "B"]


def test_the_setpoints_and_their_counts_are_stored_together(
    database_with_model, settings, monkeypatch
):
    """The setpoint rollups are kept in the tick's transaction: when counting fails, no setpoint
    is stored either, and the next try stores and counts them."""
    add_coaches(database_with_model, ["A", "B"], active=False)
    for cid in "AB":
        ingest(database_with_model, cid, flat_rows(1, 10))
    scheduler = Scheduler(database_with_model, settings)
    add = setpoint_rollups.add

    def fail(session, rows):
        raise OperationalError("INSERT", {}, Exception("connection lost"))

    monkeypatch.setattr(setpoint_rollups, "add", fail)
    with pytest.raises(OperationalError):
        scheduler.tick_fleet("live", at(10))
    assert setpoints(database_with_model) == [] and rollups(database_with_model) == {}
    monkeypatch.setattr(setpoint_rollups, "add", add)
    assert scheduler.tick_fleet("live", at(10)) == 2
    w = round(at(10).timestamp()) // 1800
    assert rollups(database_with_model) == {("A", w): (1, 0, 1, 0), ("B", w): (1, 0, 1, 0)}


def test_a_live_coach_whose_gateway_is_late_gets_the_tick_with_its_row(
    database_with_model, settings
):
    """Gateways report at slightly different moments: another coach's row passing a tick does
    not issue it to a coach whose row at the tick is on its way (each coach ticks on its own
    clock), so the late coach's controller still has the reading at the tick."""
    scheduler = Scheduler(database_with_model, settings)
    add_coaches(database_with_model, ["A", "B"])
    ingest(database_with_model, "A", sim_rows(0, 1, 60))
    ingest(database_with_model, "B", sim_rows(1, 1, 58))  # B's gateway is two minutes behind
    assert scheduler.run_live_once() == 2  # A's tick at T0 + 60 min, B's (its clock) at 55
    assert [(sp.coach_id, sp.tick) for sp in setpoints(database_with_model)] == [
        ("B", at(55)),
        ("A", at(60)),
    ]
    ingest(database_with_model, "B", sim_rows(1, 59, 60))
    assert scheduler.run_live_once() == 1
    got = by_coach(database_with_model, at(60))
    assert [(got[c].source, got[c].reason) for c in "AB"] == [("ddpc", "ok")] * 2
