import numpy as np
import pytest

from trainclimate.sim import hvac
from trainclimate.sim.params import CoachParams, stack
from trainclimate.sim.rule import MODE_OFF, MODE_REGULAR, MODE_SLUMBER

P1 = stack([CoachParams()])


def state_after(prev, mode, t_room, t_ref, t_amb):
    return int(
        hvac.next_state(
            np.array([prev]),
            np.array([mode]),
            np.full((1, 3), float(t_room)),
            np.array([float(t_ref)]),
            np.array([float(t_amb)]),
            P1,
        )[0]
    )


def test_preheating_and_precooling_with_hysteresis():
    # enter preheating 3 K below T_ref, stay until 1 K below
    assert state_after(hvac.OFF, MODE_REGULAR, 14.0, 22.0, 0.0) == hvac.PREHEATING
    assert state_after(hvac.PREHEATING, MODE_REGULAR, 20.5, 22.0, 0.0) == hvac.PREHEATING
    assert state_after(hvac.HEATING, MODE_REGULAR, 20.5, 22.0, 0.0) == hvac.HEATING
    assert state_after(hvac.PREHEATING, MODE_REGULAR, 21.2, 22.0, 0.0) == hvac.HEATING
    assert state_after(hvac.OFF, MODE_REGULAR, 30.0, 22.0, 30.0) == hvac.PRECOOLING
    assert state_after(hvac.PRECOOLING, MODE_REGULAR, 23.5, 22.0, 30.0) == hvac.PRECOOLING
    assert state_after(hvac.PRECOOLING, MODE_REGULAR, 22.8, 22.0, 30.0) == hvac.COOLING


def test_heating_mixed_cooling_switch_on_ambient_with_hysteresis():
    # T_ref 22: heating below 14 °C outside, cooling above 20 °C, 1 K hysteresis
    assert state_after(hvac.OFF, MODE_REGULAR, 22, 22, 13.5) == hvac.HEATING
    assert state_after(hvac.HEATING, MODE_REGULAR, 22, 22, 14.5) == hvac.HEATING
    assert state_after(hvac.HEATING, MODE_REGULAR, 22, 22, 15.5) == hvac.MIXED
    assert state_after(hvac.MIXED, MODE_REGULAR, 22, 22, 13.5) == hvac.MIXED
    assert state_after(hvac.MIXED, MODE_REGULAR, 22, 22, 12.9) == hvac.HEATING
    assert state_after(hvac.MIXED, MODE_REGULAR, 22, 22, 20.5) == hvac.MIXED
    assert state_after(hvac.MIXED, MODE_REGULAR, 22, 22, 21.1) == hvac.COOLING
    assert state_after(hvac.COOLING, MODE_REGULAR, 22, 22, 19.5) == hvac.COOLING
    assert state_after(hvac.COOLING, MODE_REGULAR, 22, 22, 18.9) == hvac.MIXED
    assert state_after(hvac.HEATING, MODE_REGULAR, 22, 22, 25.0) == hvac.COOLING


def test_slumber_states():
    assert state_after(hvac.OFF, MODE_SLUMBER, 16.5, 22, 0) == hvac.SLUMBER_HEATING
    assert state_after(hvac.SLUMBER_HEATING, MODE_SLUMBER, 17.5, 22, 0) == hvac.SLUMBER_HEATING
    assert state_after(hvac.SLUMBER_HEATING, MODE_SLUMBER, 18.1, 22, 0) == hvac.SLUMBER_OFF
    assert state_after(hvac.SLUMBER_OFF, MODE_SLUMBER, 17.5, 22, 0) == hvac.SLUMBER_OFF
    assert state_after(hvac.SLUMBER_OFF, MODE_SLUMBER, 25.0, 22, 15) == hvac.SLUMBER_VENTILATION
    assert state_after(hvac.SLUMBER_VENTILATION, MODE_SLUMBER, 27.5, 22, 15) == (
        hvac.SLUMBER_COOLING
    )
    assert state_after(hvac.SLUMBER_OFF, MODE_SLUMBER, 27.5, 22, 30) == hvac.SLUMBER_COOLING
    assert state_after(hvac.SLUMBER_COOLING, MODE_SLUMBER, 26.5, 22, 30) == hvac.SLUMBER_COOLING
    assert state_after(hvac.SLUMBER_COOLING, MODE_SLUMBER, 25.9, 22, 30) == hvac.SLUMBER_OFF
    assert state_after(hvac.HEATING, MODE_OFF, 10, 22, 0) == hvac.OFF


def fresh(state, t_room, t_ref, t_amb, passengers=0.0):
    pax = np.array([[passengers * 20 / 45, passengers * 8 / 45, passengers * 17 / 45]])
    f, label = hvac.fresh_air_fraction(
        np.array([state]),
        np.full((1, 3), float(t_room)),
        np.array([float(t_ref)]),
        np.array([float(t_amb)]),
        pax,
        P1,
    )
    return float(f[0]), int(label[0])


def test_fresh_air_minimum_per_passenger():
    base = CoachParams().fresh_air_base_fraction
    assert fresh(hvac.HEATING, 22, 22, 0) == (pytest.approx(base), hvac.RECIRCULATED)
    f, label = fresh(hvac.HEATING, 22, 22, 0, passengers=45)
    assert f == pytest.approx(base + 45 * 20 / 3600)
    assert label == hvac.RECIRCULATED
    # preheating an empty coach: pure recirculation; with passengers their minimum
    assert fresh(hvac.PREHEATING, 15, 22, 0)[0] == 0.0
    assert fresh(hvac.PREHEATING, 15, 22, 0, passengers=36)[0] == pytest.approx(0.2)
    # more passengers never means less fresh air
    fs = [fresh(hvac.COOLING, 22, 22, 30, passengers=n)[0] for n in (0, 10, 50, 100, 200)]
    assert fs == sorted(fs) and fs[-1] == 1.0


