"""Statuses that tell the truth, on SQLite and on PostgreSQL: a coach whose newest telemetry row
says its link to the HVAC is down is ``disconnected`` (reason ``connection_lost``, its T_ref not
applied) in its view, the coaches list, the fleet summary's attention list (right after stale)
and its coaches by status — before an override or the setpoint's status, after no-data and stale;
its view is computed afresh when its newest row changes. A coach with a deck outside the comfort
band in its newest row is flagged in the list at once (the attention list's 30-minute rule
unchanged)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from helpers.service import API, at, flat_row, flat_rows, post_rows, register
from trainclimate.service.settings import Settings
from trainclimate.service.store import queries
from trainclimate.service.store.comfort import comfort_now
from trainclimate.service.store.models import Coach, FleetClock, Setpoint, Train
from trainclimate.service.store.telemetry import insert_rows

DEMO = "demo"


@pytest.fixture
def settings(db_url, small_predictor_file) -> Settings:
    """The live loop runs once at start and then sleeps: the setpoints are the test's."""
    return Settings(
        database_url=db_url, predictor_path=small_predictor_file, scheduler_interval_s=3600
    )


def demo_coach(
    session, coach_id: str, active: bool, rows: list[dict], reason: str, t_ref_c: float | None
) -> None:
    """A coach of the demo fleet (as ``serve --fleet demo`` registers it) with its telemetry
    ``rows`` and one setpoint at the demo clock's tick T0 + 30 min of ``reason``."""
    train_id = coach_id.split("-")[0]
    if session.get(Train, train_id) is None:
        session.add(Train(id=train_id, name=f"demo train {train_id}"))
        session.flush()
    session.add(Coach(id=coach_id, train_id=train_id, fleet=DEMO, ddpc_active=active))
    session.flush()
    insert_rows(session, coach_id, rows)
    source = {"ok": "ddpc", "inactive": "rule", "warmup": "rule"}.get(reason, "fallback")
    session.add(
        Setpoint(
            coach_id=coach_id,
            tick=at(30),
            t_rule_c=22.0,
            t_ref_c=t_ref_c,
            source=source,
            reason=reason,
            solve_time_ms=0.1 if reason == "ok" else None,
        )
    )


def demo_fleet(db) -> None:
    """The demo fleet's clock at T0 + 30 min and four coaches, each with a setpoint at it:

    - D9-A (activated, DDPC ``ok`` at 21 °C): its newest row (T0 + 30) says the link is down;
    - D9-B (deactivated): connected throughout;
    - D10-A: rows up to T0 + 10 only and its newest one disconnected: stale (no telemetry in
      time beats a lost link);
    - D11-A: connected, its setpoint a fallback (``solver_failed``).
    """
    with db.transaction() as s:
        s.add(FleetClock(name=DEMO, time=at(30)))
        lost = [*flat_rows(1, 29), flat_row(at(30), connected=False, t_ref_c=22.0)]
        demo_coach(s, "D9-A", True, lost, "ok", 21.0)
        demo_coach(s, "D9-B", False, flat_rows(1, 30), "inactive", 22.0)
        demo_coach(
            s, "D10-A", True, [*flat_rows(1, 9), flat_row(at(10), connected=False)], "ok", 21.0
        )
        demo_coach(s, "D11-A", True, flat_rows(1, 30), "solver_failed", 22.0)


def get(client, path: str, headers: dict, **params):
    reply = client.get(f"{API}{path}", headers=headers, params=params)
    assert reply.status_code == 200, reply.text
    return reply.json()


def test_a_lost_link_is_disconnected_in_the_view_the_list_and_the_summary(
    client, tokens, app_database
):
    viewer = tokens["viewer"]
    demo_fleet(app_database)
    view = get(client, "/coaches/D9-A", viewer)
    assert (view["status"], view["reason"]) == ("disconnected", "connection_lost")
    # the T_ref issued is not presented as applied: the HVAC holds T_rule
    assert (view["t_ref_c"], view["t_ref_applied"], view["t_rule_c"]) == (21.0, False, 22.0)
    listed = {c["id"]: c for c in get(client, "/coaches", viewer)}
    assert listed["D9-A"] == view
    assert {c: listed[c]["status"] for c in listed} == {
        "D9-A": "disconnected",
        "D9-B": "inactive",
        "D10-A": "stale",
        "D11-A": "fallback",
    }
    assert listed["D9-B"]["t_ref_applied"] is True
    assert listed["D10-A"]["t_ref_applied"] is None  # no telemetry in time: unknown

    summary = get(client, "/fleet/summary", viewer, hours=1)
    assert summary["coaches_by_status"] == {
        "disconnected": 1,
        "fallback": 1,
        "inactive": 1,
        "stale": 1,
    }
    # stale first, then the lost link, then the fallback
    assert [(a["coach_id"], a["kind"], a["status"], a["reason"]) for a in summary["attention"]] == [
        ("D10-A", "stale", "stale", "ok"),
        ("D9-A", "disconnected", "disconnected", "connection_lost"),
        ("D11-A", "fallback", "fallback", "solver_failed"),
    ]
    assert summary["attention"][1]["detail"] == (
        "link to the HVAC lost: it holds T_rule 22.0 °C, not the T_ref issued"
    )


