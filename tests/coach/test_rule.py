import numpy as np
import pytest

from trainclimate.coach.rule import (
    MODE_OFF,
    MODE_REGULAR,
    MODE_SLUMBER,
    RuleCurve,
    mode_from_operation,
)


def test_default_curve_is_non_decreasing_piecewise_linear_and_labelled_an_assumption():
    curve = RuleCurve()
    t = np.linspace(-30, 45, 751)
    r = curve(t)
    assert np.all(np.diff(r) >= 0)
    assert curve(-10) == 22.0 and curve(19) == 22.0
    assert curve(23) == pytest.approx(23.0)  # +0.25 K per K above 19 °C
    assert curve(50) == 26.0
    assert "assumption" in curve.assumption


def test_curve_is_configurable_and_validated():
    curve = RuleCurve(t_amb_c=(0.0, 10.0, 30.0), t_rule_c=(20.0, 21.0, 24.0))
    assert curve(5.0) == pytest.approx(20.5)
    with pytest.raises(ValueError, match="non-decreasing"):
        RuleCurve(t_amb_c=(0.0, 10.0), t_rule_c=(22.0, 21.0))
    with pytest.raises(ValueError, match="strictly increasing"):
        RuleCurve(t_amb_c=(10.0, 10.0), t_rule_c=(22.0, 23.0))


def test_modes_follow_operation():
    ops = np.array(["service", "layover", "parked", "service"])
    np.testing.assert_array_equal(
        mode_from_operation(ops), [MODE_REGULAR, MODE_SLUMBER, MODE_OFF, MODE_REGULAR]
    )
    with pytest.raises(ValueError, match="unknown train operation"):
        mode_from_operation(np.array(["flying"]))
