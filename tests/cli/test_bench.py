"""``bench`` as users call it."""

from helpers.cli import call_json


def test_bench_simulator_keys(capsys):
    data = call_json(
        capsys, "bench", "simulator", "--coaches", "4", "--days", "0.02", "--loop-coaches", "2"
    )
    assert data["coaches"] == 4 and data["days"] == 0.02
    assert data["coach_days_per_s"] > 0 and data["speedup_vs_loop"] > 0
