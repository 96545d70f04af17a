"""``bench pipeline`` at a tiny scale (the logs of ``days=2`` linked, not simulated again; the
runs in child processes as in the benchmark): the figures it reports, and their text."""

import pytest

from trainclimate.bench import pipeline


@pytest.mark.slow  # the session's raw logs: 4 simulated coach-days
def test_the_pipeline_benchmark_reports_throughput_and_memory(pregenerated):
    days = pregenerated
    d = pipeline.run(days=days, copies=(1, 2), big_file_mb=40)
    big = d["big_file"]
    assert d["target_met"] == (
        d["memory_growth"] <= d["target"]["memory_growth_max"]
        and big["runs"][-1]["peak_rss_mb"] <= d["target"]["big_file_peak_rss_mb_max"]
    )
    # the big export: about the size asked, the same coach-days, its added days read and counted
    # (whole days of 2-s rows added: 2.9 MB each)
    assert big["runs"][0]["file_mb"] < 8 and abs(big["runs"][1]["file_mb"] - 40) < 1.5
    assert [r["coach_days"] for r in big["runs"]] == [big["baseline"]["coach_days"]] * 2
    assert big["baseline"]["raw_rows"] < big["runs"][0]["raw_rows"] < big["runs"][1]["raw_rows"]
    assert big["runs"][1]["peak_rss_mb"] < 1.5 * big["baseline"]["peak_rss_mb"]
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
    assert text.startswith("pipeline: ") and "2× the data" in text and "MB export" in text
