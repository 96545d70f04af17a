import numpy as np
import pytest

from trainclimate.coach.rule import MODE_OFF, MODE_REGULAR, MODE_SLUMBER
from trainclimate.coach.states import HEATING, OFF, PREHEATING, SLUMBER_STATES
from trainclimate.sim import scenarios
from trainclimate.sim.simulator import FleetSimulator

REQUIRED = {
    "winter-day",
    "parked-cooling-oct",
    "parked-cooling-aug-conservative",
    "parked-cooling-aug-energy",
    "parked-heating-nov",
}


def test_contract_scenarios_exist():
    assert set(scenarios.SCENARIOS) >= REQUIRED
    with pytest.raises(scenarios.ScenarioError, match="unknown scenario 'nope'"):
        scenarios.get("nope")


def run(name, hours, n=2):
    env, params = scenarios.build(scenarios.get(name), n_coaches=n, hours=hours)
    sim = FleetSimulator(params, env, seed=scenarios.get(name).seed)
    sim.run()
    return env, sim.result()


def test_scenarios_are_reproducible():
    a_env, a = run("parked-cooling-oct", 1.0)
    b_env, b = run("parked-cooling-oct", 1.0)
    np.testing.assert_array_equal(a.states_c, b.states_c)
    np.testing.assert_array_equal(a.total_power_w, b.total_power_w)
    np.testing.assert_array_equal(a_env.t_amb_c, b_env.t_amb_c)


def test_parked_scenarios_are_empty_still_and_regular():
    for name in REQUIRED - {"winter-day"}:
        env, _ = scenarios.build(scenarios.get(name), hours=0.5)
        assert np.all(env.mode == MODE_REGULAR)
        assert np.all(env.speed_kmh == 0) and np.all(env.occupancy_pct == 0)
        assert not np.any(env.door_open)


def test_scenario_weather_character():
    hot, _ = scenarios.build(scenarios.get("parked-cooling-aug-energy"))
    cold, _ = scenarios.build(scenarios.get("parked-heating-nov"))
    assert hot.t_amb_c.max() > 27 and hot.ghi_w_m2.max() > 500
    assert cold.t_amb_c.max() < 7


@pytest.mark.slow
def test_winter_day_covers_every_mode_and_the_main_states():
    env, result = run("winter-day", 23.0, n=1)
    modes = set(np.unique(env.mode))
    assert {MODE_OFF, MODE_SLUMBER, MODE_REGULAR} <= modes
    states = set(np.unique(result.hvac_state).tolist())
    assert {PREHEATING, HEATING, OFF} <= states
    assert states & set(SLUMBER_STATES)
    # the in-service coach stops at stations with its doors open
    assert env.door_open.sum() > 50
    assert env.speed_kmh.max() > 80
