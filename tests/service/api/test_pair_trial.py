"""A pair's trial in the service, on SQLite and on PostgreSQL: windows count only where the layer
ran, each excluded one with its reason; a crossover over service days cancels the coaches' own
difference and carries its interval; the fleet pools its trains."""

from __future__ import annotations

import pytest

from helpers.service import (
    API,
    DAY,
    HOURS,
    at,
    crossover_train,
    decided,
    flat_rows,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.service.settings import Settings


@pytest.fixture
def settings(sleeping_settings) -> Settings:
    """The setpoints are the test's."""
    return sleeping_settings


def test_a_crossover_cancels_the_coaches_difference(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    days = 8
    crossover_train(client, op, "X", ratio=1.12, saving=0.10, days=days, seed=1)
    span = {"start": at(0).isoformat(), "end": at((days - 1) * DAY + HOURS).isoformat()}
    c = client.get(f"{API}/trains/X/comparison", params=span, headers=viewer).json()
    assert c["coaches"] == ["X-A", "X-B"]
    assert c["estimator"] == "crossover"
    assert c["days"] == {"coach_0": 4, "coach_1": 4, "reference": 0, "dropped": {}}
    low, high = c["savings_ci95_pct"]
    assert low < 10.0 < high and high - low < 5.0
    assert c["savings_pct"] == pytest.approx(10.0, abs=1.0)
    # the naive figure (energy over energy of the counted windows) is reported beside it
    assert c["naive_savings_pct"] != c["savings_pct"]
    assert c["days_to_target"] is not None and c["meets_guideline_14"] is True
    assert c["distinguishable_from_zero"] is True
    # the windows say who ran the layer; the lead-in after each switch is excluded
    counted = [w for w in c["windows"] if not w["excluded"]]
    assert {w["activated"] for w in counted} == {"X-A", "X-B"}
    reasons = c["excluded_minutes_by_reason"]
    assert reasons["plan_switch"] == (days - 1) * 2 * 30.0  # two windows after each switch
    day0 = [w for w in c["windows"] if w["start"] < at(HOURS).isoformat()]
    assert [w["excluded_reason"] for w in day0] == [None] * 6  # the first day has no switch
    day1 = [
        w for w in c["windows"] if at(DAY).isoformat() <= w["start"] < at(DAY + HOURS).isoformat()
    ]
    assert [w["excluded_reason"] for w in day1] == ["plan_switch"] * 2 + [None] * 4
    assert {w["activated"] for w in day1} == {"X-B"}


def test_windows_where_the_layer_did_not_run_do_not_count(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "Y-A", "Y", active=True)
    register(client, op, "Y-B", "Y", active=False)
    # the model was being prepared for the first hour, a DDPC fallback the next half-hour, the
    # HVAC out of regular mode after; then the layer ran
    decided(client, "Y-A", 0, 55, "rule", "no_model")
    decided(client, "Y-A", 60, 85, "fallback", "solver_failed")
    decided(client, "Y-A", 90, 115, "rule", "not_regular")
    decided(client, "Y-B", 0, 175, "rule", "inactive")
    post_rows(client, op, "Y-A", flat_rows(1, 180, power_kw=8.0))
    post_rows(client, op, "Y-B", flat_rows(1, 180))
    span = {"start": at(0).isoformat(), "end": at(120).isoformat()}
    c = client.get(f"{API}/trains/Y/comparison", params=span, headers=viewer).json()
    assert [w["excluded_reason"] for w in c["windows"]] == [
        "preparing",
        "preparing",
        "fallback",
        "not_regular",
    ]
    assert c["savings_pct"] is None and c["counted_windows"] == 0
    assert c["estimator"] is None and c["savings_ci95_reason"] == "no comparable days yet"
    s = client.get(
        f"{API}/fleet/summary", params={"hours": 2, "end": at(120).isoformat()}, headers=viewer
    ).json()
    assert s["savings_pct"] is None and s["counted_windows"] == 0
    assert s["trains"][0]["excluded_minutes_by_reason"] == {
        "preparing": 60.0,
        "fallback": 30.0,
        "not_regular": 30.0,
    }
    # the layer then ran: its windows count
    decided(client, "Y-A", 120, 175)
    span = {"start": at(0).isoformat(), "end": at(180).isoformat()}
    c = client.get(f"{API}/trains/Y/comparison", params=span, headers=viewer).json()
    assert c["counted_windows"] == 2 and c["savings_pct"] == pytest.approx(20.0)


def test_the_fleet_pools_its_trains_estimates(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    days = 8
    crossover_train(client, op, "P1", ratio=1.1, saving=0.08, days=days, seed=2)
    crossover_train(client, op, "P2", ratio=0.9, saving=0.08, days=days, seed=3)
    end = at((days - 1) * DAY + HOURS).isoformat()
    s = client.get(
        f"{API}/fleet/summary", params={"hours": days * 24, "end": end}, headers=viewer
    ).json()
    assert s["estimator"] == "random_effects" and s["trains_pooled"] == 2
    low, high = s["savings_ci95_pct"]
    assert low < s["savings_pct"] < high and s["savings_pct"] == pytest.approx(8.0, abs=1.0)
    for t in s["trains"]:
        assert t["estimator"] == "crossover" and t["savings_ci95_pct"] is not None
        c = client.get(
            f"{API}/trains/{t['id']}/comparison",
            params={"start": t["start"], "end": end},
            headers=viewer,
        ).json()
        assert t["savings_pct"] == pytest.approx(c["savings_pct"])
        assert t["savings_ci95_pct"] == pytest.approx(c["savings_ci95_pct"])
    widths = [t["savings_ci95_pct"][1] - t["savings_ci95_pct"][0] for t in s["trains"]]
    assert high - low < min(widths)
