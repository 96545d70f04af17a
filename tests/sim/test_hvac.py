import numpy as np
import pytest

from trainclimate.coach.rule import MODE_OFF, MODE_REGULAR, MODE_SLUMBER
from trainclimate.coach.states import (
    COOLING,
    HEATING,
    MIXED,
    OFF,
    PRECOOLING,
    PREHEATING,
    SLUMBER_COOLING,
    SLUMBER_HEATING,
    SLUMBER_OFF,
    SLUMBER_VENTILATION,
)
from trainclimate.sim import hvac
from trainclimate.sim.params import CoachParams, stack

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
    assert state_after(OFF, MODE_REGULAR, 14.0, 22.0, 0.0) == PREHEATING
    assert state_after(PREHEATING, MODE_REGULAR, 20.5, 22.0, 0.0) == PREHEATING
    assert state_after(HEATING, MODE_REGULAR, 20.5, 22.0, 0.0) == HEATING
    assert state_after(PREHEATING, MODE_REGULAR, 21.2, 22.0, 0.0) == HEATING
    assert state_after(OFF, MODE_REGULAR, 30.0, 22.0, 30.0) == PRECOOLING
    assert state_after(PRECOOLING, MODE_REGULAR, 23.5, 22.0, 30.0) == PRECOOLING
    assert state_after(PRECOOLING, MODE_REGULAR, 22.8, 22.0, 30.0) == COOLING


def test_heating_mixed_cooling_switch_on_ambient_with_hysteresis():
    # T_ref 22: heating below 14 °C outside, cooling above 20 °C, 1 K hysteresis
    assert state_after(OFF, MODE_REGULAR, 22, 22, 13.5) == HEATING
    assert state_after(HEATING, MODE_REGULAR, 22, 22, 14.5) == HEATING
    assert state_after(HEATING, MODE_REGULAR, 22, 22, 15.5) == MIXED
    assert state_after(MIXED, MODE_REGULAR, 22, 22, 13.5) == MIXED
    assert state_after(MIXED, MODE_REGULAR, 22, 22, 12.9) == HEATING
    assert state_after(MIXED, MODE_REGULAR, 22, 22, 20.5) == MIXED
    assert state_after(MIXED, MODE_REGULAR, 22, 22, 21.1) == COOLING
    assert state_after(COOLING, MODE_REGULAR, 22, 22, 19.5) == COOLING
    assert state_after(COOLING, MODE_REGULAR, 22, 22, 18.9) == MIXED
    assert state_after(HEATING, MODE_REGULAR, 22, 22, 25.0) == COOLING


def test_slumber_states():
    assert state_after(OFF, MODE_SLUMBER, 16.5, 22, 0) == SLUMBER_HEATING
    assert state_after(SLUMBER_HEATING, MODE_SLUMBER, 17.5, 22, 0) == SLUMBER_HEATING
    assert state_after(SLUMBER_HEATING, MODE_SLUMBER, 18.1, 22, 0) == SLUMBER_OFF
    assert state_after(SLUMBER_OFF, MODE_SLUMBER, 17.5, 22, 0) == SLUMBER_OFF
    assert state_after(SLUMBER_OFF, MODE_SLUMBER, 25.0, 22, 15) == SLUMBER_VENTILATION
    assert state_after(SLUMBER_VENTILATION, MODE_SLUMBER, 27.5, 22, 15) == (SLUMBER_COOLING)
    assert state_after(SLUMBER_OFF, MODE_SLUMBER, 27.5, 22, 30) == SLUMBER_COOLING
    assert state_after(SLUMBER_COOLING, MODE_SLUMBER, 26.5, 22, 30) == SLUMBER_COOLING
    assert state_after(SLUMBER_COOLING, MODE_SLUMBER, 25.9, 22, 30) == SLUMBER_OFF
    assert state_after(HEATING, MODE_OFF, 10, 22, 0) == OFF


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
    assert fresh(HEATING, 22, 22, 0) == (pytest.approx(base), hvac.RECIRCULATED)
    f, label = fresh(HEATING, 22, 22, 0, passengers=45)
    assert f == pytest.approx(base + 45 * 20 / 3600)
    assert label == hvac.RECIRCULATED
    # preheating an empty coach: pure recirculation; with passengers their minimum
    assert fresh(PREHEATING, 15, 22, 0)[0] == 0.0
    assert fresh(PREHEATING, 15, 22, 0, passengers=36)[0] == pytest.approx(0.2)
    # more passengers never means less fresh air
    fs = [fresh(COOLING, 22, 22, 30, passengers=n)[0] for n in (0, 10, 50, 100, 200)]
    assert fs == sorted(fs) and fs[-1] == 1.0