def test_economiser_substates():
    assert fresh(hvac.COOLING, 23, 22, 10) == (1.0, hvac.OUTSIDE)
    f, label = fresh(hvac.COOLING, 21.7, 22, 10)
    assert 0.15 < f < 1.0 and label == hvac.MIXED_AIR
    assert fresh(hvac.COOLING, 23, 22, 30)[1] == hvac.RECIRCULATED
    assert fresh(hvac.OFF, 23, 22, 10) == (0.0, hvac.RECIRCULATED)
    assert fresh(hvac.SLUMBER_VENTILATION, 25, 22, 15) == (1.0, hvac.OUTSIDE)


def test_mixed_state_economiser_opens_only_above_the_setpoint():
    """Continuous at T_ref: no free cooling while the coach is at or below its setpoint (the
    heaters may still run in the mixed state); fully open 1 K above it."""
    f_min = fresh(hvac.HEATING, 21.0, 22, 15)[0]
    assert fresh(hvac.MIXED, 22.0, 22, 15)[0] == pytest.approx(f_min)
    assert fresh(hvac.MIXED, 22.01, 22, 15)[0] == pytest.approx(f_min + 0.01 * (1 - f_min))
    assert fresh(hvac.MIXED, 22.5, 22, 15)[0] == pytest.approx(f_min + 0.5 * (1 - f_min))
    assert fresh(hvac.MIXED, 23.0, 22, 15) == (pytest.approx(1.0), hvac.OUTSIDE)
    # no economiser when outside is not cooler than the coach by the band
    assert fresh(hvac.MIXED, 22.5, 22, 22)[0] == pytest.approx(f_min)


def test_floor_wall_heating_only_in_preheating_and_heating():
    q_max = CoachParams().q_fw_max_w
    states = np.array(
        [
            hvac.PREHEATING,
            hvac.HEATING,
            hvac.HEATING,
            hvac.HEATING,
            hvac.MIXED,
            hvac.COOLING,
            hvac.SLUMBER_HEATING,
            hvac.OFF,
        ]
    )
    t_amb = np.array([10.0, -20.0, 2.5, 20.0, 0.0, 0.0, 0.0, 0.0])
    q = hvac.floor_wall_heating(states, t_amb, stack([CoachParams()] * 8))
    np.testing.assert_allclose(q[0], q_max)
    np.testing.assert_allclose(q[1], q_max)
    np.testing.assert_allclose(q[2], 0.5 * q_max)
    np.testing.assert_allclose(q[3:], 0.0)


def run_pid(pid, setpoint, y, state, steps):
    out = []
    for _ in range(steps):
        out.append(pid.update(np.array([setpoint]), np.full((1, 3), y), np.array([state])))
    return np.array(out)[:, 0, :]


def test_pid_output_and_rate_limits():
    p = CoachParams()
    pid = hvac.PID(1, P1, dt_s=10.0)
    out = run_pid(pid, 22.0, 15.0, hvac.HEATING, 60)
    assert np.all(np.diff(out, axis=0) <= p.pid_rate_w_s * 10.0 + 1e-9)
    np.testing.assert_allclose(out[-1], p.q_heat_max_w)
    assert np.all(out >= 0)
    pid = hvac.PID(1, P1, dt_s=10.0)
    out = run_pid(pid, 22.0, 30.0, hvac.COOLING, 60)
    np.testing.assert_allclose(out[-1], -p.q_cool_max_w)
    assert np.all(out <= 0)


def test_pid_anti_windup_recovers_at_once():
    p = CoachParams()
    pid = hvac.PID(1, P1, dt_s=10.0)
    run_pid(pid, 22.0, 15.0, hvac.HEATING, 2000)  # 5.5 h saturated at full heat
    assert np.all(pid.integral <= p.q_heat_max_w + 1e-9)
    # the error reverses: without anti-windup the integral (~10⁷ W) would hold full heat for
    # hours; with it the output leaves saturation within a minute
    out = run_pid(pid, 22.0, 22.6, hvac.HEATING, 6)
    assert np.all(out[-1] < 0.9 * p.q_heat_max_w)


def test_pid_resets_on_state_transitions():
    p = CoachParams()
    pid = hvac.PID(1, P1, dt_s=10.0)
    run_pid(pid, 22.0, 22.5, hvac.HEATING, 10)
    pid.reset_on_transition(np.array([hvac.HEATING]), np.array([hvac.PREHEATING]))
    np.testing.assert_allclose(pid.integral[0], p.q_heat_max_w)
    pid.reset_on_transition(np.array([hvac.PREHEATING]), np.array([hvac.SLUMBER_OFF]))
    np.testing.assert_allclose(pid.integral[0], 0.0)
    np.testing.assert_allclose(pid.output[0], 0.0)
    # heating → mixed is bumpless
    pid = hvac.PID(1, P1, dt_s=10.0)
    before = run_pid(pid, 22.0, 21.0, hvac.HEATING, 30)[-1]
    pid.reset_on_transition(np.array([hvac.HEATING]), np.array([hvac.MIXED]))
    after = run_pid(pid, 22.0, 21.0, hvac.MIXED, 1)[-1]
    assert np.all(np.abs(after - before) < 0.05 * p.q_heat_max_w)