def test_the_newest_row_decides_and_the_cached_view_follows_it(client, tokens, app_database):
    """Reconnected, the coach is ``ok`` again; an override in force does not hide a lost link;
    each change of the newest row is seen at once (the read cache keys on its time)."""
    op, viewer = tokens["operator"], tokens["viewer"]
    demo_fleet(app_database)
    cache = client.app.state.read_cache
    assert get(client, "/coaches/D9-A", viewer)["status"] == "disconnected"
    assert get(client, "/coaches/D9-A", viewer)["status"] == "disconnected"
    misses = cache.misses

    def newest(minute: int, connected: bool) -> None:
        """A new newest row of D9-A at T0 + ``minute``, the demo clock moved to it."""
        with app_database.transaction() as s:
            insert_rows(s, "D9-A", [flat_row(at(minute), connected=connected)])
            s.get(FleetClock, DEMO).time = at(minute)

    newest(31, True)
    view = get(client, "/coaches/D9-A", viewer)
    assert cache.misses == misses + 1  # computed afresh
    assert (view["status"], view["reason"], view["t_ref_applied"]) == ("ok", "ok", True)
    listed = {c["id"]: c for c in get(client, "/coaches", viewer)}
    assert listed["D9-A"] == view
    summary = get(client, "/fleet/summary", viewer, hours=1)
    assert "disconnected" not in summary["coaches_by_status"]
    assert all(a["kind"] != "disconnected" for a in summary["attention"])

    # an override in force: overridden while connected, disconnected when the link goes
    body = {"t_ref_c": 22.5, "duration_min": 60, "reason": "passengers report it is cold"}
    assert client.post(f"{API}/coaches/D9-A/override", json=body, headers=op).status_code == 201
    assert get(client, "/coaches/D9-A", viewer)["status"] == "override"
    newest(32, False)
    view = get(client, "/coaches/D9-A", viewer)
    assert (view["status"], view["reason"]) == ("disconnected", "connection_lost")
    assert view["override_until"] is not None
    attention = get(client, "/fleet/summary", viewer, hours=1)["attention"]
    assert ("D9-A", "disconnected") in {(a["coach_id"], a["kind"]) for a in attention}
    assert ("D9-A", "override") not in {(a["coach_id"], a["kind"]) for a in attention}

    # rows behind the demo clock by more than two periods: stale beats the lost link
    with app_database.transaction() as s:
        s.get(FleetClock, DEMO).time = at(60)
    view = get(client, "/coaches/D9-A", viewer)
    assert (view["status"], view["t_ref_applied"], view["comfort"]) == ("stale", None, None)


def test_a_live_coach_reporting_a_lost_link_is_disconnected(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "L-A", "L", active=True)
    rows = [*flat_rows(1, 9), flat_row(at(10), connected=False)]
    assert post_rows(client, op, "L-A", rows).status_code == 200
    view = get(client, "/coaches/L-A", viewer)
    assert (view["status"], view["reason"]) == ("disconnected", "connection_lost")
    summary = get(client, "/fleet/summary", viewer, hours=1)
    assert summary["coaches_by_status"] == {"disconnected": 1}
    assert [a["kind"] for a in summary["attention"]] == ["disconnected"]
    # silent since (nothing arrives: the wall clock moves on): stale, whatever the row said
    stale = queries.with_liveness(
        {**view, "last_seen_at": datetime.fromisoformat(view["last_seen_at"])},
        None,
        datetime.now(UTC) + timedelta(hours=1),
        timedelta(minutes=5),
        2,
    )
    assert (stale["status"], stale["t_ref_applied"], stale["comfort"]) == ("stale", None, None)


def test_a_deck_outside_the_band_is_flagged_in_the_list_at_once(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    for coach in ("W-A", "W-B", "W-C"):
        register(client, op, coach, "W", active=coach == "W-A")
    # W-A: its up deck 0.3 K above T_rule + 1 K in its newest row only
    post_rows(client, op, "W-A", [*flat_rows(1, 9), flat_row(at(10), t_room_up_c=23.3)])
    post_rows(client, op, "W-B", flat_rows(1, 10, t_room_low_c=21.0))  # at the band's edge
    post_rows(client, op, "W-C", flat_rows(1, 10, mode="slumber", t_room_mid_c=15.0))
    listed = {c["id"]: c for c in get(client, "/coaches", viewer)}
    flagged = listed["W-A"]["comfort"]
    assert flagged["in_band"] is False and flagged["decks_out"] == ["up"]
    assert flagged["worst_excess_k"] == pytest.approx(0.3)
    assert listed["W-B"]["comfort"] == {"in_band": True, "worst_excess_k": 0.0, "decks_out": []}
    assert listed["W-C"]["comfort"] is None  # the band applies in regular mode only
    assert get(client, "/coaches/W-A", viewer)["comfort"] == flagged
    # the attention list still waits for 30 min outside the band
    summary = get(client, "/fleet/summary", viewer, hours=1)
    assert all(a["kind"] != "comfort" for a in summary["attention"])


def test_comfort_now():
    band = 1.0
    assert comfort_now(None, 22.0, "regular", band) is None
    assert comfort_now([21.0, 22.0, 23.0], None, "regular", band) is None
    assert comfort_now([21.0, 22.0, 23.0], 22.0, "slumber", band) is None
    assert comfort_now([None, None, None], 22.0, "regular", band) is None
    assert comfort_now([21.0, 22.0, 23.0], 22.0, "regular", band) == {
        "in_band": True,
        "worst_excess_k": 0.0,
        "decks_out": [],
    }
    out = comfort_now([20.5, None, 23.2], 22.0, "regular", band)
    assert out["in_band"] is False and out["decks_out"] == ["up", "low"]
    assert out["worst_excess_k"] == pytest.approx(0.5)


def test_every_status_a_view_can_have_is_in_the_schema():
    """The statuses the setpoints' reasons map to, and those decided before them."""
    assert set(queries.STATUS.values()) | {"no-data", "disconnected", "fallback"} == set(
        queries.STATUSES
    )
