"""``bench pipeline`` at a tiny scale (the logs of ``days=2`` linked, not simulated again; the
runs in child processes as in the benchmark): the figures it reports, and their text."""

import pytest

from trainclimate.bench import pipeline


@pytest.mark.slow  # the session's raw logs: 4 simulated coach-days
def test_the_pipeline_benchmark_reports_throughput_and_memory(pregenerated):
    days = pregenerated
    d = pipeline.run(days=days, copies=(1, 2))
    assert d["target_met"] == (d["memory_growth"] <= d["target"]["memory_growth_max"])
    small, large = d["runs"]
    assert small["coach_days"] == 2 * days and large["coach_days"] == 2 * 2 * days
    assert large["raw_rows"] == 2 * small["raw_rows"] and d["size_ratio"] == 2
    for run in d["runs"]:
        assert run["seconds"] > 0 and run["rows_per_s"] > 0 and run["parse_only_rows_per_s"] > 0
        assert 20 < run["peak_rss_mb"] < 4000
    assert d["rows_per_s"] == large["rows_per_s"] and d["peak_rss_mb"] == large["peak_rss_mb"]
    assert 0.5 < d["memory_growth"] < 2
    assert d["winter_1min_run"]["coach_days"] == 2 * days  # the winter coach's days, 2 copies
    assert d["fleet_year_hours_estimate"] > 0 and d["fleet_year_1min_hours_estimate"] > 0
    text = pipeline.text(d)
    assert text.startswith("pipeline: ") and "2× the data" in text
