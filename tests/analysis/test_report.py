import numpy as np

from trainclimate.analysis.kpi import avg_hourly_violation_k, discomfort_kh, energy_kwh
from trainclimate.analysis.report import write_simulation_report
from trainclimate.sim import scenarios
from trainclimate.sim.simulator import FleetSimulator


def test_kpis_by_hand():
    t_rule = np.full(4, 22.0)
    t_room = np.array([[22.0, 23.5, 20.0], [22.0, 23.0, 21.0], [24.0, 22.0, 22.0], [22, 22, 22]])
    # violations: up 0,0,1,0; mid 0.5,0,0,0; low 1,0,0,0 — samples of 900 s
    np.testing.assert_allclose(discomfort_kh(t_room, t_rule, 900.0), [0.25, 0.125, 0.25])
    assert avg_hourly_violation_k(t_room, t_rule, 900.0) == np.mean([0.25, 0.125, 0.25])
    mask = np.array([False, True, True, True])
    assert avg_hourly_violation_k(t_room, t_rule, 900.0, mask=mask) == np.mean([1, 0, 0]) / 3
    assert energy_kwh(np.array([2.0, 4.0]), 1800.0) == 3.0


def test_report_is_self_contained_html(tmp_path):
    scenario = scenarios.get("parked-cooling-oct")
    env, params = scenarios.build(scenario, n_coaches=2, hours=1.0)
    sim = FleetSimulator(params, env, record_flows=True)
    sim.run()
    path = write_simulation_report({"rule": sim.result()}, scenario, tmp_path / "r.html")
    text = path.read_text()
    assert text.startswith("<!DOCTYPE html>")
    assert '<script src="http' not in text and "Plotly.newPlot" in text  # plotly.js inline
    for title in ("deck temperatures", "electrical power", "heat balance", "energy per coach"):
        assert title in text
