"""One rule applies a reference at the HVAC interface: T_ref clipped to T_rule ± 2 K where it may be
applied, else T_rule."""

import numpy as np

from trainclimate.coach.setpoint import U_BAND_K, apply_setpoint
from trainclimate.control import OCPSettings


def test_the_band_is_the_drivers_two_kelvin_and_the_controllers_default():
    assert U_BAND_K == 2.0 and OCPSettings().u_band == U_BAND_K


def test_a_reference_is_clipped_to_the_band_or_replaced_by_t_rule():
    t_rule = np.array([22.0, 22.0, 22.0, 22.0, 20.0])
    t_ref = np.array([21.0, 25.5, np.nan, 23.0, 17.0])
    use = np.array([True, True, True, False, True])
    np.testing.assert_array_equal(
        apply_setpoint(t_ref, t_rule, use), [21.0, 24.0, 22.0, 22.0, 18.0]
    )


def test_scalars_broadcast():
    assert apply_setpoint(30.0, 21.0, True) == 23.0
    assert apply_setpoint(30.0, 21.0, False) == 21.0
