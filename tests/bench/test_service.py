"""``bench service`` at a tiny scale on PostgreSQL: every part runs and reports what it did (the
figures themselves are for docs/benchmarks.md, not for a test)."""

from __future__ import annotations

import pytest

from service_support import PG_SKIP, PG_URL
from trainclimate.bench import service
from trainclimate.cli import main


def test_the_service_benchmark_runs_at_a_small_scale():
    if not PG_URL:
        pytest.skip(PG_SKIP)
    steps = []
    d = service.run(
        ingest_coaches=4,
        ingest_batches=2,
        trains=2,
        days=2,
        requests=3,
        fleet=20,
        progress=steps.append,
    )
    assert steps == [1, 1, 1, 1, 1]
    i, c, t = d["ingest"], d["comparison"], d["fleet_tick"]
    assert d["target"]["fleet_tick_s"] == t["target_s"]
    summary_met = c["summary"]["large"]["p95_ms"] <= d["target"]["summary_p95_ms"]
    assert d["target_met"] == (t["tick_s"] <= t["target_s"] and summary_met)
    assert i["rows"] == 4 * 2 * 60 and i["batches"] == 8
    assert min(i["http_rows_per_s"], i["direct_rows_per_s"], i["plain_insert_rows_per_s"]) > 0
    assert i["http_batch_latency"]["requests"] == 8
    assert c["large"]["rows_stored"] == 2 * 2 * 2 * 1440 and c["large"]["requests"] == 3
    assert c["large"]["windows_per_reply"] in (47, 48)
    assert c["summary"]["large"]["trains_per_reply"] == 2 and c["summary"]["large"]["requests"] == 3
    assert c["summary"]["small"]["trains_per_reply"] == 1
    assert c["summary"]["new_range"]["large"]["requests"] == 3
    assert d["target"]["summary_p95_ms"] == 150.0
    assert c["copy"]["rows"] == c["large"]["rows_stored"] and c["copy"]["rows_per_s"] > 0
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
    assert len(lines) == 5 and lines[2].startswith("24-h fleet summary of 2 trains")
    assert lines[3].startswith("fleet tick of 20 coaches")
    assert lines[4].startswith("metrics: ") and "a scrape at 20 coaches" in lines[4]


def test_the_service_benchmark_needs_postgresql(capsys):
    with pytest.raises(service.ServiceBenchError, match="needs PostgreSQL, not sqlite"):
        service.run("sqlite:///never.db")
    assert main(["bench", "service", "--db", "sqlite:///never.db"]) == 2
    assert "needs PostgreSQL, not sqlite" in capsys.readouterr().err
