"""The HVAC's electrical power: today's model by hand, and each literature option of the power
model by hand, off by default."""

import dataclasses

import numpy as np
import pytest

from trainclimate.sim.params import CoachParams, stack
from trainclimate.sim.power import cop, electrical_power, part_load_factor

DEFAULT = CoachParams()


def power(params: CoachParams, q_hvac_w, t_amb_c=30.0, t_mix_c=26.0):
    p = stack([params])
    return electrical_power(
        np.array([q_hvac_w], dtype=float),
        np.zeros((1, 3)),
        np.array([t_amb_c]),
        np.array([True]),
        p,
        np.array([t_mix_c]),
    )


def test_the_default_model_by_hand():
    # cooling 6.6 kW of 22 kW capacity at 30 °C: COP 4.4 − 0.06 · 30 = 2.6
    pw = power(DEFAULT, [-2000.0, -2000.0, -2600.0])
    assert pw.compressor_w[0] == pytest.approx(6600.0 / 2.6)
    assert pw.fans_w[0] == pytest.approx(1100.0 + 800.0 * 6600.0 / 22000.0)
    # the evaporator's air does not matter while the Carnot model is off
    assert power(DEFAULT, [-2000.0, -2000.0, -2600.0], t_mix_c=10.0).total_w == pw.total_w


def test_the_carnot_efficiency_cop_depends_on_both_sides_of_the_cycle():
    p = stack([dataclasses.replace(DEFAULT, cop_carnot_efficiency=0.3)])
    # T_e = 26 − 10 = 16 °C = 289.15 K, T_c = 30 + 15 = 45 °C = 318.15 K
    expected = 0.3 * 289.15 / (318.15 - 289.15)
    assert cop(np.array([30.0]), p, np.array([26.0]))[0] == pytest.approx(expected)
    # warmer return air: a warmer evaporator, a better COP; the ambient-only law cannot see it
    assert cop(np.array([30.0]), p, np.array([28.0]))[0] > expected
    # clipped to the unit's range
    assert cop(np.array([30.0]), p, np.array([60.0]))[0] == DEFAULT.cop_max
    assert cop(np.array([30.0]), stack([DEFAULT]), np.array([26.0]))[0] == pytest.approx(2.6)


def test_part_load_cycling_degrades_the_cop_below_the_minimum_capacity():
    p = stack([dataclasses.replace(DEFAULT, part_load_degradation=0.25)])
    # at or above 30 % of its capacity the compressor modulates: no loss
    np.testing.assert_allclose(part_load_factor(np.array([0.3, 0.8]), p), 1.0)
    # at 15 % it cycles half the time: 1 − 0.25 · (1 − 0.5)
    assert part_load_factor(np.array([0.15]), p)[0] == pytest.approx(0.875)
    light = [-1100.0, 0.0, 0.0]  # 5 % of capacity
    degraded = power(dataclasses.replace(DEFAULT, part_load_degradation=0.25), light)
    cr = 1100.0 / 22000.0 / 0.3
    assert degraded.compressor_w[0] == pytest.approx(1100.0 / 2.6 / (1 - 0.25 * (1 - cr)))
    assert power(DEFAULT, light).compressor_w[0] == pytest.approx(1100.0 / 2.6)


def test_fans_running_with_the_compressor_or_following_the_load():
    light = [-1100.0, 0.0, 0.0]  # 5 % of the cooling capacity
    cycling = power(dataclasses.replace(DEFAULT, fan_condenser_cycling=1.0), light)
    assert cycling.fans_w[0] == pytest.approx(1100.0 + 800.0)
    assert power(dataclasses.replace(DEFAULT, fan_condenser_cycling=1.0), [0, 0, 0]).fans_w[
        0
    ] == pytest.approx(1100.0)
    following = dataclasses.replace(DEFAULT, fan_supply_min_fraction=0.3)
    heating = [4800.0, 0.0, 0.0]  # 20 % of the 24 kW heating capacity
    assert power(following, heating).fans_w[0] == pytest.approx(1100.0 * (0.3 + 0.7 * 0.2))
    assert power(DEFAULT, heating).fans_w[0] == pytest.approx(1100.0)
