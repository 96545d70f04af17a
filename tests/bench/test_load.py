"""``bench load`` at a tiny scale on SQLite: the server runs as its own process, every request is
answered, and the result reports what it measured (the figures themselves are for
docs/benchmarks.md, not for a test)."""

from __future__ import annotations

import pytest

from trainclimate.bench import load
from trainclimate.cli import main
from trainclimate.service.adapters import demo


def test_the_load_benchmark_runs_at_a_small_scale():
    steps = []
    d = load.run(clients=4, requests=40, progress=steps.append)
    assert steps == [1, 1, 1]
    assert d["clients"] == 4 and d["requests"] == 40 and d["database"] == "sqlite"
    assert d["errors"] == {}
    assert "500" not in d["by_status"]
    assert sum(d["by_status"].values()) == 40
    assert set(d["by_status"]) <= {"200", "201", "503"}
    assert set(d["by_kind"]) <= {"fleet", "comparison", "override"}
    assert sum(k["requests"] for k in d["by_kind"].values()) == 40
    lat = d["latency"]
    assert 0 < lat["median_ms"] <= lat["p95_ms"] <= lat["p99_ms"] <= lat["max_ms"]
    assert d["requests_per_s"] > 0 and d["seconds"] > 0
    base = d["baseline"]
    assert base["requests"] == 20 and base["errors"] == {} and "500" not in base["by_status"]
    assert base["median_ratio"] > 0 and base["p99_ratio"] > 0
    ticks = d["ticks"]
    assert set(ticks["issued"]) == set(demo.coach_ids())
    assert ticks["expected"] > 0 and isinstance(ticks["on_time"], bool)
    assert isinstance(d["target_met"], bool)
    assert d["machine"]["cores"] and "before" in d["machine"]["load_average_1min"]
    lines = load.text(d).splitlines()
    assert lines[0].startswith("4 clients, 40 requests on sqlite")
    m = d["mqtt"]
    if m is None:  # no broker answers on 127.0.0.1:1883
        assert len(lines) == 3
        return
    # ten live coaches fed through the broker while the clients asked: every row once
    assert len(lines) == 4 and lines[3].startswith("MQTT: 5 gateways, 10 coaches")
    assert m["coaches"] == 10 and m["published"] == 10 * m["minutes"] > 0
    assert m["unacknowledged"] == 0 and m["dropped"] == {}
    assert m["rows_stored"] == m["published"] and m["exactly_once"]
    assert set(m["ticks"]["issued"]) == {f"L{t}-{s}" for t in range(1, 6) for s in "AB"}


def test_the_load_benchmark_takes_a_postgresql_server_only(capsys):
    with pytest.raises(load.LoadBenchError, match="PostgreSQL server"):
        load.run(1, 1, "sqlite:///never.db")
    assert main(["bench", "load", "--db", "sqlite:///never.db"]) == 2
    assert "--db takes a PostgreSQL server" in capsys.readouterr().err
    assert main(["bench", "load", "--clients", "0"]) == 2
    assert main(["bench", "load", "--mqtt-coaches", "3"]) == 2
    assert "--mqtt-coaches must be an even number" in capsys.readouterr().err
