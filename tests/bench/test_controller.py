"""``bench controller`` at a tiny scale, on a small dataset and a model fitted on it (at the
default model's setting, 5 min, ρ = 12, T = 6): the figures it reports, and their text."""

import pytest

from trainclimate.bench import controller
from trainclimate.data import cache
from trainclimate.data.trajectory import iter_trajectories
from trainclimate.predict import TransientPredictor, default


@pytest.fixture
def small_default(dataset, monkeypatch):
    """The default dataset and model replaced by the small ones."""
    model = TransientPredictor(12, 6).fit(iter_trajectories(dataset / "trajectories_5min.parquet"))
    monkeypatch.setattr(cache, "default_dataset", lambda *args, **kwargs: dataset)
    monkeypatch.setattr(default, "default_predictor", lambda *args, **kwargs: model)


@pytest.mark.slow  # the session's raw logs: 4 simulated coach-days
def test_the_controller_benchmark_reports_solve_step_and_tick_times(small_default):
    d = controller.run(n_steps=5, n_naive=2, fleet=4)
    assert d["target"] == controller.TARGET
    assert d["target_met"] == (
        d["fast_median_ms"] <= 1.0 and d["naive_over_fast"] >= 20 and d["fleet_1000_tick_s"] <= 2
    )
    assert (d["rho"], d["horizon"], d["instances"], d["fleet_coaches"]) == (12, 6, 5, 4)
    for path in ("fast", "cvxpy_dpp", "cvxpy_naive", "controller_step"):
        assert 0 < d[f"{path}_median_ms"] <= d[f"{path}_p99_ms"] < 10_000
    assert d["naive_over_fast"] == d["cvxpy_naive_median_ms"] / d["fast_median_ms"]
    assert d["objective"] == "states" and 0 < d["paper_fast_median_ms"] < 10_000
    assert sum(d["fleet_tick_reasons"].values()) == 4 and d["fleet_1000_tick_s"] > 0
    lines = controller.text(d).splitlines()
    assert len(lines) == 2 and lines[0].startswith("OCP solve (ρ = 12, T = 6, states)")
