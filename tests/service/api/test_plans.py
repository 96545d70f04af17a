"""A train's trial plan through the HTTP API, on SQLite and on PostgreSQL: reading and setting it
(viewer reads, operator writes), the audit entry, the refusals (422 for a bad plan, hour, seed or
reason; 404 for an unknown train; 409 for a plan on a train without a pair), the manual layer
switch refused while a plan switches the layer, a change on a train that reports telemetry
pending until the next switch hour (and replaced by a newer one), and ``plan`` in the trains'
list."""

from __future__ import annotations

from typing import get_args

from helpers.service import (
    API,
    at,
    flat_rows,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.analysis import trial_plan
from trainclimate.service.api.schemas.trains import Plan
from trainclimate.service.store import models

BODY = {"plan": "alternate", "reason": "a crossover trial"}


def audit(client, tokens, **params) -> list[dict]:
    reply = client.get(f"{API}/audit", params=params, headers=tokens["viewer"])
    assert reply.status_code == 200
    return reply.json()


def test_the_plans_are_named_alike_everywhere():
    assert get_args(Plan) == trial_plan.PLANS == models.PLANS


def test_reading_and_setting_a_plan(client, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "P-A", "P", active=True)
    register(client, op, "P-B", "P", active=False)
    url = f"{API}/trains/P/plan"
    view = client.get(url, headers=viewer).json()
    assert {k: view[k] for k in ("train_id", "plan", "switch_hour", "seed", "reason")} == {
        "train_id": "P",
        "plan": "fixed",
        "switch_hour": 3,
        "seed": 0,
        "reason": None,
    }
    assert (view["effective_from"], view["pending"], view["history"]) == (None, None, [])
    assert view["activated_today"] == "P-A"
    assert view["message"].startswith("the fixed plan is in force: operators switch the layer")

    assert client.put(url, json=BODY, headers=viewer).status_code == 403
    for bad in (
        {"plan": "weekly", "reason": "x"},
        {**BODY, "switch_hour": 24},
        {**BODY, "switch_hour": -1},
        {**BODY, "switch_hour": 3.5},
        {**BODY, "seed": -1},
        {**BODY, "reason": ""},
        {**BODY, "reason": "x" * 501},
        {"plan": "alternate"},
        {**BODY, "until": "never"},
    ):
        assert client.put(url, json=bad, headers=op).status_code == 422, bad
    missing = client.put(f"{API}/trains/Z/plan", json=BODY, headers=op)
    assert missing.status_code == 404 and missing.json() == {"detail": "no train 'Z'"}
    assert client.get(f"{API}/trains/Z/plan", headers=viewer).status_code == 404
    assert audit(client, tokens, target="P") == []

    # nothing reported yet: in force at once
    reply = client.put(url, json={**BODY, "switch_hour": 4, "seed": 9}, headers=op)
    assert reply.status_code == 200
    view = reply.json()
    assert (view["plan"], view["switch_hour"], view["seed"], view["pending"]) == (
        "alternate",
        4,
        9,
        None,
    )
    assert view["message"] == (
        "the alternate plan is in force at once: train P has reported no telemetry yet."
    )
    assert view["activated_today"] in ("P-A", "P-B") and view["created_by"] == "test-operator"
    assert [(h["plan"], h["reason"]) for h in view["history"]] == [("alternate", BODY["reason"])]
    assert client.get(url, headers=viewer).json()["plan"] == "alternate"
    [entry] = audit(client, tokens, target="P")
    assert {k: entry[k] for k in ("user", "role", "action", "reason")} == {
        "user": "test-operator",
        "role": "operator",
        "action": "train.plan",
        "reason": BODY["reason"],
    }
    before, after = entry["detail"]["before"], entry["detail"]["after"]
    assert (before["plan"], before["switch_hour"], before["effective_from"]) == ("fixed", 3, None)
    assert (after["plan"], after["switch_hour"], after["seed"]) == ("alternate", 4, 9)
    assert after["effective_from"] == view["effective_from"].replace("Z", "+00:00")

    assert client.get(f"{API}/trains/P", headers=viewer).json()["plan"] == "alternate"
    trains = client.get(f"{API}/trains", headers=viewer).json()
    assert [(t["id"], t["plan"]) for t in trains] == [("P", "alternate")]

    # the plan switches the layer: not by hand
    switch = {"active": False, "reason": "maintenance"}
    refused = client.put(f"{API}/coaches/P-A/controller", json=switch, headers=op)
    assert refused.status_code == 409
    assert refused.json()["detail"] == (
        "train P runs an alternate plan, which switches the layer of its coaches; set the plan "
        "to fixed first"
    )


def test_a_change_on_a_reporting_train_waits_for_the_next_switch_hour(client, tokens):
    """The pair reports telemetry up to 07:10 Zurich time (06:10 UTC) on 2024-11-28: a new
    plan is pending until 03:00 the next day, the fixed plan stays in force (the layer may still
    be switched by hand), and a second change replaces the first."""
    op, viewer = tokens["operator"], tokens["viewer"]
    register(client, op, "Q-A", "Q", active=True)
    register(client, op, "Q-B", "Q", active=False)
    for cid in ("Q-A", "Q-B"):
        post_rows(client, op, cid, flat_rows(1, 10))
    url = f"{API}/trains/Q/plan"
    view = client.put(url, json=BODY, headers=op).json()
    assert view["clock"] == "2024-11-28T06:10:00Z" == at(10).isoformat().replace("+00:00", "Z")
    assert (view["plan"], view["effective_from"]) == ("fixed", None)
    assert view["pending"]["plan"] == "alternate"
    assert view["pending"]["effective_from"] == "2024-11-29T02:00:00Z"
    assert view["next_switch"] == "2024-11-29T02:00:00Z"
    assert view["message"] == (
        "the alternate plan takes effect at the start of the next service day, 2024-11-29 03:00 "
        "Zurich time (switch hour 3), not mid-day: the fixed plan stays in force until then."
    )
    again = client.get(url, headers=viewer).json()
    assert again["pending"] == view["pending"] and again["message"] == (
        "the fixed plan is in force: operators switch the layer per coach (Q-A runs the layer); "
        "it changes to the alternate plan at 2024-11-29 03:00 Zurich time; the next service "
        "day starts at 2024-11-29 03:00 Zurich time."
    )
    assert client.get(f"{API}/trains/Q", headers=viewer).json()["plan"] == "fixed"
    switch = {"active": True, "reason": "both before the trial"}
    assert client.put(f"{API}/coaches/Q-B/controller", json=switch, headers=op).status_code == 200

    body = {"plan": "reference", "switch_hour": 5, "reason": "measure the coaches first"}
    view = client.put(url, json=body, headers=op).json()
    assert view["pending"]["plan"] == "reference"
    assert view["pending"]["effective_from"] == "2024-11-29T04:00:00Z"  # 05:00 Zurich
    assert view["message"].endswith("; it replaces the pending change to the alternate plan.")
    assert [h["plan"] for h in view["history"]] == ["reference"]
    entry = audit(client, tokens, target="Q")[0]
    assert entry["detail"]["replaced"]["plan"] == "alternate"
    assert entry["detail"]["after"]["effective_from"] == "2024-11-29T04:00:00+00:00"


def test_a_train_of_one_coach_runs_fixed_only(client, tokens):
    op = tokens["operator"]
    register(client, op, "S-A", "S", active=True)
    url = f"{API}/trains/S/plan"
    for plan in ("alternate", "randomized", "reference"):
        reply = client.put(url, json={**BODY, "plan": plan}, headers=op)
        assert reply.status_code == 409, plan
        assert reply.json()["detail"].startswith("train S has 1 coach(es): ")
        assert reply.json()["detail"].endswith("needs a pair of two; only fixed is possible")
    reply = client.put(url, json={**BODY, "plan": "fixed"}, headers=op)
    assert reply.status_code == 200 and reply.json()["plan"] == "fixed"
    assert reply.json()["activated_today"] == "S-A"
