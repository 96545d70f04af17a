"""``bench replicas`` at a tiny scale on PostgreSQL: two service processes split the live fleet's
tick and every coach gets exactly one setpoint (the figures themselves are for
docs/benchmarks.md, not for a test)."""

from __future__ import annotations

import pytest

from helpers.service import PG_SKIP, PG_URL
from trainclimate.bench import replicas
from trainclimate.cli import main


def test_the_replicas_benchmark_runs_at_a_small_scale():
    if not PG_URL:
        pytest.skip(PG_SKIP)
    steps = []
    # 8 batches of 5 coaches per tick, so that both processes find some to claim
    d = replicas.run(40, batch=5, progress=steps.append)
    assert steps == [1, 1, 1]
    assert d["coaches"] == 40 and d["activated"] == 20 and d["exactly_once"]
    for p, n in (("1", 1), ("2", 2)):
        run = d["runs"][p]
        assert len(d["tick_s_runs"][p]) == replicas.MEASURED_TICKS and d["tick_s"][p] > 0
        assert len(run["warm_up_s"]) == replicas.WARM_UP_TICKS
        assert run["reasons"] == {"ok": 20, "inactive": 20}
        assert [r["replica"] for r in run["processes"]] == [
            f"bench-replica-{i}" for i in range(1, n + 1)
        ]
        assert 0 < d["db_share"][p] < 1
        # every coach exactly once per measured tick, the replicas' counts as they reported them
        for k, by_replica in enumerate(d["by_replica"][p]):
            assert sum(by_replica.values()) == 40
            issued = {r["replica"]: r["issued"][k] for r in run["processes"]}
            assert by_replica == {r: c for r, c in issued.items() if c}
    assert d["by_replica"]["1"] == [{"bench-replica-1": 40}] * replicas.MEASURED_TICKS
    assert all(c["coaches"] == 0 for c in d["runs"]["1"]["changed_replica"])
    # one process built a controller for each activated coach, in its first tick
    (one,) = d["runs"]["1"]["processes"]
    assert one["controllers"] == 20 and one["controllers_built"] == [0] * replicas.MEASURED_TICKS
    # with 2 processes both took coaches at every measured tick
    assert all(len(b) == 2 and min(b.values()) > 0 for b in d["by_replica"]["2"])
    assert d["speedup"] == d["tick_s"]["1"] / d["tick_s"]["2"]
    assert d["target"] == {"tick_s_2_processes": 10.0, "speedup": 1.6}
    assert isinstance(d["target_met"], bool)
    assert d["database"]["version"] and d["machine"]["cores"]
    assert "before" in d["machine"]["load_average_1min"]
    parts = d["runs"]["2"]["processes"][0]["parts_s"]
    assert set(parts) == {*replicas.PARTS, "other"}
    lines = replicas.text(d).splitlines()
    assert len(lines) == 3 and lines[0].startswith("40 live coaches (20 activated) on PostgreSQL")


def test_the_replicas_benchmark_takes_a_postgresql_server_only(capsys):
    with pytest.raises(replicas.ReplicasBenchError, match="PostgreSQL server"):
        replicas.run(40, "sqlite:///never.db")
    assert main(["bench", "replicas", "--db", "sqlite:///never.db"]) == 2
    assert "--db takes a PostgreSQL server" in capsys.readouterr().err
    assert main(["bench", "replicas", "--db", "postgresql://postgres@127.0.0.1:1/test"]) == 2
    assert "no PostgreSQL database to benchmark on" in capsys.readouterr().err
    assert main(["bench", "replicas", "--coaches", "3"]) == 2
    assert "--coaches must be an even number" in capsys.readouterr().err
