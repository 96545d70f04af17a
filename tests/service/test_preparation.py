"""A database without a model: the service answers at once, the coaches run under T_rule, /health
says how far the model's preparation is, and the layer takes over on its own when it is ready —
or, if the preparation fails, the coaches stay on T_rule and /health says why.

``startup_predictor`` (which builds the quick campaign and fits it, ≈ 1 min) is replaced by one
that reports progress and waits for the test's go before returning the small test model.
"""

from __future__ import annotations

import threading

import pytest
from fastapi.testclient import TestClient

from helpers.service import (
    API,
    at,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
    sim_rows,
    wait_for,
    wait_for_tick,
)
from trainclimate.predict import default as models
from trainclimate.predict.artifact import load_predictor
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token


@pytest.fixture
def gate(monkeypatch, small_predictor_file):
    """``go``: let the preparation finish; ``fail``: make it raise instead."""
    go, state = threading.Event(), {"fail": False}
    predictor = load_predictor(small_predictor_file)

    def startup_predictor(progress=None):
        progress("generate", 12, 48)
        assert go.wait(60), "the test never let the preparation finish"
        if state["fail"]:
            raise RuntimeError("no space left on device")
        progress("pipeline", 48, 48)
        return predictor, "quick"

    monkeypatch.setattr(models, "startup_predictor", startup_predictor)
    return go, state


@pytest.fixture
def app_without_model(db_url, gate):
    migrate(db_url)
    db = Database(db_url)
    with db.transaction() as session:
        token, _ = create_token(session, "admin", "prep-test")
    db.dispose()
    settings = Settings(database_url=db_url, scheduler_interval_s=0.05)  # no --predictor
    with TestClient(create_app(settings)) as client:
        yield client, {"Authorization": f"Bearer {token}"}


def preparing(client) -> list[dict]:
    return client.get(f"{API}/health").json()["preparing"]


def test_coaches_run_under_t_rule_until_the_model_is_ready_then_the_layer_takes_over(
    app_without_model, gate
):
    client, headers = app_without_model
    go, _ = gate
    [status] = preparing(client)
    assert status["task"] == "predictor model" and status["state"] == "running"
    assert status["stage"] == "simulating a quick campaign"
    assert status["percent"] == pytest.approx(100 * 0.55 * 12 / 48, abs=0.05)
    assert client.get(f"{API}/models", headers=headers).json() == []

    assert register(client, headers, "A").status_code == 201
    assert post_rows(client, headers, "A", sim_rows(0, 1, 60)).status_code == 200
    sp = wait_for_tick(client, headers, "A", at(60))
    assert sp["source"] == "rule" and sp["t_ref_c"] == pytest.approx(
        sim_rows(0, 60, 60)[0]["t_rule_c"]
    )
    coach = client.get(f"{API}/coaches/A", headers=headers).json()
    assert (coach["status"], coach["reason"]) == ("preparing", "no_model")

    go.set()
    wait_for(lambda: preparing(client) == [], 60, "the model to be ready")
    [model] = client.get(f"{API}/models", headers=headers).json()
    assert (model["version"], model["active"]) == (1, True)
    assert post_rows(client, headers, "A", sim_rows(0, 61, 65)).status_code == 200
    sp = wait_for_tick(client, headers, "A", at(65))
    assert sp["source"] == "ddpc", sp


def test_a_failed_preparation_leaves_t_rule_and_says_why(app_without_model, gate):
    client, headers = app_without_model
    go, state = gate
    state["fail"] = True
    go.set()
    [status] = wait_for(
        lambda: [p for p in preparing(client) if p["state"] == "failed"], 60, "the failure"
    )
    assert status["detail"] == "no space left on device"
    assert client.get(f"{API}/models", headers=headers).json() == []
    register(client, headers, "A")
    post_rows(client, headers, "A", sim_rows(0, 1, 60))
    sp = wait_for_tick(client, headers, "A", at(60))
    assert sp["source"] == "rule"