def test_economiser_substates():
    assert fresh(COOLING, 23, 22, 10) == (1.0, hvac.OUTSIDE)
    f, label = fresh(COOLING, 21.7, 22, 10)
    assert 0.15 < f < 1.0 and label == hvac.MIXED_AIR
    assert fresh(COOLING, 23, 22, 30)[1] == hvac.RECIRCULATED
    assert fresh(OFF, 23, 22, 10) == (0.0, hvac.RECIRCULATED)
    assert fresh(SLUMBER_VENTILATION, 25, 22, 15) == (1.0, hvac.OUTSIDE)


def test_mixed_state_economiser_opens_only_above_the_setpoint():
    """Continuous at T_ref: no free cooling while the coach is at or below its setpoint (the
    heaters may still run in the mixed state); fully open 1 K above it."""
    f_min = fresh(HEATING, 21.0, 22, 15)[0]
    assert fresh(MIXED, 22.0, 22, 15)[0] == pytest.approx(f_min)
    assert fresh(MIXED, 22.01, 22, 15)[0] == pytest.approx(f_min + 0.01 * (1 - f_min))
    assert fresh(MIXED, 22.5, 22, 15)[0] == pytest.approx(f_min + 0.5 * (1 - f_min))
    assert fresh(MIXED, 23.0, 22, 15) == (pytest.approx(1.0), hvac.OUTSIDE)
    # no economiser when outside is not cooler than the coach by the band
    assert fresh(MIXED, 22.5, 22, 22)[0] == pytest.approx(f_min)


