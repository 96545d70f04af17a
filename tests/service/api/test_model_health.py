"""A predictor model's health through the HTTP API, on SQLite and on PostgreSQL: stored
predictions offset from hand-made telemetry by known amounts give the MAE per step, the samples
and the per-coach first-step MAE worked out here by hand; disconnected, non-regular, missing rows
and missing deck values are left out; the window, the ``active`` alias, a model without
predictions, a model over the bound, the refusals (404, 422) and the roles. Then the real
demo fleet's predictions in closed loop against an independent pairing."""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pytest
from sqlalchemy import select, update

from helpers.service import (
    API,
    at,
    flat_row,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.service.adapters import demo
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store.model_health import BOUND_C
from trainclimate.service.store.models import (
    Coach,
    PredictorModel,
    Setpoint,
    Telemetry,
    Train,
)
from trainclimate.service.store.tokens import create_token

#: The decks' actual temperatures (up, mid, low, °C) of every hand-made row.
DECKS = (21.0, 21.5, 22.0)
#: Each deck's sign of the offset (the error is absolute: a prediction below counts as above).
SIGNS = (1.0, -1.0, 1.0)
MIN = timedelta(minutes=1)


def when(value: str) -> datetime:
    return datetime.fromisoformat(value)


def trajectory(offset_per_step: float) -> dict:
    """A stored prediction whose step k (1 … 6) is ``k · offset_per_step`` K off every deck."""
    y = [
        [d + s * k * offset_per_step for d, s in zip(DECKS, SIGNS, strict=True)]
        for k in range(1, 7)
    ]
    return {"t_opt_c": [22.0] * 7, "u_plan_c": [22.0] * 7, "y_pred_c": y}


def row(minute: int, **values) -> dict:
    decks = dict(zip(("t_room_up_c", "t_room_mid_c", "t_room_low_c"), DECKS, strict=True))
    return flat_row(at(minute), **{**decks, **values})


def add_model(session, version: int) -> PredictorModel:
    v1 = session.scalar(select(PredictorModel).where(PredictorModel.version == 1))
    model = PredictorModel(
        version=version,
        method=v1.method,
        rho=v1.rho,
        horizon=v1.horizon,
        sampling_min=v1.sampling_min,
        artifact=v1.artifact,
        state="candidate",
    )
    session.add(model)
    session.flush()
    return model


def store(session, coach_id: str, rows: list[dict], predictions: dict[int, dict], model_id: int):
    """A coach of train H with telemetry ``rows`` and DDPC setpoints at the ticks ``predictions``
    (minute → predicted) of model ``model_id``."""
    if session.get(Coach, coach_id) is None:
        if session.get(Train, "H") is None:
            session.add(Train(id="H", name="H"))
        session.add(Coach(id=coach_id, train_id="H", fleet="live", ddpc_active=True))
        session.flush()
    session.add_all(Telemetry(coach_id=coach_id, **r) for r in rows)
    session.add_all(
        Setpoint(
            coach_id=coach_id,
            tick=at(minute),
            t_rule_c=22.0,
            t_ref_c=22.0,
            source="ddpc",
            reason="ok",
            predicted=predicted,
            model_id=model_id,
        )
        for minute, predicted in predictions.items()
    )


@pytest.fixture
def fleet(app_database):
    """Model version 1's predictions (Δ = 5 min, T = 6):

    - coach H-A at the ticks T0 + 60, 65, … 90 min, every deck off by 0.1 K per step; rows at
      minutes 1 … 100, but the row at 70 disconnected, at 75 in slumber mode and at 80 without
      the mid deck;
    - coach H-B at the ticks 70, 75, 80 off by 0.3 K per step; rows at 1 … 120 but 85;
    - coach H-C, one setpoint of the model without a predicted y (left out).

    Version 2 (inactive) predicted for H-B at the ticks 95 and 100, off by 0.3 K per step;
    version 3 never predicted."""
    with app_database.transaction() as s:
        v1 = s.scalar(select(PredictorModel).where(PredictorModel.version == 1))
        v2 = add_model(s, 2)
        add_model(s, 3)
        a_rows = [row(m) for m in range(1, 101) if m not in (70, 75, 80)]
        a_rows += [row(70, connected=False), row(75, mode="slumber"), row(80, t_room_mid_c=None)]
        store(s, "H-A", a_rows, {m: trajectory(0.1) for m in range(60, 91, 5)}, v1.id)
        b_rows = [row(m) for m in range(1, 121) if m != 85]
        store(s, "H-B", b_rows, {m: trajectory(0.3) for m in (70, 75, 80)}, v1.id)
        store(s, "H-C", [row(m) for m in range(1, 101)], {65: {"t_opt_c": [22.0] * 7}}, v1.id)
        store(s, "H-B", [], {m: trajectory(0.3) for m in (95, 100)}, v2.id)


def health(client, headers, version="1", **params):
    return client.get(f"{API}/models/{version}/health", params=params, headers=headers)


def test_mae_per_step_by_hand(client, tokens, fleet):
    reply = health(client, tokens["viewer"])
    assert reply.status_code == 200
    h = reply.json()
    # the actual at step k of the prediction at tick t is the row at t + 5k min. H-A has 3 decks
    # at each of the 7 targets t + 5k but none at 70 and 75 (disconnected, slumber), 2 at 80
    # and none after 100; H-B has 3 at each of its 3 targets but none at 85.
    a = [14, 14, 14, 14, 12, 9]  # targets 65…95: 3+0+0+2+3+3+3; 70…100; 75…105; …; 90…120
    b = [6, 6, 6, 9, 9, 9]  # targets 75, 80, 85; 80, 85, 90; 85, 90, 95; 90, 95, 100; …
    assert (
        h["samples_per_step"]
        == [x + y for x, y in zip(a, b, strict=True)]
        == [20, 20, 20, 23, 21, 18]
    )
    assert h["samples"] == 122
    expected = [k * (0.1 * a[k - 1] + 0.3 * b[k - 1]) / (a[k - 1] + b[k - 1]) for k in range(1, 7)]
    assert expected == pytest.approx([0.16, 0.32, 0.48, 16.4 / 23, 19.5 / 21, 1.2])
    assert h["mae_per_step_c"] == pytest.approx(expected)
    assert h["coaches"] == [
        {"coach_id": "H-A", "first_step_mae_c": pytest.approx(0.1), "samples": sum(a)},
        {"coach_id": "H-B", "first_step_mae_c": pytest.approx(0.3), "samples": sum(b)},
    ]
    assert (h["version"], h["step_min"], h["bound_c"], h["predictions"]) == (1, 5.0, 0.25, 10)
    # the window: the 24 h up to the model's newest prediction tick (the data's clock)
    assert (when(h["end"]), when(h["start"])) == (at(90), at(90) - timedelta(hours=24))
    assert h["exceeds_bound"] is False  # 0.16 ≤ 0.25
    assert client.get(f"{API}/models/active/health", headers=tokens["viewer"]).json() == h


def test_the_window(client, tokens, fleet):
    # 15 min up to T0 + 90: the ticks 80, 85, 90 of H-A and 80 of H-B
    h = health(client, tokens["viewer"], hours=0.25).json()
    assert (when(h["start"]), when(h["end"]), h["predictions"]) == (at(75), at(90), 4)
    # step k: H-A's targets 80 + 5k, 85 + 5k, 90 + 5k (none after 100), H-B's 80 + 5k (not 85)
    a, b = [9, 9, 6, 3, 0, 0], [0, 3, 3, 3, 3, 3]
    assert h["samples_per_step"] == [9, 12, 9, 6, 3, 3]
    mae = [
        0.1,
        (9 * 0.2 + 3 * 0.6) / 12,
        (6 * 0.3 + 3 * 0.9) / 9,
        (3 * 0.4 + 3 * 1.2) / 6,
        1.5,
        1.8,
    ]
    assert h["mae_per_step_c"] == pytest.approx(mae)
    assert h["coaches"] == [
        {"coach_id": "H-A", "first_step_mae_c": pytest.approx(0.1), "samples": sum(a)},
        {"coach_id": "H-B", "first_step_mae_c": None, "samples": sum(b)},
    ]


def test_a_model_over_the_bound_and_one_without_predictions(client, tokens, fleet):
    viewer = tokens["viewer"]
    # version 2: H-B at the ticks 95 and 100, 0.3 K per step; its rows end at 120
    h = health(client, viewer, "2").json()
    assert (when(h["end"]), h["predictions"]) == (at(100), 2)
    assert h["samples_per_step"] == [6, 6, 6, 6, 3, 0]  # targets 100, 105 … 125, 130
    assert h["mae_per_step_c"] == pytest.approx([0.3, 0.6, 0.9, 1.2, 1.5, None])
    assert h["exceeds_bound"] is True and BOUND_C < 0.3
    # its online MAE (0.9 °C over the steps) is drift against the bound (it records no validation)
    assert (
        h["drift"] is True and h["drift_reason"] == "online MAE 0.900 °C exceeds the bound 0.25 °C"
    )
    assert h["coaches"] == [
        {"coach_id": "H-B", "first_step_mae_c": pytest.approx(0.3), "samples": 27}
    ]
    # version 3 never predicted
    assert health(client, viewer, "3").json() == {
        "version": 3,
        "start": None,
        "end": None,
        "step_min": 5.0,
        "bound_c": 0.25,
        "predictions": 0,
        "samples": 0,
        "samples_per_step": [],
        "mae_per_step_c": [],
        "coaches": [],
        "exceeds_bound": False,
        "state": "candidate",
        "beside": None,
        "validation_mae_per_step_c": None,
        "drift_factor": 1.5,
        "drift": False,
        "drift_reason": None,
    }


def test_refusals(client, tokens, settings, app_database):
    viewer = tokens["viewer"]
    missing = health(client, viewer, "99")
    assert missing.status_code == 404 and missing.json() == {"detail": "no model version 99"}
    for version in ("0", "two", str(2**31)):
        assert health(client, viewer, version).status_code == 422, version
    for hours in ("0", "-1", "745", "nan", "x"):
        assert health(client, viewer, hours=hours).status_code == 422, hours
        assert health(client, viewer, "active", hours=hours).status_code == 422, hours
    assert health(client, viewer, hours="744").status_code == 200
    # roles: no token 401, a gateway token 403 (it may only use the live feed)
    with app_database.transaction() as s:
        gateway, _ = create_token(s, "gateway", "gw-h", ["H-A"])
    for version in ("1", "active"):
        assert health(client, {}, version).status_code == 401
        refused = health(client, {"Authorization": f"Bearer {gateway}"}, version)
        assert refused.status_code == 403
        assert refused.json() == {"detail": "this needs the viewer role; the token is gateway"}
    # no active model
    with app_database.transaction() as s:
        s.execute(update(PredictorModel).values(state="retired"))
    none = health(client, viewer, "active")
    assert none.status_code == 404 and none.json() == {"detail": "no active model"}


@pytest.mark.slow  # the demo fleet in closed loop for 2.5 simulated hours
def test_the_demo_fleets_predictions(client, tokens, app_database, settings):
    """The demo fleet in closed loop for 2.5 simulated hours (30 periods): the scheduler's stored
    predictions, paired here independently by the rows' times, give the answer's MAE per step;
    the model tracks the simulated coaches well within the bound."""
    with app_database.transaction() as s:
        demo.register(s)
    fleet = demo.DemoFleet(app_database, Scheduler(app_database, settings), speedup=1.0)
    for _ in range(30):
        fleet.advance()
    h = client.get(f"{API}/models/active/health", headers=tokens["viewer"]).json()
    with app_database.transaction() as s:
        model = s.scalar(select(PredictorModel).where(PredictorModel.state == "active"))
        predicted = [
            (sp.coach_id, sp.tick, sp.predicted["y_pred_c"])
            for sp in s.scalars(select(Setpoint).where(Setpoint.model_id == model.id))
        ]
        rows = {(r.coach_id, r.time): r for r in s.scalars(select(Telemetry))}
    errors: list[list[float]] = [[] for _ in range(6)]
    for coach_id, tick, y_pred in predicted:
        for k, y in enumerate(y_pred, start=1):
            r = rows.get((coach_id, tick + 5 * k * MIN))
            if r is not None and r.connected and r.mode == "regular":
                actual = (r.t_room_up_c, r.t_room_mid_c, r.t_room_low_c)
                errors[k - 1] += [abs(p - a) for p, a in zip(y, actual, strict=True)]
    assert h["predictions"] == len(predicted) > 20
    assert h["samples_per_step"] == [len(e) for e in errors]
    assert h["mae_per_step_c"] == pytest.approx([float(np.mean(e)) for e in errors])
    coaches = sorted({coach_id for coach_id, _, _ in predicted})
    assert [c["coach_id"] for c in h["coaches"]] == coaches
    assert all(c.endswith("-A") for c in coaches)  # the activated demo coaches
    assert when(h["end"]) == max(tick for _, tick, _ in predicted)  # the demo's clock
    assert 0 < h["mae_per_step_c"][0] < BOUND_C and h["exceeds_bound"] is False
