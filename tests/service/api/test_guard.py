"""The guard in the service, on SQLite and on PostgreSQL: a pair whose crossover trial says, with
confidence, that the layer costs energy is handed back to T_rule (``costing_energy``) after the
set number of consecutive service days, evaluated once per service day; the fleet's attention
list shows it with the figures; an operator's audited reset re-enables the layer; and a pair whose
interval contains 0 is never handed back."""

from __future__ import annotations

import pytest
from sqlalchemy import select

from helpers.service import (
    API,
    DAY,
    at,
    crossover_train,
    flat_rows,
    post_rows,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.settings import Settings
from trainclimate.service.store.models import AuditLog, Setpoint


@pytest.fixture
def settings(sleeping_settings) -> Settings:
    """The ticks are the test's. Two consecutive days with the interval below 0 trip the
    guard."""
    return sleeping_settings.model_copy(update={"guard_days": 2})


def tick(client, op, scheduler: Scheduler, minute: int) -> dict[str, tuple[str, str]]:
    """Both coaches' rows up to ``at(minute)`` (``op`` posts them), then the tick at it; each
    coach's (source, reason) there."""
    for coach in ("X-A", "X-B"):
        post_rows(client, op, coach, flat_rows(minute - 30, minute))
    scheduler.tick_fleet("live", at(minute))
    with client.app.state.db.transaction() as s:
        rows = s.scalars(select(Setpoint).where(Setpoint.tick == at(minute)))
        return {sp.coach_id: (sp.source, sp.reason) for sp in rows}


def test_a_pair_costing_energy_is_handed_back_and_re_enabled(client, settings, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    # eight service days of an alternate trial in which the layer costs 15 %: 4 days a coach
    crossover_train(client, op, "X", ratio=1.1, saving=-0.15, days=8, seed=4)
    scheduler = Scheduler(client.app.state.db, settings)
    # day 8: the first evaluation says it costs energy; one day is not enough
    assert tick(client, op, scheduler, 8 * DAY + 60)["X-A"][1] != "costing_energy"
    g = client.get(f"{API}/trains/X/guard", headers=viewer).json()
    assert g["state"] == "watching" and g["below_days"] == 1
    low, high = g["figures"]["savings_ci95_pct"]
    assert high < 0 and g["figures"]["estimator"] == "crossover"
    assert g["figures"]["savings_pct"] == pytest.approx(-15.0, abs=2.0)
    # later the same day: not evaluated again (it would count a second day and trip)
    assert tick(client, op, scheduler, 8 * DAY + 65)["X-A"][1] != "costing_energy"
    assert client.get(f"{API}/trains/X/guard", headers=viewer).json()["below_days"] == 1
    # day 9: the second consecutive day below 0 trips it; the coach with the layer on is
    # handed back to T_rule at once, the other stays off
    decided = tick(client, op, scheduler, 9 * DAY + 60)
    assert decided == {"X-A": ("rule", "costing_energy"), "X-B": ("rule", "inactive")}
    g = client.get(f"{API}/trains/X/guard", headers=viewer).json()
    assert g["state"] == "tripped" and g["coach_id"] == "X-A" and g["below_days"] == 2
    s = client.get(
        f"{API}/fleet/summary", params={"end": at(9 * DAY + 60).isoformat()}, headers=viewer
    ).json()
    [entry] = [a for a in s["attention"] if a["train_id"] == "X"]
    assert entry["kind"] == "costing_energy" and entry["coach_id"] == "X-A"
    assert entry["figures"]["savings_ci95_pct"] == [low, high]
    assert f"{g['figures']['savings_pct']:.1f} %" in entry["detail"]
    # it stays handed back on the next tick
    assert tick(client, op, scheduler, 9 * DAY + 65)["X-A"] == ("rule", "costing_energy")
    # a viewer cannot re-enable it; an operator can, with a reason, once
    body = {"reason": "the HVAC unit was repaired"}
    assert client.post(f"{API}/trains/X/guard/reset", json=body, headers=viewer).status_code == 403
    assert client.post(f"{API}/trains/X/guard/reset", json={}, headers=op).status_code == 422
    r = client.post(f"{API}/trains/X/guard/reset", json=body, headers=op)
    assert r.status_code == 200, r.text
    assert r.json()["state"] == "watching" and r.json()["reset_by"] == "test-operator"
    assert client.post(f"{API}/trains/X/guard/reset", json=body, headers=op).status_code == 409
    with client.app.state.db.transaction() as db:
        [audit] = db.scalars(select(AuditLog).where(AuditLog.action == "guard.reset")).all()
        assert audit.target == "X" and audit.reason == body["reason"]
        assert audit.detail["figures"]["savings_ci95_pct"] == [low, high]
    assert tick(client, op, scheduler, 9 * DAY + 70)["X-A"][1] != "costing_energy"
    s = client.get(
        f"{API}/fleet/summary", params={"end": at(9 * DAY + 70).isoformat()}, headers=viewer
    ).json()
    assert not [a for a in s["attention"] if a["kind"] == "costing_energy"]
    # the next days count only windows after the re-enabling: the old days do not trip it again
    for d in (10, 11):
        assert tick(client, op, scheduler, d * DAY + 60)["X-A"][1] != "costing_energy"
    g = client.get(f"{API}/trains/X/guard", headers=viewer).json()
    assert g["state"] == "watching" and g["below_days"] == 0


def test_a_pair_whose_interval_contains_zero_is_never_handed_back(client, settings, tokens):
    op, viewer = tokens["operator"], tokens["viewer"]
    # the layer saves nothing: the interval straddles 0
    crossover_train(client, op, "X", ratio=0.9, saving=0.0, days=8, seed=5)
    scheduler = Scheduler(client.app.state.db, settings)
    for d in (8, 9, 10):
        assert tick(client, op, scheduler, d * DAY + 60)["X-A"][1] != "costing_energy"
        g = client.get(f"{API}/trains/X/guard", headers=viewer).json()
        low, high = g["figures"]["savings_ci95_pct"]
        assert low < 0 < high
        assert g["state"] == "watching" and g["below_days"] == 0
    assert client.get(f"{API}/trains/X/guard", headers=viewer).json()["tripped_at"] is None
    r = client.post(f"{API}/trains/X/guard/reset", json={"reason": "x"}, headers=op)
    assert r.status_code == 409