def test_floor_wall_heating_only_in_preheating_and_heating():
    q_max = CoachParams().q_fw_max_w
    states = np.array(
        [
            PREHEATING,
            HEATING,
            HEATING,
            HEATING,
            MIXED,
            COOLING,
            SLUMBER_HEATING,
            OFF,
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
    out = run_pid(pid, 22.0, 15.0, HEATING, 60)
    assert np.all(np.diff(out, axis=0) <= p.pid_rate_w_s * 10.0 + 1e-9)
    np.testing.assert_allclose(out[-1], p.q_heat_max_w)
    assert np.all(out >= 0)
    pid = hvac.PID(1, P1, dt_s=10.0)
    out = run_pid(pid, 22.0, 30.0, COOLING, 60)
    np.testing.assert_allclose(out[-1], -p.q_cool_max_w)
    assert np.all(out <= 0)


def test_pid_anti_windup_recovers_at_once():
    p = CoachParams()
    pid = hvac.PID(1, P1, dt_s=10.0)
    run_pid(pid, 22.0, 15.0, HEATING, 2000)  # 5.5 h saturated at full heat
    assert np.all(pid.integral <= p.q_heat_max_w + 1e-9)
    # the error reverses: without anti-windup the integral (~10⁷ W) would hold full heat for
    # hours; with it the output leaves saturation within a minute
    out = run_pid(pid, 22.0, 22.6, HEATING, 6)
    assert np.all(out[-1] < 0.9 * p.q_heat_max_w)


def test_pid_resets_on_state_transitions():
    p = CoachParams()
    pid = hvac.PID(1, P1, dt_s=10.0)
    run_pid(pid, 22.0, 22.5, HEATING, 10)
    pid.reset_on_transition(np.array([HEATING]), np.array([PREHEATING]))
    np.testing.assert_allclose(pid.integral[0], p.q_heat_max_w)
    pid.reset_on_transition(np.array([PREHEATING]), np.array([SLUMBER_OFF]))
    np.testing.assert_allclose(pid.integral[0], 0.0)
    np.testing.assert_allclose(pid.output[0], 0.0)
    # heating → mixed is bumpless
    pid = hvac.PID(1, P1, dt_s=10.0)
    before = run_pid(pid, 22.0, 21.0, HEATING, 30)[-1]
    pid.reset_on_transition(np.array([HEATING]), np.array([MIXED]))
    after = run_pid(pid, 22.0, 21.0, MIXED, 1)[-1]
    assert np.all(np.abs(after - before) < 0.05 * p.q_heat_max_w)


def room_state(prev, decks, t_ref, t_amb, demand, p=P1):
    """:func:`hvac.next_state` in regular mode with deck temperatures and the decks' demand."""
    return int(
        hvac.next_state(
            np.array([prev]),
            np.array([MODE_REGULAR]),
            np.array([decks], float),
            np.array([float(t_ref)]),
            np.array([float(t_amb)]),
            p,
            demand_w=np.array([demand], float),
        )[0]
    )


def test_between_the_thresholds_the_room_chooses_the_state():
    """T_ref 22, T_amb 17 (between 14 and 20 °C): the decks' demand and the mean decide."""
    warm = [22.1, 22.0, 21.9]
    # from mixed: cooling once no deck heats and one cools; heating likewise; else mixed
    assert room_state(MIXED, warm, 22, 17, [-900, -200, 0]) == COOLING
    assert room_state(MIXED, warm, 22, 17, [300, 100, 500]) == HEATING
    assert room_state(MIXED, warm, 22, 17, [-900, -200, 400]) == MIXED
    assert room_state(MIXED, warm, 22, 17, [0, 0, 0]) == MIXED
    # … but not with the coach's mean more than half the band (0.25 K) on the wrong side
    assert room_state(MIXED, [21.8, 21.7, 21.6], 22, 17, [-900, -200, 0]) == MIXED
    # cooling holds, whatever the demand, until the mean is 0.5 K below T_ref
    assert room_state(COOLING, [21.9, 21.6, 21.2], 22, 17, [0, 0, 0]) == COOLING
    assert room_state(COOLING, [21.6, 21.4, 21.3], 22, 17, [0, 0, 0]) == MIXED
    assert room_state(HEATING, [22.6, 22.5, 22.5], 22, 17, [0, 0, 0]) == MIXED
    # one deck alone far off does not move the coach (the unit acts on the mean)
    assert room_state(COOLING, [22.2, 22.0, 21.0], 22, 17, [-500, 0, 0]) == COOLING
    # outside the thresholds T_amb decides as before
    assert room_state(MIXED, warm, 22, 12.5, [-900, -900, -900]) == HEATING
    assert room_state(MIXED, warm, 22, 21.5, [900, 900, 900]) == COOLING
    # climate_from_room 0: always mixed between the thresholds (the earlier model)
    ambient = stack([CoachParams(climate_from_room=0.0)])
    assert room_state(MIXED, warm, 22, 17, [-900, -200, 0], ambient) == MIXED
    assert room_state(COOLING, warm, 22, 17, [-900, -200, 0], ambient) == MIXED


def test_the_demand_is_the_output_averaged_over_the_integral_time():
    p = CoachParams()
    pid = hvac.PID(1, P1, dt_s=10.0)
    out = run_pid(pid, 22.0, 30.0, COOLING, 60)  # 10 min at full cooling
    assert np.all(pid.demand < 0) and np.all(pid.demand > out[-1])
    # it lags the output by the integral time and then follows it: after 10 time constants of
    # full cooling it is the output
    run_pid(pid, 22.0, 30.0, COOLING, int(10 * p.pid_ti_s[0] / 10.0))
    np.testing.assert_allclose(pid.demand, pid.output, rtol=1e-3)


def test_a_deck_s_cooling_may_not_restart_within_its_minimum_off_time():
    p1 = stack([CoachParams(cooling_min_off_s=120.0)])
    pid = hvac.PID(1, p1, dt_s=10.0)
    run_pid(pid, 22.0, 23.0, MIXED, 30)  # cooling
    assert np.all(pid.output < 0)
    off = run_pid(pid, 22.0, 20.0, MIXED, 3)  # too cold: the cooling stops, heat comes
    assert np.all(off[-1] >= 0)
    # too warm again: cooling is locked for 120 s after it stopped, then runs
    again = run_pid(pid, 22.0, 24.0, MIXED, 14)
    stopped_at = np.argmax(off[:, 0] >= 0)  # the step (of `off`) where it stopped
    locked_steps = 12 - (len(off) - stopped_at)
    assert np.all(again[:locked_steps] >= 0)
    assert np.all(again[-1] < 0)
    # without the limit it would have cooled at once
    free = hvac.PID(1, P1, dt_s=10.0)
    run_pid(free, 22.0, 23.0, MIXED, 30)
    run_pid(free, 22.0, 20.0, MIXED, 3)
    assert np.all(run_pid(free, 22.0, 24.0, MIXED, 2)[-1] < 0)


def test_a_snapshot_from_before_the_demand_and_the_off_timer_restores():
    """The demo keeps its simulator's snapshot in the database: one written before the PIDs
    had a demand and a cooling off-timer continues, those starting from their initial values."""
    from trainclimate.sim import scenarios
    from trainclimate.sim.simulator import FleetSimulator

    env, params = scenarios.build(scenarios.get("parked-heating-nov"), n_coaches=2, hours=0.5)
    sim = FleetSimulator(params, env, seed=1)
    sim.run(steps=30)
    old = sim.snapshot()
    for name in ("demand", "cooling_off_s"):
        del old["pid"][name]
    again = FleetSimulator(params, env, seed=1)
    again.restore(old)
    np.testing.assert_array_equal(again.pid.integral, sim.pid.integral)
    np.testing.assert_array_equal(again.pid.demand, np.zeros((2, 3)))
    again.k = sim.k
    again.run(steps=10)  # it steps on
    assert np.isfinite(again.T).all()
