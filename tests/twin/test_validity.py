"""A calibrated twin's validated ambient range: its file, and the warning of a scenario that
leaves it (experiment, study fleet)."""

import json

import numpy as np
import pytest

from helpers.twin import twin_file
from trainclimate.sim.params import ParamsError, load_params
from trainclimate.twin import validity


def test_a_twin_file_is_a_coach_params_file_with_its_validated_range(tmp_path):
    path = twin_file(tmp_path / "t.json", [-2.0, 12.5])
    assert load_params(path).fan_supply_w == 1300.0
    assert validity.validated_range_of_file(path) == [-2.0, 12.5]
    assert validity.validated_range_of_file(None) is None
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"fan_supply_w": 1200.0}))
    assert validity.validated_range_of_file(plain) is None
    # validated nowhere: every use warns
    assert validity.validated_range_of_file(twin_file(tmp_path / "n.json", None)) == []
    assert "validated it at no ambient" in validity.range_warning([], np.zeros(3), "x")
    with pytest.raises(ParamsError, match=r"validated_t_amb_c must be \[low, high\]"):
        validity.validated_range_of_file(twin_file(tmp_path / "bad.json", [5.0, -5.0]))


def test_a_scenario_leaving_the_range_is_warned_of():
    assert validity.range_warning([-5.0, 10.0], np.array([-4.0, 0.0, 9.0]), "s") is None
    assert validity.range_warning(None, np.array([40.0]), "s") is None
    warning = validity.range_warning([-5.0, 10.0], np.array([0.0, 5.0, 11.0, 14.0]), "scenario s")
    assert warning == (
        "scenario s: T_amb 0.0 to 14.0 °C leaves the twin's validated range -5 to 10 °C for "
        "50 % of the time: its results there are extrapolated"
    )
