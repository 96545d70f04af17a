"""``bench predictor`` at a tiny scale (a small dataset, ρ = 6, T = 3; each fit in a child process
as in the benchmark): the figures it reports, and their text."""

import pytest

from trainclimate.bench import predictor


@pytest.mark.slow  # the session's raw logs: 4 simulated coach-days
def test_the_predictor_benchmark_reports_fit_times_and_memory(dataset):
    steps = []
    d = predictor.run((1, 2), dataset, rho=6, horizon=3, progress=steps.append)
    assert isinstance(d["target_met"], bool) and "streaming_extra_mb_growth_max" in d["target"]
    assert steps == [1, 1, 1]
    assert [(r["mode"], r["scale"]) for r in d["runs"]] == [
        ("one_shot", 1),
        ("streaming", 1),
        ("streaming", 2),
    ]
    one_shot, once, twice = d["runs"]
    assert d["rows"] == 9 * (6 + 3) and d["columns"] == once["columns"] > d["rows"]
    assert one_shot["columns"] == once["columns"] and twice["columns"] == 2 * once["columns"]
    assert d["fit_seconds"] == once["seconds"] > 0
    assert all(r["peak_rss_mb"] >= r["rss_before_fit_mb"] > 20 for r in d["runs"])
    assert set(d["streaming_extra_mb"]) == set(d["seconds_per_million_columns"]) == {1, 2}
    lines = predictor.text(d).splitlines()
    assert len(lines) == 3 and "one_shot" in lines[0] and "MB for the fit" in lines[2]
