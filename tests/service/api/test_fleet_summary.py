"""``GET /fleet/summary`` on SQLite and on PostgreSQL: every train's figures are its pair
comparison's over the same range (lost links, an override, gaps, a coach off the minute grid, a
coach in slumber), the fleet's pool them, the coaches by status and the attention list; the
refusals."""

from __future__ import annotations

from datetime import timedelta

import pytest

from helpers.service import (
    API,
    T0,
    at,
    decided,
    flat_row,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.service.settings import Settings
from trainclimate.service.store import fleet_summary, pair_windows, queries

FIGURES = (
    "savings_pct",
    "energy_activated_kwh",
    "energy_deactivated_kwh",
    "excluded_minutes",
)


@pytest.fixture
def settings(sleeping_settings) -> Settings:
    """The setpoints are the test's (:func:`decided`): no tick of the live loop lands between
    two summaries."""
    return sleeping_settings


def _rows(first: int, last: int, **by_minute) -> list[dict]:
    """:func:`flat_row` for minutes first … last; each of ``by_minute`` is a function of the
    minute giving that field's value (None: leave the default)."""
    out = []
    for m in range(first, last + 1):
        values = {k: f(m) for k, f in by_minute.items() if f(m) is not None}
        out.append(flat_row(at(m), **values))
    return out


def _fleet(client, op) -> None:
    """Four trains over three hours (rows T0 + 1 … 180 min) and a lone coach:

    - F1: A 8 kW, B 10 kW throughout → 20 % in every window;
    - F2: A 9 kW and 2 K too warm on every deck from T0 + 100 on (comfort violated), B 10 kW
      with its link down at T0 + 44 and no rows T0 + 130 … 140 (a gap);
    - F3: A 6 kW, B 10 kW, B in slumber T0 + 61 … 90 (no band there) and an override on A
      from T0 + 150 for an hour (in force at the end);
    - F4: A's rows 30 s off the minute grid from T0 + 31 … 60 (not on the comparison's grid);
    - L1-A: an activated coach without a twin (no pair: left out).
    """
    for train in ("F1", "F2", "F3", "F4"):
        assert register(client, op, f"{train}-A", train, active=True).status_code == 201
        assert register(client, op, f"{train}-B", train, active=False).status_code == 201
    assert register(client, op, "L1-A", "L1", active=True).status_code == 201
    for train in ("F1", "F2", "F3", "F4"):
        decided(client, f"{train}-A", 0, 175)  # the layer ran on A, B was on T_rule
        decided(client, f"{train}-B", 0, 175, "rule", "inactive")
    warm = {f"t_room_{d}_c": (lambda m: 24.0 if m >= 100 else None) for d in ("up", "mid", "low")}
    parts = {
        "F1-A": _rows(1, 180, power_kw=lambda m: 8.0),
        "F1-B": _rows(1, 180),
        "F2-A": _rows(1, 180, power_kw=lambda m: 9.0, **warm),
        "F2-B": [
            r
            for r in _rows(1, 180, connected=lambda m: False if m == 44 else None)
            if not 130 <= (r["time"] - T0) / timedelta(minutes=1) <= 140
        ],
        "F3-A": _rows(1, 180, power_kw=lambda m: 6.0),
        "F3-B": _rows(1, 180, mode=lambda m: "slumber" if 61 <= m <= 90 else None),
        "F4-A": [
            {**r, "time": r["time"] + timedelta(seconds=30)}
            if 31 <= (r["time"] - T0) / timedelta(minutes=1) <= 60
            else r
            for r in _rows(1, 180, power_kw=lambda m: 7.0)
        ],
        "F4-B": _rows(1, 180),
        "L1-A": _rows(1, 180),
    }
    for cid, rows in parts.items():
        first = [r for r in rows if r["time"] <= at(150)]
        assert post_rows(client, op, cid, first).status_code == 200
    body = {"t_ref_c": 22.5, "duration_min": 60, "reason": "check the exclusion"}
    assert client.post(f"{API}/coaches/F3-A/override", json=body, headers=op).status_code == 201
    for cid, rows in parts.items():
        rest = [r for r in rows if r["time"] > at(150)]
        assert post_rows(client, op, cid, rest).status_code == 200


def test_summary_is_the_pair_comparisons_pooled(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    _fleet(client, op)
    reply = client.get(f"{API}/fleet/summary", params={"hours": 3}, headers=viewer)
    assert reply.status_code == 200, reply.text
    s = reply.json()
    assert (s["hours"], s["window_min"]) == (3.0, 30.0)
    trains = {t["id"]: t for t in s["trains"]}
    assert sorted(trains) == ["F1", "F2", "F3", "F4"]  # L1 has no pair
    for tid, t in trains.items():
        assert (t["activated"], t["deactivated"]) == (f"{tid}-A", f"{tid}-B")
        c = client.get(
            f"{API}/trains/{tid}/comparison",
            params={
                "start": (at(180) - timedelta(hours=3)).isoformat(),
                "end": at(180).isoformat(),
            },
            headers=viewer,
        ).json()
        assert t["start"] == c["start"] and t["end"] == c["end"]
        # no row splits the floor heating off: the whole coach's meter, as the comparison's
        assert t["meter"] == c["meter"] == "hvac_and_floor"
        assert t["savings_by_meter_pct"]["hvac"] is None
        assert t["savings_by_meter_pct"]["hvac_and_floor"] == pytest.approx(c["savings_pct"])
        for k in FIGURES:
            assert t[k] == pytest.approx(c[k], abs=1e-9), (tid, k)
        assert t["avg_hourly_violation_activated_k"] == pytest.approx(c["avg_hourly_violation_k"])
        assert t["avg_hourly_violation_deactivated_k"] == pytest.approx(c["baseline_violation_k"])

    # by hand: F1 20 % over 6 windows (3 kWh a window for A's 6, 5 for B's 10 kW … per half-hour)
    f1, f2, f3, f4 = (trains[t] for t in ("F1", "F2", "F3", "F4"))
    assert f1["savings_pct"] == pytest.approx(20.0) and f1["excluded_minutes"] == 0.0
    assert f1["energy_activated_kwh"] == pytest.approx(6 * 4.0)
    assert f1["avg_hourly_violation_activated_k"] == 0.0
    # F2: the lost link (T0 + 44, window 30 … 60) and the gap (windows 120 … 150) excluded
    assert f2["excluded_minutes"] == 60.0 and f2["savings_pct"] == pytest.approx(10.0)
    # 24 °C against 22 ± 1: 1 K on every deck from T0 + 100 on, counted when nothing affected
    counted_warm = (180 - 100 + 1) - 11  # the gap's 11 minutes are not counted
    assert f2["counted_hours"] == pytest.approx((180 - 1 - 11) / 60)
    assert f2["avg_hourly_violation_activated_k"] == pytest.approx(
        counted_warm / 60 / f2["counted_hours"]
    )
    # F3: the override (T0 + 150 … 180) excludes its window; the slumber half-hour still counts
    # for energy but not for comfort
    assert f3["excluded_minutes"] == 30.0 and f3["savings_pct"] == pytest.approx(40.0)
    assert f3["counted_hours"] == pytest.approx((180 - 30 - 30) / 60)
    # F4: the rows off the minute grid leave the window T0 + 30 … 60 without its minutes
    assert f4["excluded_minutes"] == 30.0 and f4["savings_pct"] == pytest.approx(30.0)

    # the fleet pools its trains: energy over energy, discomfort over the hours counted
    e_act = sum(t["energy_activated_kwh"] for t in trains.values())
    e_deact = sum(t["energy_deactivated_kwh"] for t in trains.values())
    assert s["energy_activated_kwh"] == pytest.approx(e_act)
    assert s["savings_pct"] == pytest.approx(100 * (1 - e_act / e_deact))
    hours = sum(t["counted_hours"] for t in trains.values())
    assert s["counted_hours"] == pytest.approx(hours)
    kh = sum(t["avg_hourly_violation_activated_k"] * t["counted_hours"] for t in trains.values())
    assert s["avg_hourly_violation_activated_k"] == pytest.approx(kh / hours)
    assert s["excluded_minutes"] == 120.0
    # per window, the trains that count it: they add up to the fleet's energy
    assert len(s["windows"]) == 6
    assert [w["trains"] for w in s["windows"]] == [4, 2, 4, 4, 3, 3]
    assert sum(w["energy_activated_kwh"] for w in s["windows"]) == pytest.approx(e_act)
    assert sum(w["energy_deactivated_kwh"] for w in s["windows"]) == pytest.approx(e_deact)
    assert s["windows"][0]["energy_deactivated_kwh"] == pytest.approx(4 * 5.0)

    # statuses as the fleet list shows them; the attention list: the override, the comfort
    # (the live loop ticks meanwhile: a status may move on; the counting is tested below)
    assert sum(s["coaches_by_status"].values()) == 9
    assert set(s["coaches_by_status"]) <= set(queries.STATUSES)
    # F2-B's lost link at T0 + 44 is long past: its newest row is connected
    assert "disconnected" not in s["coaches_by_status"]
    concerns = {(a["coach_id"], a["kind"]) for a in s["attention"]}
    assert ("F3-A", "override") in concerns
    assert ("F2-A", "comfort") in concerns and ("F1-A", "comfort") not in concerns
    comfort = next(a for a in s["attention"] if a["kind"] == "comfort")
    # its last row within the band is T0 + 99, its newest T0 + 180
    assert comfort["detail"] == "outside the comfort band for 81 min"


def test_summary_window_and_end(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    _fleet(client, op)
    # the first hour only: F2's lost link excluded, nothing else
    s = client.get(
        f"{API}/fleet/summary", params={"hours": 1, "end": at(60).isoformat()}, headers=viewer
    ).json()
    trains = {t["id"]: t for t in s["trains"]}
    assert trains["F2"]["excluded_minutes"] == 30.0 and trains["F1"]["excluded_minutes"] == 0.0
    assert trains["F1"]["energy_deactivated_kwh"] == pytest.approx(10.0)
    assert s["excluded_minutes"] == 60.0  # F2's link, F4's rows off the grid


def test_empty_fleet_and_refusals(client, tokens):
    viewer = tokens["viewer"]
    s = client.get(f"{API}/fleet/summary", headers=viewer).json()
    assert s["trains"] == [] and s["savings_pct"] is None and s["coaches_by_status"] == {}
    assert s["attention"] == [] and s["energy_activated_kwh"] == 0.0
    bad = ({"hours": 0}, {"hours": 745}, {"hours": "x"}, {"hours": "1.5"}, {"hours": "5e-324"})
    for params in (*bad, {"end": "2024-11-28T06:00"}):
        assert client.get(f"{API}/fleet/summary", params=params, headers=viewer).status_code == 422
    assert client.get(f"{API}/fleet/summary").status_code == 401


def test_attention_order_and_details():
    def view(cid, status, reason=None, until=None, t_rule=None):
        return {
            "id": cid,
            "train_id": cid[:2],
            "status": status,
            "reason": reason,
            "override_until": until,
            "t_rule_c": t_rule,
        }

    views = [
        view("A1-A", "ok"),
        view("A2-A", "override", "override", T0),
        view("A3-A", "override", "override"),  # issued under an override cancelled since
        view("A4-A", "fallback", "solver_failed"),
        view("A5-A", "stale"),
        view("A6-A", "disconnected", "connection_lost", t_rule=21.5),
        view("A7-A", "disconnected", "connection_lost"),
    ]
    out = fleet_summary.attention(views, {"A1-A": 31.0, "A4-A": 30.0, "A5-A": 400.0})
    assert [(a["coach_id"], a["kind"]) for a in out] == [
        ("A5-A", "stale"),
        ("A6-A", "disconnected"),
        ("A7-A", "disconnected"),
        ("A4-A", "fallback"),
        ("A2-A", "override"),
        ("A3-A", "override"),
        ("A1-A", "comfort"),
        ("A5-A", "comfort"),
    ]
    details = [a["detail"] for a in out]
    assert details[1:3] == [
        "link to the HVAC lost: it holds T_rule 21.5 °C, not the T_ref issued",
        "link to the HVAC lost: it holds its T_rule, not the T_ref issued",
    ]
    assert out[1]["reason"] == "connection_lost"
    assert details[3] == "rule-based setpoint: solver_failed"
    assert details[4] == f"operator's setpoint until {T0:%Y-%m-%d %H:%M} UTC"
    assert details[5] == "operator's setpoint"
    assert details[6:] == [
        "outside the comfort band for 31 min",
        "outside the comfort band for more than 400 min",
    ]
    assert fleet_summary.coaches_by_status(views) == {
        "disconnected": 2,
        "fallback": 1,
        "ok": 1,
        "override": 2,
        "stale": 1,
    }


def test_summary_kept_while_the_counted_windows_are_unchanged(client, tokens, monkeypatch):
    op, viewer = tokens["operator"], tokens["viewer"]
    _fleet(client, op)
    summed = []  # the trains whose windows were summed in the database
    pair_grids = pair_windows.pair_grids

    def spy(session, pairs, *args, **kwargs):
        summed.append(sorted(p[0][:2] for p in pairs))
        return pair_grids(session, pairs, *args, **kwargs)

    monkeypatch.setattr(pair_windows, "pair_grids", spy)

    def summary() -> dict:
        params = {"hours": 3, "end": at(180).isoformat()}
        reply = client.get(f"{API}/fleet/summary", params=params, headers=viewer)
        assert reply.status_code == 200, reply.text
        return {t["id"]: t for t in reply.json()["trains"]}

    first = summary()
    assert summary() == first and summed == [["F1", "F2", "F3", "F4"]]  # then all kept
    # F2-B's missing minutes arrive: F2 is summed afresh, its gap's window now counts
    gap = [flat_row(at(m)) for m in range(130, 141)]
    assert post_rows(client, op, "F2-B", gap).status_code == 200
    second = summary()
    assert summed[-1] == ["F2"]
    assert second["F2"]["excluded_minutes"] == 30.0 and first["F2"]["excluded_minutes"] == 60.0
    assert {t: second[t] for t in ("F1", "F3", "F4")} == {t: first[t] for t in ("F1", "F3", "F4")}
    # a cancelled override changes F3's state: summed afresh (cancelled at the clock, it still
    # covered the minutes up to it)
    reason = {"reason": "done"}
    assert client.delete(f"{API}/coaches/F3-A/override", params=reason, headers=op).is_success
    third = summary()
    assert summed[-1] == ["F3"] and third == second


def test_the_fleet_counts_the_hvac_units_when_every_train_splits_the_floor_off(client, tokens):
    """S1 and S2 report the floor heating's share: each on the HVAC units' meter; the fleet too
    — until a train without the split joins, which puts the fleet on the whole coach's meter
    while S1 and S2 keep theirs."""
    op, viewer = tokens["operator"], tokens["viewer"]
    for train, (pa, pb) in {"S1": (6.0, 7.0), "S2": (5.0, 7.0)}.items():
        register(client, op, f"{train}-A", train, active=True)
        register(client, op, f"{train}-B", train, active=False)
        decided(client, f"{train}-A", 0, 55)
        decided(client, f"{train}-B", 0, 55, "rule", "inactive")
        post_rows(
            client,
            op,
            f"{train}-A",
            _rows(1, 60, power_kw=lambda m, p=pa: p, floor_power_kw=lambda m: 2.0),
        )
        post_rows(
            client,
            op,
            f"{train}-B",
            _rows(1, 60, power_kw=lambda m, p=pb: p, floor_power_kw=lambda m: 2.0),
        )
    params = {"hours": 1, "end": at(60).isoformat()}
    s = client.get(f"{API}/fleet/summary", params=params, headers=viewer).json()
    trains = {t["id"]: t for t in s["trains"]}
    assert trains["S1"]["meter"] == trains["S2"]["meter"] == s["meter"] == "hvac"
    assert trains["S1"]["savings_pct"] == pytest.approx(20.0)  # 4 against 5 kW
    assert trains["S2"]["savings_pct"] == pytest.approx(40.0)  # 3 against 5 kW
    assert s["savings_pct"] == pytest.approx(30.0)  # 7 against 10 kW
    assert s["savings_by_meter_pct"]["hvac_and_floor"] == pytest.approx(100 * (1 - 11 / 14))
    assert s["energy_activated_kwh"] == pytest.approx(7.0)
    assert sum(w["energy_activated_kwh"] for w in s["windows"]) == pytest.approx(7.0)
    register(client, op, "S3-A", "S3", active=True)
    register(client, op, "S3-B", "S3", active=False)
    decided(client, "S3-A", 0, 55)
    decided(client, "S3-B", 0, 55, "rule", "inactive")
    post_rows(client, op, "S3-A", _rows(1, 60, power_kw=lambda m: 8.0))
    post_rows(client, op, "S3-B", _rows(1, 60))
    s = client.get(f"{API}/fleet/summary", params=params, headers=viewer).json()
    trains = {t["id"]: t for t in s["trains"]}
    assert s["meter"] == "hvac_and_floor" and s["savings_by_meter_pct"]["hvac"] is None
    assert (trains["S1"]["meter"], trains["S3"]["meter"]) == ("hvac", "hvac_and_floor")
    assert s["energy_activated_kwh"] == pytest.approx(6.0 + 5.0 + 8.0)
