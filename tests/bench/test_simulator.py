"""``bench simulator`` at a tiny scale: the figures it reports, and their text."""

from trainclimate.bench import simulator


def test_the_simulator_benchmark_reports_coach_days_per_second():
    d = simulator.run(coaches=4, days=0.02, loop_coaches=2)
    assert d["target_met"] == (d["coach_days_per_s"] >= d["target"]["coach_days_per_s"] == 10)
    assert (d["coaches"], d["days"], d["loop_coaches"], d["dt_s"]) == (4, 0.02, 2, 10.0)
    assert d["steps"] == round(0.02 * 86400 / 10.0)
    assert d["coach_days_per_s"] > 0 and d["loop_coach_days_per_s"] > 0 and d["fleet_seconds"] > 0
    assert d["speedup_vs_loop"] == d["coach_days_per_s"] / d["loop_coach_days_per_s"]
    assert set(d["machine"]) == {"cpu", "cpu_model", "cores", "python", "numpy"}
    assert simulator.text(d).startswith("simulator: ") and "speed-up" in simulator.text(d)


def test_the_loop_baseline_never_simulates_more_coaches_than_the_fleet():
    assert simulator.run(coaches=1, days=0.01, loop_coaches=5)["loop_coaches"] == 1
