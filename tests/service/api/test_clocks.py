"""One gateway's clock moves no other coach: a gateway an hour ahead of the server's clock is
refused (422 naming the row, counted as ``ahead_of_clock``) while another coach keeps getting its
setpoints; a coach's week-old backlog leaves another live coach's staleness as it was — each live
coach has its own clock, its own pace and its own ticks; and a setpoint expired on its coach's
clock is not served."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient

from helpers.service import (
    API,
    at,
    flat_row,
    flat_rows,
    no_setpoint,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
    wait_for_tick,
)
from trainclimate.service.app import create_app
from trainclimate.service.scheduler import floor_tick
from trainclimate.service.store import liveness
from trainclimate.service.store.models import Coach

PERIOD = timedelta(minutes=5)


def now_minute() -> datetime:
    return datetime.now(UTC).replace(second=0, microsecond=0)


def test_a_gateway_an_hour_ahead_is_refused_and_others_keep_their_setpoints(
    client, tokens, settings
):
    op, viewer = tokens["operator"], tokens["viewer"]
    for coach in ("A", "B"):
        assert register(client, op, coach).status_code == 201
    now = now_minute()
    ahead = [flat_row(now + timedelta(hours=1, minutes=m)) for m in range(3)]
    reply = post_rows(client, op, "A", ahead)
    assert reply.status_code == 422
    detail = reply.json()["detail"]
    assert detail.startswith("rows[0]: time ") and "more than 5 min ahead" in detail, detail
    assert "3 row(s)" in detail
    health = client.get(f"{API}/health").json()
    assert health["telemetry_refused"] == {"ahead_of_clock": 3}
    # within the skew allowed, a row is taken
    assert post_rows(client, op, "A", [flat_row(now + timedelta(minutes=4))]).status_code == 200
    # B, on the server's clock, gets the tick its own rows reach, decided on its data
    rows = [flat_row(now - timedelta(minutes=m)) for m in range(90, -1, -1)]
    assert post_rows(client, op, "B", rows).json()["stored"] == 91
    sp = wait_for_tick(client, viewer, "B", floor_tick(now, PERIOD))
    assert sp["source"] in ("ddpc", "rule") and sp["reason"] != "stale", sp
    assert datetime.fromisoformat(sp["tick"]) == floor_tick(now, PERIOD)
    status = {c["id"]: c["status"] for c in client.get(f"{API}/coaches", headers=viewer).json()}
    assert status["B"] != "stale"


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_the_allowed_skew_is_a_setting(settings, tokens):
    with TestClient(create_app(settings.model_copy(update={"max_ahead_min": 90}))) as c:
        assert register(c, tokens["operator"], "A").status_code == 201
        rows = [flat_row(now_minute() + timedelta(hours=1))]
        assert post_rows(c, tokens["operator"], "A", rows).status_code == 200


def test_a_backlog_leaves_another_live_coach_alive(client, tokens, settings, monkeypatch):
    """On a fresh database a gateway sends a week of its coach's rows, then another coach
    reports live: the backlog's jump is not the live coach's pace, so the live coach is not
    ``stale`` while it reports (nor is the one whose backlog arrived)."""
    monkeypatch.setattr(liveness, "PACE_MIN_S", 1.0)  # the pace counts after 1 s, not 20 s
    op, viewer = tokens["operator"], tokens["viewer"]
    for coach in ("A", "C"):
        assert register(client, op, coach).status_code == 201
    week_ago = now_minute() - timedelta(days=7)
    for day in range(3):  # the backlog, oldest first
        start = week_ago + timedelta(days=day)
        rows = [flat_row(start + timedelta(minutes=m)) for m in range(1, 721)]
        assert post_rows(client, op, "C", rows).status_code == 200
    started = time.monotonic()
    while time.monotonic() - started < 3.0:  # A reports live, a row at a time, for 3 s
        row = flat_row(datetime.now(UTC).replace(microsecond=0))
        assert post_rows(client, op, "A", [row]).status_code == 200
        time.sleep(0.2)
    time.sleep(0.5)
    status = {c["id"]: c["status"] for c in client.get(f"{API}/coaches", headers=viewer).json()}
    assert status["A"] != "stale" and status["C"] != "stale", status
    db = client.app.state.db
    with db.transaction() as s:
        clocks = liveness.clocks(s)
    assert liveness.pace(clocks["A"]) == pytest.approx(1.0, abs=0.5)
    assert clocks["C"].time == week_ago + timedelta(days=2, minutes=720)


def test_a_setpoint_expired_on_its_coach_clock_is_not_served(client, tokens, settings):
    """The pull serves the newest setpoint only while it is valid on its coach's clock: when
    no tick follows (the replica that holds the coach paused), the gateway is told nothing once
    its rows pass ``valid_until``, and keeps T_rule."""
    op, viewer = tokens["operator"], tokens["viewer"]
    assert register(client, op, "A").status_code == 201
    assert post_rows(client, op, "A", flat_rows(1, 5)).status_code == 200
    sp = wait_for_tick(client, viewer, "A", at(5))
    assert datetime.fromisoformat(sp["valid_until"]) == at(15)  # two periods
    db = client.app.state.db
    with db.transaction() as s:  # no further tick for A: as if its replica were paused
        s.get(Coach, "A").last_tick = at(600)
    assert post_rows(client, op, "A", flat_rows(6, 14)).status_code == 200
    served = client.get(f"{API}/coaches/A/setpoint", headers=viewer).json()
    assert datetime.fromisoformat(served["tick"]) == at(5) and served["t_ref_c"] is not None
    assert post_rows(client, op, "A", flat_rows(15, 20)).status_code == 200
    served = client.get(f"{API}/coaches/A/setpoint", headers=viewer).json()
    assert served == no_setpoint("A")
