"""``bench service`` at a tiny scale on PostgreSQL: every part runs and reports what it did (the
figures themselves are for docs/benchmarks.md, not for a test)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from helpers.service import PG_SKIP, PG_URL
from trainclimate.analysis import trial_plan
from trainclimate.bench import service
from trainclimate.bench.service import comparison
from trainclimate.cli import main


@pytest.mark.slow  # every part of the service benchmark, the 1 000-coach tick among them
def test_the_service_benchmark_runs_at_a_small_scale():
    if not PG_URL:
        pytest.skip(PG_SKIP)
    steps = []
    d = service.run(
        ingest_coaches=4,
        ingest_batches=2,
        pairs=2,
        days=2,
        samples=3,
        requests=3,
        fleet=20,
        progress=steps.append,
    )
    assert steps == [1, 1, 1, 1, 1]
    i, c, t = d["ingest"], d["fleet_scale"], d["fleet_tick"]
    # the headline figures, as the JSON gives them
    assert set(d["summary_ms"]) == {"6h", "24h", "7d", "30d"}
    for name, v in d["summary_ms"].items():
        for kind in ("refresh", "new", "latest"):
            assert v[kind] == {
                "median": c["summary"][name][kind]["median_ms"],
                "p95": c["summary"][name][kind]["p95_ms"],
            }
            assert c["summary"][name][kind]["requests"] == 3
    assert set(d["comparison_ms"]) == {"24h", "7d"}
    assert d["comparison_ms"]["7d"]["p95"] == c["comparison"]["7d"]["p95_ms"]
    assert d["ingest_rows_per_s"] == i["direct_rows_per_s"] and d["rows"] == 2 * 2 * 2 * 1440
    assert d["target"] == {
        "fleet_tick_s": t["target_s"],
        "summary_p95_ms": 300.0,
        "comparison_7d_p95_ms": 150.0,
    }
    summary_met = all(
        v[k]["p95"] <= 300.0 for v in d["summary_ms"].values() for k in ("refresh", "new", "latest")
    )
    met = summary_met and d["comparison_ms"]["7d"]["p95"] <= 150.0
    assert d["target_met"] == (t["tick_s"] <= t["target_s"] and met)
    assert i["rows"] == 4 * 2 * 60 and i["batches"] == 8
    assert min(i["http_rows_per_s"], i["direct_rows_per_s"], i["plain_insert_rows_per_s"]) > 0
    assert i["rollups_cost"] == pytest.approx(
        i["direct_without_rollups_rows_per_s"] / i["direct_rows_per_s"] - 1.0
    )
    assert i["http_batch_latency"]["requests"] == 8
    # the fleet's data and its rollups: 2 days of 48 windows for each of 4 coaches
    assert c["trains_per_reply"] == 2 and c["rollups"]["rows"] == 4 * 2 * 48
    # and the pair days over: the data's first two hours and its first whole service day (the
    # days switch at 02:00 UTC; the data ends at midnight)
    assert c["pair_days"]["rows"] == 2 * 2 and c["pair_days"]["total_mb"] > 0
    assert c["copy"]["rows"] == d["rows"] and c["copy"]["rows_per_s"] > 0
    assert set(c["floor"]) == set(d["summary_ms"]) and c["floor"]["7d"]["requests"] == 3
    assert c["new_vs_floor_p95"]["24h"] == (
        c["summary"]["24h"]["new"]["p95_ms"] / c["floor"]["24h"]["p95_ms"]
    )
    # the timed tick reached every coach: the activated ones past their lead-in solve
    assert t["setpoints_written"] == [20] and t["reasons"] == {"ok": 10, "inactive": 10}
    assert t["baseline_reasons"] == t["reasons"]
    assert d["database"]["created"] and d["database"]["version"]
    assert d["model"] in ("small (fitted here)", "default (cached)")
    # the metrics: their work in the tick of 20 coaches against it, requests with and without
    m = d["metrics"]
    assert m["tick"]["coaches"] == 20 and m["tick"]["tick_s"] == t["tick_s"]
    assert m["tick"]["ratio"] == (t["tick_s"] + m["tick"]["metrics_s"]) / t["tick_s"] > 1
    for route in ("health", "me"):
        r = m[route]
        assert r["with"]["median_ms"] > 0 and r["without"]["median_ms"] > 0
        assert r["median_ratio"] == r["with"]["median_ms"] / r["without"]["median_ms"]
    assert m["scrape"]["coaches"] == 20 and m["scrape"]["bytes"] > 1000
    lines = service.text(d).splitlines()
    assert len(lines) == 6 and lines[1].startswith("2 pairs × 2 days (0.0 M rows")
    assert lines[2].startswith("fleet summary median/p95 ms: 6h refresh")
    assert lines[3].startswith("pair comparison median/p95 ms: 24h")
    assert lines[4].startswith("fleet tick of 20 coaches")
    assert lines[5].startswith("metrics: ") and "a scrape at 20 coaches" in lines[5]


def test_the_service_benchmark_needs_postgresql(capsys):
    with pytest.raises(service.ServiceBenchError, match="needs PostgreSQL, not sqlite"):
        service.run("sqlite:///never.db")
    assert main(["bench", "service", "--db", "sqlite:///never.db"]) == 2
    assert "needs PostgreSQL, not sqlite" in capsys.readouterr().err
    assert main(["bench", "service", "--pairs", "0"]) == 2
    assert "--pairs, --days and --samples must be ≥ 1" in capsys.readouterr().err


def test_the_latest_ranges_end_each_in_a_window_of_its_own_in_the_day_still_running():
    rng = np.random.default_rng(0)
    ends = [comparison._latest_end(rng, 2, k) for k in range(43)]
    data_end = comparison.DATA_START + pd.Timedelta(days=2)
    # each request a new range (the read cache cannot answer it), newest first: it ends at the
    # start of the window its end falls in
    his = [e.floor("30min") for e in ends]
    assert his == [data_end - pd.Timedelta(minutes=30 * (k + 1)) for k in range(43)]
    assert all(e > hi for e, hi in zip(ends, his, strict=True))
    # its last window in the data's last service day, which no pair day holds yet
    last_windows = pd.DatetimeIndex(his) - pd.Timedelta(minutes=30)
    last_day = trial_plan.service_day(data_end - pd.Timedelta(minutes=30), 3).toordinal()
    assert set(trial_plan.service_days(last_windows).tolist()) == {last_day}
