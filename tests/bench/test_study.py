"""``bench study`` at a tiny scale (4 coaches × 1 day, chunks of 2 coaches, the tests' small
predictor in place of the default model): the figures it reports and how they are derived."""

import pytest

from trainclimate.bench import study
from trainclimate.predict import default


@pytest.mark.slow  # two LocalClusters and a profiled chunk: ≈ 30 s
def test_the_study_benchmark_reports_scaling_memory_profile_and_fleet_year(
    monkeypatch, small_predictor
):
    monkeypatch.setattr(default, "default_predictor", lambda *args, **kwargs: small_predictor)
    d = study.run(coaches=4, days=1, chunk_coaches=2)
    assert (d["coach_days"], d["chunk"]) == (4, [2, 1])
    assert d["same_totals"] is True
    assert d["coach_days_per_s_1_worker"] > 0 and d["coach_days_per_s_2_workers"] > 0
    ratio = d["coach_days_per_s_2_workers"] / d["coach_days_per_s_1_worker"]
    assert d["scaling_2_over_1"] == pytest.approx(ratio)
    assert d["parallel_efficiency"] == pytest.approx(ratio / 2)
    assert len(d["worker_peak_rss_mb"]) == 2 and min(d["worker_peak_rss_mb"]) > 50
    prof = d["profile"]
    assert prof["coach_ticks"] > 0
    parts = prof["seconds"]
    assert parts["controller_step"] <= parts["closed_loop_tick"]
    assert parts["state_estimate"] + parts["t_opt"] + parts["ocp_solve"] <= parts["controller_step"]
    assert parts["osqp"] <= parts["ocp_solve"]
    fy = d["fleet_year"]
    assert fy["coach_days"] == 900 * 365
    rate = d["coach_days_per_s_1_worker"]
    assert fy["core_hours"] == pytest.approx(fy["coach_days"] / rate / 3600)
    assert fy["hours_on_cores"]["64"] == pytest.approx(
        fy["core_hours"] / (64 * d["parallel_efficiency"])
    )
    assert d["target_met"] == (fy["hours_on_cores"]["64"] <= 1.0)
    assert len(study.text(d).splitlines()) == 4
