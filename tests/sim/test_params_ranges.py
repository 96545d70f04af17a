"""Plausible parameter ranges (``PLAUSIBLE``) and the simulator's divergence guard: a unit slip
in a parameter file is one line and exit 2, a diverging simulation is an error, never ``NaN``."""

import dataclasses
import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from helpers.cli import call
from trainclimate.sim import scenarios, thermal
from trainclimate.sim.params import VARIED, CoachParams, ParamsError
from trainclimate.sim.plausible import PLAUSIBLE
from trainclimate.sim.simulator import FleetSimulator, SimulationError

DOCS = Path(__file__).resolve().parents[2] / "docs" / "model.md"
#: A short run of a cold scenario, as the CLI tests call it.
SIMULATE = ["simulate", "--scenario", "parked-heating-nov", "--hours", "0.1"]


def refused(change: dict) -> str:
    with pytest.raises(ParamsError) as err:
        CoachParams.from_dict(change)
    return str(err.value)


def test_every_field_has_a_range_holding_its_default_and_the_coach_diversity():
    assert list(PLAUSIBLE) == [f.name for f in dataclasses.fields(CoachParams)]
    default = CoachParams()
    for name, (low, high, _unit, _reason) in PLAUSIBLE.items():
        value = np.asarray(getattr(default, name))
        factors = (0.85, 1.0, 1.15) if name in VARIED else (1.0,)  # diversify's ±15 %
        for factor in factors:
            assert np.all((low <= value * factor) & (value * factor <= high)), (name, factor)


@pytest.mark.parametrize("name", scenarios.SCENARIOS)
def test_every_scenario_coach_is_plausible(name):
    spec = scenarios.get(name)
    for params in scenarios.coach_params(CoachParams(), 30, spec.seed):
        params.validate()


def test_capacity_in_kj_per_k_is_refused_naming_field_unit_and_range():
    message = refused({"c_room_j_k": [90.0, 60.0, 105.0]})
    assert message.startswith("c_room_j_k[up] = 90 J/K is outside 10000 … 1e+06 J/K (")
    assert message.endswith("; kJ/K given?)")
    assert "\n" not in message


@pytest.mark.parametrize(
    ("change", "start", "hint"),
    [
        ({"c_chassis_j_k": [1.4e6, 0.7e6, 1.8e9]}, "c_chassis_j_k[low] = 1.8e+09 J/K is", ""),
        ({"q_heat_max_w": [9.0, 5.0, 10.0]}, "q_heat_max_w[up] = 9 W is", "; kW given?)"),
        ({"supply_air_m3_h": 1.0}, "supply_air_m3_h = 1 m³/h is outside 500 … 20000 m³/h", ""),
        ({"pid_ti_s": [10.0, 10.0, 10.0]}, "pid_ti_s[up] = 10 s is outside 30 … 10000 s", ""),
        ({"ua_chassis_chassis_w_k": [40.0, 40.0, 1e5]}, "ua_chassis_chassis_w_k[up–low] =", ""),
        ({"window_g": 0.95}, "window_g = 0.95 is outside 0.05 … 0.9 (", ""),
        ({"seats": [20.0, 80.0, 17.0]}, "seats[mid] = 80 is outside 0 … 60 (", ""),
    ],
)
def test_values_outside_their_range_are_refused(change, start, hint):
    message = refused(change)
    assert message.startswith(start)
    # the kilo-unit question only when the value is too small and 1000 × it would fit
    if hint:
        assert message.endswith(hint)
    else:
        assert "given?" not in message


def test_existing_checks_come_first():
    assert "'c_room_j_k' must be > 0" in refused({"c_room_j_k": [-9e4, 6e4, 1e5]})


def test_docs_table_lists_every_range():
    rows = re.findall(r"^\| `(\w+)` \| (\S+) … (\S+) \| (\S+) \| (.+) \|$", DOCS.read_text(), re.M)
    documented = {name: (float(lo), float(hi), unit, why) for name, lo, hi, unit, why in rows}
    assert documented == {
        name: (low, high, unit or "–", why) for name, (low, high, unit, why) in PLAUSIBLE.items()
    }


@pytest.mark.parametrize("command", [SIMULATE, ["coach-params", "--json"]])
def test_cli_refuses_an_implausible_file_with_exit_2_and_one_line(capsys, tmp_path, command):
    path = tmp_path / "coach.json"
    path.write_text(json.dumps({"c_room_j_k": [90.0, 60.0, 105.0]}))
    flag = "--coach-params" if command[0] == "simulate" else "--file"
    code, out, err = call(capsys, *command, flag, str(path))
    assert code == 2 and out == ""
    assert err.splitlines() == [
        "trainclimate: error: c_room_j_k[up] = 90 J/K is outside 10000 … 1e+06 J/K "
        "(a deck's air and light fittings, ~30–120 kJ/K; kJ/K given?)"
    ]


def nan_after_two_steps(monkeypatch):
    """Make the thermal integration return NaN temperatures from the third step on."""
    real = thermal.rk4_step
    calls = []

    def rk4_step(T, *args):
        calls.append(1)
        new, flows = real(T, *args)
        return (new * np.nan if len(calls) > 2 else new), flows

    monkeypatch.setattr(thermal, "rk4_step", rk4_step)


def test_a_non_finite_state_stops_the_simulator(monkeypatch):
    nan_after_two_steps(monkeypatch)
    env, params = scenarios.build(scenarios.get("parked-heating-nov"), n_coaches=2, hours=0.1)
    sim = FleetSimulator(params, env)
    with pytest.raises(SimulationError, match=r"diverged in step 2 .*, coach 0: .*NaN"):
        sim.run()
    assert sim.k == 2


def test_cli_prints_no_nan_for_a_non_finite_simulation(capsys, monkeypatch):
    nan_after_two_steps(monkeypatch)
    code, out, err = call(capsys, *SIMULATE, "--json")
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and "diverged in step 2" in err


def test_cli_stops_a_diverging_plausible_combination_in_one_line(capsys, tmp_path):
    # each value is plausible; together they make the 10 s RK4 step unstable
    path = tmp_path / "coach.json"
    path.write_text(json.dumps({"c_room_j_k": [1e4, 1e4, 1e4], "ua_deck_deck_w_k": [5e3, 5e3]}))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # stopped before any overflow
        code, out, err = call(capsys, *SIMULATE, "--json", "--coach-params", str(path))
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and "diverged" in err and "coach parameters" in err


def test_cli_refuses_non_finite_kpis(capsys, monkeypatch):
    from trainclimate.analysis import summary

    real = summary.fleet_kpis
    monkeypatch.setattr(summary, "fleet_kpis", lambda r: {**real(r), "energy_kwh": float("nan")})
    code, out, err = call(capsys, *SIMULATE, "--json")
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and "not finite" in err
