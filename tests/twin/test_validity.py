"""A calibrated twin's validated ambient range: its file, and the warning of a scenario that
leaves it (experiment, study fleet); the warning of its savings when its response to setpoint
changes was not validated."""

import json

import numpy as np
import pytest

from helpers.twin import RESPONSE_OK, twin_file
from trainclimate.sim.params import ParamsError, load_params
from trainclimate.twin import validity


def validated_range_of_file(path):
    return validity.validated_range(validity.record_of_file(path), str(path))


def test_a_twin_file_is_a_coach_params_file_with_its_validated_range(tmp_path):
    path = twin_file(tmp_path / "t.json", [-2.0, 12.5])
    assert load_params(path).fan_supply_w == 1300.0
    assert validated_range_of_file(path) == [-2.0, 12.5]
    assert validity.record_of_file(path)["holdout"]["setpoint_response"] == RESPONSE_OK
    assert validated_range_of_file(None) is None
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"fan_supply_w": 1200.0}))
    assert validity.record_of_file(plain) is None
    assert validated_range_of_file(plain) is None
    # validated nowhere: every use warns
    assert validated_range_of_file(twin_file(tmp_path / "n.json", None)) == []
    assert "validated it at no ambient" in validity.range_warning([], np.zeros(3), "x")
    with pytest.raises(ParamsError, match=r"validated_t_amb_c must be \[low, high\]"):
        validated_range_of_file(twin_file(tmp_path / "bad.json", [5.0, -5.0]))


def test_a_twin_whose_response_to_setpoint_changes_was_not_validated_warns_of_its_savings():
    def warning(**score):
        return validity.savings_warning({"holdout": {"setpoint_response": score}}, "t.json")

    assert warning(scored=3, response_error_pct=15.0) is None  # 3 changes, 15 %: validated
    assert warning(scored=2, response_error_pct=3.0) == (
        "t.json: the savings predicted with the twin are not validated: its response to a "
        "setpoint change is untested: the held-out days hold 2 scored change(s), 3 needed"
    )
    assert warning(scored=0, response_error_pct=None).endswith("hold 0 scored change(s), 3 needed")
    assert warning(scored=4, response_error_pct=39.4) == (
        "t.json: the savings predicted with the twin are not validated: its energy response to "
        "the 4 held-out setpoint changes is 39 % off (beyond 15 %)"
    )
    # no score (a coach-params file of one's own, an older calibration's): nothing to say
    assert validity.savings_warning(None, "x") is None
    assert validity.savings_warning({"holdout": {"energy_error_pct": 1.0}}, "x") is None
    for bad in ({"scored": "2"}, {"scored": -1}, {"scored": 4, "response_error_pct": "x"}, [4]):
        with pytest.raises(ParamsError, match=r"t\.json: holdout\.setpoint_response must hold"):
            validity.savings_warning({"holdout": {"setpoint_response": bad}}, "t.json")


def test_a_scenario_leaving_the_range_is_warned_of():
    assert validity.range_warning([-5.0, 10.0], np.array([-4.0, 0.0, 9.0]), "s") is None
    assert validity.range_warning(None, np.array([40.0]), "s") is None
    warning = validity.range_warning([-5.0, 10.0], np.array([0.0, 5.0, 11.0, 14.0]), "scenario s")
    assert warning == (
        "scenario s: T_amb 0.0 to 14.0 °C leaves the twin's validated range -5 to 10 °C for "
        "50 % of the time: its results there are extrapolated"
    )
