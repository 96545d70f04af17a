"""The live feed through the HTTP API, on SQLite and on PostgreSQL: registering coaches, posting
telemetry (stored once, read back exactly; resends and duplicates counted; anything malformed
refused whole with a 422), and the setpoint pull before any tick."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta, timezone

from helpers.service import (
    API,
    T0,
    at,
    count,
    flat_row,
    no_setpoint,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
    sim_rows,
    to_wire,
)
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import AuditLog, Coach, CoachLiveness, Telemetry, Train


def accepted(received: int, stored: int) -> dict:
    """The reply to a telemetry batch."""
    return {"received": received, "stored": stored, "duplicates": received - stored}


def test_register_a_coach(client, tokens, settings):
    op = tokens["operator"]
    reply = register(client, op, "124-A", "124", active=True)
    assert reply.status_code == 201
    body = reply.json()
    assert {k: body[k] for k in ("id", "train_id", "fleet", "ddpc_active", "status")} == {
        "id": "124-A",
        "train_id": "124",
        "fleet": "live",
        "ddpc_active": True,
        "status": "no-data",
    }
    assert body["t_rule_c"] is None and body["t_ref_c"] is None and body["mode"] is None
    # the same again: left as it is (even the flag), 200
    again = register(client, op, "124-A", "124", active=False)
    assert again.status_code == 200 and again.json()["ddpc_active"] is True
    # the same coach for another train: a conflict
    other = register(client, op, "124-A", "125")
    assert other.status_code == 409 and "belongs to train '124'" in other.json()["detail"]
    assert register(client, op, "124-B", "124", active=False).status_code == 201
    for bad in ({"id": "a b", "train_id": "124"}, {"id": "", "train_id": "124"}, {"id": "x"}):
        assert client.post(f"{API}/coaches", json=bad, headers=op).status_code == 422
    extra = {"id": "124-C", "train_id": "124", "colour": "red"}
    assert client.post(f"{API}/coaches", json=extra, headers=op).status_code == 422
    train = client.get(f"{API}/trains/124", headers=tokens["viewer"]).json()
    assert train == {
        "id": "124",
        "name": "124",
        "plan": "fixed",
        "coaches": ["124-A", "124-B"],
        "activated": ["124-A"],
        "deactivated": ["124-B"],
    }
    # audited: the two coaches created, not the 200, 409 or 422s
    assert count(settings.database_url, AuditLog, action="coach.register") == 2
    listed = client.get(f"{API}/coaches", headers=tokens["viewer"]).json()
    assert [c["id"] for c in listed] == ["124-A", "124-B"]


def test_setpoint_is_null_before_any_tick(client, tokens):
    register(client, tokens["operator"], "A")
    reply = client.get(f"{API}/coaches/A/setpoint", headers=tokens["viewer"])
    assert reply.status_code == 200
    assert reply.json() == no_setpoint("A")
    history = client.get(f"{API}/coaches/A/setpoints", headers=tokens["viewer"]).json()
    assert history["tick"] == [] and history["source"] == []


def test_telemetry_is_stored_once_and_read_back(client, tokens, settings):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "A")
    register(client, op, "B", active=False)
    rows_a, rows_b = sim_rows(0, 1, 30), sim_rows(1, 1, 30)
    assert post_rows(client, op, "A", rows_a).json() == accepted(30, 30)
    assert post_rows(client, op, "B", rows_b).json() == accepted(30, 30)
    # the same batch again (a gateway resending after a lost reply): nothing new
    assert post_rows(client, op, "A", rows_a).json() == accepted(30, 0)
    # the same minutes written in another offset are the same instants
    cet = timezone(timedelta(hours=1))
    shifted = [{**r, "time": r["time"].astimezone(cet)} for r in rows_a[-5:]]
    assert to_wire(shifted[0])["time"].endswith("+01:00")
    assert post_rows(client, op, "A", shifted).json() == accepted(5, 0)
    # an overlapping batch: only the new rows; a minute twice in one batch: stored once
    more = sim_rows(0, 21, 40)
    assert post_rows(client, op, "A", more).json() == accepted(20, 10)
    twice = sim_rows(0, 41, 41)
    reply = post_rows(client, op, "A", twice + twice)
    assert reply.json() == accepted(2, 1)
    assert count(settings.database_url, Telemetry, coach_id="A") == 41
    assert count(settings.database_url, Telemetry, coach_id="B") == 30

    series = client.get(f"{API}/coaches/A/timeseries", headers=viewer)
    assert series.status_code == 200
    ts = series.json()
    expected = sim_rows(0, 1, 41)
    n = len(expected)
    assert {k: len(v) for k, v in ts.items()} == dict.fromkeys(ts, n)
    assert {"time", "t_room_c", "t_ref_c", "t_rule_c", "t_amb_c", "power_kw", "source"} <= set(ts)
    assert [datetime.fromisoformat(t) for t in ts["time"]] == [r["time"] for r in expected]
    assert all(len(row) == 3 for row in ts["t_room_c"])
    assert ts["t_room_c"] == [
        [r["t_room_up_c"], r["t_room_mid_c"], r["t_room_low_c"]] for r in expected
    ]
    for key in ("t_ref_c", "t_rule_c", "t_amb_c", "power_kw", "occupancy_pct", "speed_kmh"):
        assert ts[key] == [r[key] for r in expected], key
    assert set(ts["mode"]) == {"regular"} and all(ts["connected"])
    assert set(ts["source"]) <= {None, "rule", "ddpc", "override", "fallback"}
    # explicit range: start exclusive, end inclusive
    part = client.get(
        f"{API}/coaches/B/timeseries",
        params={"start": at(10).isoformat(), "end": at(20).isoformat()},
        headers=viewer,
    ).json()
    assert [datetime.fromisoformat(t) for t in part["time"]] == [at(m) for m in range(11, 21)]
    assert part["power_kw"] == [r["power_kw"] for r in rows_b[10:20]]
    # the live clock is the newest row
    clock = client.get(f"{API}/coaches/A", headers=viewer).json()["clock"]
    assert datetime.fromisoformat(clock) == at(41)


def test_timeseries_defaults_to_the_last_24_hours_of_the_clock(client, tokens):
    op = tokens["operator"]
    register(client, op, "A")
    now = T0 + timedelta(days=2)
    rows = [flat_row(now - timedelta(hours=h), power_kw=float(h)) for h in (25, 24, 23, 1, 0)]
    assert post_rows(client, op, "A", rows).json()["stored"] == 5
    ts = client.get(f"{API}/coaches/A/timeseries", headers=tokens["viewer"]).json()
    # (clock − 24 h, clock]: the row exactly 24 h old is out, like the one 25 h old
    assert ts["power_kw"] == [23.0, 1.0, 0.0]
    assert [datetime.fromisoformat(t) for t in ts["time"]] == [
        now - timedelta(hours=23),
        now - timedelta(hours=1),
        now,
    ]


def _raw(client, headers, body: str):
    return client.post(
        f"{API}/telemetry",
        content=body,
        headers={**headers, "Content-Type": "application/json"},
    )


MALFORMED = {
    "deck temperature NaN": ("t_room_c", [21.0, float("nan"), 21.0]),
    "deck temperature infinite": ("t_room_c", [21.0, float("inf"), 21.0]),
    "T_amb NaN": ("t_amb_c", float("nan")),
    "power NaN": ("power_kw", float("nan")),
    "T_ref infinite": ("t_ref_c", float("inf")),
    "two deck temperatures": ("t_room_c", [21.0, 21.0]),
    "four deck temperatures": ("t_room_c", [21.0, 21.0, 21.0, 21.0]),
    "deck temperature a string": ("t_room_c", [21.0, "warm", 21.0]),
    "naive timestamp": ("time", "2024-11-28T06:01:00"),
    "not a timestamp": ("time", "yesterday"),
    "timestamp out of range": ("time", "0001-01-01T00:00:00+01:00"),
    "timestamp before 2000": ("time", "1999-12-31T23:59:00+00:00"),
    "timestamp in the future": ("time", "2999-01-01T00:00:00+00:00"),
    "T_amb out of range": ("t_amb_c", 80.0),
    "deck temperature out of range": ("t_room_c", [21.0, 95.0, 21.0]),
    "negative power": ("power_kw", -1.0),
    "T_rule out of range": ("t_rule_c", 45.0),
    "occupancy out of range": ("occupancy_pct", 301.0),
    "unknown mode": ("mode", "turbo"),
    "unknown field": ("humidity_pct", 40.0),
    "T_rule missing": ("t_rule_c", None),
}


def test_malformed_telemetry_is_refused_whole(client, tokens, settings):
    """Every malformed batch (one bad row among good ones) gives a 422 with a JSON detail, and
    nothing of it is stored: no row, no clock."""
    op = tokens["operator"]
    register(client, op, "A")
    good = [to_wire(r) for r in sim_rows(0, 1, 5)]
    for name, (key, value) in MALFORMED.items():
        bad = dict(good[2])
        if key == "t_rule_c" and value is None:
            del bad[key]
        else:
            bad[key] = value
        body = json.dumps({"coach_id": "A", "rows": [*good[:2], bad, *good[3:]]})
        reply = _raw(client, op, body)
        assert reply.status_code == 422, (name, reply.status_code, reply.text)
        assert reply.headers["content-type"] == "application/json", name
        assert "detail" in reply.json(), name
    for body in (
        {"coach_id": "A", "rows": []},
        {"coach_id": "A"},
        {"coach_id": "A", "rows": good, "gateway": "x"},
        {"rows": good},
    ):
        assert client.post(f"{API}/telemetry", json=body, headers=op).status_code == 422, body
    assert _raw(client, op, '{"coach_id": "A", "rows": [').status_code == 422
    assert count(settings.database_url, Telemetry) == 0
    assert count(settings.database_url, CoachLiveness) == 0
    assert client.get(f"{API}/coaches/A", headers=tokens["viewer"]).json()["status"] == "no-data"
    # and the good rows alone are fine
    reply = client.post(f"{API}/telemetry", json={"coach_id": "A", "rows": good}, headers=op)
    assert reply.json() == accepted(5, 5)


def test_telemetry_for_an_unknown_coach_is_404(client, tokens, settings):
    reply = post_rows(client, tokens["operator"], "ghost", sim_rows(0, 1, 3))
    assert reply.status_code == 404 and reply.json() == {"detail": "no coach 'ghost'"}
    assert (
        count(settings.database_url, Telemetry) == 0
        and count(settings.database_url, CoachLiveness) == 0
    )


def test_a_row_from_just_now_is_accepted(client, tokens):
    """The future check allows the clock skew of a few minutes."""
    register(client, tokens["operator"], "A")
    now = datetime.now(UTC).replace(microsecond=0)
    rows = [flat_row(now + timedelta(minutes=m)) for m in (-1, 0, 4)]
    reply = post_rows(client, tokens["operator"], "A", rows)
    assert reply.status_code == 200 and reply.json()["stored"] == 3


def test_telemetry_for_a_demo_coach_is_refused(client, tokens, settings):
    """The demo fleet writes its coaches' telemetry itself; a posted row would collide with it."""
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            s.add(Train(id="D1", name="demo"))
            s.flush()
            s.add(Coach(id="D1-A", train_id="D1", fleet="demo", ddpc_active=True))
    finally:
        db.dispose()
    reply = post_rows(client, tokens["operator"], "D1-A", sim_rows(0, 1, 3))
    assert reply.status_code == 409
    assert reply.json() == {"detail": "coach 'D1-A' is simulated by the demo fleet"}
    assert count(settings.database_url, Telemetry) == 0
    assert count(settings.database_url, CoachLiveness) == 0
