"""``bench calibrate`` at a small scale: one fit, the batched Jacobian against its baseline."""

import pytest

from trainclimate.bench import calibration


@pytest.mark.slow  # 12 generated coach-days and a fit of one parameter
def test_the_calibration_benchmark_reports_time_per_coach_week():
    d = calibration.run(days=6, fits=(("envelope_scale",),))
    assert d["days_logged"] >= 3 and d["scored_training_minutes"] > 720
    fit = d["fits"]["envelope_scale"]
    assert fit["result"]["envelope_scale"] == pytest.approx(1.2, rel=0.10)
    assert fit["seconds_per_coach_week"] == pytest.approx(fit["seconds"] * 7 / d["days_logged"])
    assert d["seconds_per_coach_week"] == fit["seconds_per_coach_week"]
    assert d["target_met"] == (d["seconds_per_coach_week"] <= 300)
    # seven parameter sets as one fleet cost less than seven simulations
    assert d["jacobian_separate_s"] > d["jacobian_batched_s"] > 0 and d["batched_speedup"] > 1
    assert "per coach-week" in calibration.text(d)
