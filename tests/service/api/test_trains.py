"""The trains' pair comparison through the HTTP API, on SQLite and on PostgreSQL: the analysis
module's numbers on hand-made telemetry (excluded windows for a lost link and an override, other
window lengths, a range of excluded windows only), and the refusals (no pair, unknown train, bad
parameters)."""

from __future__ import annotations

from datetime import datetime

import numpy as np
import pandas as pd
import pytest

from helpers.service import (
    API,
    T0,
    at,
    decided,
    flat_row,
    flat_rows,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.analysis import savings
from trainclimate.service.store.telemetry import to_wire


def when(value: str) -> datetime:
    return datetime.fromisoformat(value)


#: Two hours of a pair, minute by minute (rows stamped T0 + 1 … 120 min): the activated coach A
#: draws 8 kW, the deactivated B 10 kW, except in the two middle half-hours where A draws 10 kW
#: too — where B's link is down for a minute (T0 + 44) and an override on A is in force
#: (T0 + 60 … 90); A's decks are 1.5 K above T_rule for ten minutes (a comfort violation).
def _power_a(minute: int) -> float:
    return 10.0 if 31 <= minute <= 90 else 8.0


def _pair_rows(first: int, last: int) -> tuple[list[dict], list[dict]]:
    a, b = [], []
    for m in range(first, last + 1):
        hot = 23.5 if 11 <= m <= 20 else 21.5
        a.append(
            flat_row(
                at(m), power_kw=_power_a(m), t_room_up_c=hot, t_room_mid_c=hot, t_room_low_c=hot
            )
        )
        b.append(flat_row(at(m), power_kw=10.0, connected=m != 45))
    return a, b


def test_pair_comparison(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "P-A", "P", active=True)
    register(client, op, "P-B", "P", active=False)
    decided(client, "P-A", 0, 115)  # the layer ran on A, B was on T_rule
    decided(client, "P-B", 0, 115, "rule", "inactive")
    a, b = _pair_rows(1, 60)
    post_rows(client, op, "P-A", a)
    post_rows(client, op, "P-B", b)
    body = {"t_ref_c": 22.5, "duration_min": 30, "reason": "test the exclusion"}
    assert client.post(f"{API}/coaches/P-A/override", json=body, headers=op).status_code == 201
    a, b = _pair_rows(61, 120)
    post_rows(client, op, "P-A", a)
    post_rows(client, op, "P-B", b)

    reply = client.get(f"{API}/trains/P/comparison", headers=viewer)
    assert reply.status_code == 200
    c = reply.json()
    assert (c["activated"], c["deactivated"], c["window_min"]) == ("P-A", "P-B", 30.0)
    assert c["coaches"] == ["P-A", "P-B"]
    assert (when(c["start"]), when(c["end"])) == (T0, at(120))
    windows = c["windows"]
    assert [when(w["start"]) for w in windows] == [at(0), at(30), at(60), at(90)]
    assert [w["excluded"] for w in windows] == [False, True, True, False]
    assert [w["excluded_reason"] for w in windows] == [None, "disconnected", "override", None]
    assert [w["activated"] for w in windows] == ["P-A"] * 4
    assert c["excluded_minutes_by_reason"] == {"disconnected": 30.0, "override": 30.0}
    # two windows of one day, one coach activated: the naive figure, labelled as confounded
    assert c["estimator"] == "fixed_naive" and c["savings_ci95_pct"] is None
    assert "confounded" in c["savings_ci95_reason"]
    assert c["naive_savings_pct"] == c["savings_pct"] and c["counted_windows"] == 2
    assert [w["savings_pct"] for w in windows] == [
        pytest.approx(20.0),
        None,
        None,
        pytest.approx(20.0),
    ]
    assert [w["energy_activated_kwh"] for w in windows] == pytest.approx([4.0, 5.0, 5.0, 4.0])
    assert [w["energy_deactivated_kwh"] for w in windows] == pytest.approx([5.0] * 4)
    assert c["savings_pct"] == pytest.approx(20.0)  # 10 % if the excluded windows counted
    assert (c["energy_activated_kwh"], c["energy_deactivated_kwh"]) == pytest.approx((8.0, 10.0))
    assert c["excluded_minutes"] == 60.0
    assert c["avg_hourly_violation_k"] > 0 and c["baseline_violation_k"] == 0.0

    # rows without the floor heating's share: the whole coach's meter is the headline, the
    # HVAC units' is unknown
    assert c["meter"] == "hvac_and_floor"
    assert c["savings_by_meter_pct"] == {"hvac": None, "hvac_and_floor": c["savings_pct"]}
    # the analysis module's function on the same series, minute by minute, gives the same
    time = pd.date_range(T0, periods=120, freq="1min")
    room_a = np.array([[r["t_room_up_c"]] * 3 for r in _pair_rows(1, 120)[0]])
    overridden = (time >= at(60)) & (time < at(90))
    mine = savings.compare(
        savings.CoachSeries(
            time=time,
            power_kw=[_power_a(m) for m in range(1, 121)],
            t_room_c=room_a,
            t_rule_c=np.full(120, 22.0),
            affected=overridden,
        ),
        savings.CoachSeries(
            time=time,
            power_kw=np.full(120, 10.0),
            t_room_c=np.full((120, 3), 21.5),
            t_rule_c=np.full(120, 22.0),
            affected=time == at(44),
        ),
        start=T0,
        window_min=30.0,
    )
    assert [w["savings_pct"] for w in windows] == pytest.approx(mine.savings_30min_pct)
    assert [w["excluded"] for w in windows] == mine.excluded.tolist()
    assert [w["energy_activated_kwh"] for w in windows] == pytest.approx(
        mine.energy_activated_kwh.tolist()
    )
    assert [w["energy_deactivated_kwh"] for w in windows] == pytest.approx(
        mine.energy_deactivated_kwh.tolist()
    )
    assert c["savings_pct"] == pytest.approx(mine.savings_pct)
    assert c["avg_hourly_violation_k"] == pytest.approx(mine.avg_hourly_violation_k)
    assert c["baseline_violation_k"] == mine.baseline_violation_k
    assert c["excluded_minutes"] == mine.excluded_minutes

    # 15-min windows: the half-hour at T0 + 45 … 60 has no saving but counts
    c15 = client.get(f"{API}/trains/P/comparison", params={"window_min": 15}, headers=viewer).json()
    assert [w["savings_pct"] for w in c15["windows"]] == [
        pytest.approx(20.0),
        pytest.approx(20.0),
        None,
        pytest.approx(0.0),
        None,
        None,
        pytest.approx(20.0),
        pytest.approx(20.0),
    ]
    assert c15["savings_pct"] == pytest.approx(16.0) and c15["excluded_minutes"] == 45.0
    # a range with only excluded windows: no savings to report
    part = client.get(
        f"{API}/trains/P/comparison",
        params={"start": at(30).isoformat(), "end": at(90).isoformat()},
        headers=viewer,
    ).json()
    assert [w["excluded"] for w in part["windows"]] == [True, True]
    assert part["savings_pct"] is None and part["excluded_minutes"] == 60.0


def test_comparison_needs_a_pair(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "Q-A", "Q", active=True)
    post_rows(client, op, "Q-A", flat_rows(1, 40))
    reply = client.get(f"{API}/trains/Q/comparison", headers=viewer)
    assert reply.status_code == 422
    assert reply.json() == {"detail": "train Q has no pair of coaches to compare"}
    register(client, op, "Q-B", "Q", active=False)
    assert client.get(f"{API}/trains/Q/comparison", headers=viewer).status_code == 200
    reply = client.get(f"{API}/trains/R/comparison", headers=viewer)
    assert reply.status_code == 404 and reply.json() == {"detail": "no train 'R'"}
    for params in ({"window_min": 0}, {"window_min": 2000}, {"start": "soon"}):
        assert (
            client.get(f"{API}/trains/Q/comparison", params=params, headers=viewer).status_code
            == 422
        )


def test_pair_comparison_on_both_meters(client, tokens):
    """Rows that split the floor heating off: the headline is the HVAC units' meter (the power
    less the floor's), the whole coach's beside it; the floor heating, the same in both coaches,
    only dilutes the whole coach's saving."""
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "M-A", "M", active=True)
    register(client, op, "M-B", "M", active=False)
    decided(client, "M-A", 0, 55)
    decided(client, "M-B", 0, 55, "rule", "inactive")
    post_rows(client, op, "M-A", flat_rows(1, 60, power_kw=6.0, floor_power_kw=2.0))
    post_rows(client, op, "M-B", flat_rows(1, 60, power_kw=7.0, floor_power_kw=2.0))
    c = client.get(f"{API}/trains/M/comparison", headers=viewer).json()
    assert c["meter"] == "hvac"
    assert c["savings_pct"] == pytest.approx(20.0)  # 1 − 4/5
    assert c["savings_by_meter_pct"] == {
        "hvac": pytest.approx(20.0),
        "hvac_and_floor": pytest.approx(100 / 7),  # 1 − 6/7
    }
    assert (c["energy_activated_kwh"], c["energy_deactivated_kwh"]) == pytest.approx((4.0, 5.0))
    # the share must be a share
    bad = [flat_row(at(61), power_kw=1.0, floor_power_kw=2.0)]
    body = {"coach_id": "M-A", "rows": [to_wire(r) for r in bad]}
    reply = client.post(f"{API}/telemetry", json=body, headers=op)
    assert reply.status_code == 422 and "floor_power_kw is a share of power_kw" in reply.text
