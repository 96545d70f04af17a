"""The coach block: heat-flow directions, thresholds, energy balance and integration accuracy."""

import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp

from trainclimate.coach.rule import MODE_OFF, MODE_REGULAR
from trainclimate.sim import hvac, thermal
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, stack
from trainclimate.sim.simulator import FleetSimulator

P1 = stack([CoachParams()])
FLOW = {name: j for j, name in enumerate(thermal.FLOW_NAMES)}


def drivers(**kw):
    base = dict(
        q_act_w=np.zeros((1, 6)),
        t_amb_c=np.array([10.0]),
        speed_kmh=np.array([0.0]),
        q_roof_w_m2=np.array([0.0]),
        q_side_w_m2=np.array([0.0]),
        passengers=np.zeros((1, 3)),
        door_open=np.array([0.0]),
        fresh_air_kg_s=np.zeros((1, 3)),
    )
    base.update({k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in kw.items()})
    for k in ("q_act_w", "passengers", "fresh_air_kg_s"):
        base[k] = base[k].reshape(1, -1)
    return thermal.Drivers(**base)


def flows(T=20.0, **kw):
    return thermal.heat_flows(np.full((1, 9), T, dtype=float), drivers(**kw), P1)[0]


def test_uniform_temperatures_exchange_no_heat_internally():
    f = flows(T=20.0, t_amb_c=20.0)
    np.testing.assert_allclose(f[: thermal.N_INTERNAL], 0.0)


def test_heat_flows_from_warm_to_cold():
    T = np.full((1, 9), 20.0)
    T[0, 0] = 25.0  # upper deck warmer
    f = thermal.heat_flows(T, drivers(t_amb_c=20.0), P1)[0]
    assert f[FLOW["conv_room_up_mid"]] < 0  # mid receives from up: flow into up is negative
    assert f[FLOW["conv_room_inv_up"]] < 0
    dT = thermal.derivative(T, drivers(t_amb_c=20.0), P1, 1 / thermal.capacities(P1))[0]
    assert dT[0] < 0 and dT[1] > 0 and dT[3] > 0 and dT[6] > 0


def test_outer_convection_grows_with_speed():
    h = thermal.h_ext_w_m2_k(np.array([0.0, 18.0, 36.0, 100.0, 160.0]))
    assert h[0] == pytest.approx(5.7)
    assert np.all(np.diff(h) > 0)
    # the two branches of McAdams' correlation nearly meet at 5 m/s
    assert abs(5.7 + 3.8 * 5 - 7.2 * 5**0.78) < 1.0
    slow = flows(T=20.0, t_amb_c=0.0, speed_kmh=0.0)[FLOW["conv_env_chassis_up"]]
    fast = flows(T=20.0, t_amb_c=0.0, speed_kmh=120.0)[FLOW["conv_env_chassis_up"]]
    assert fast < slow < 0


def test_ground_radiation_only_above_20_degrees():
    assert flows(T=20.0, t_amb_c=19.9)[FLOW["ground_radiation"]] == 0.0
    hot = flows(T=30.0, t_amb_c=32.0)[FLOW["ground_radiation"]]
    # T_G = 44 °C against a 30 °C underframe: ε σ A (T_G⁴ − T⁴) ≈ 2.6 kW
    expected = 0.85 * 5.670374419e-8 * 35.0 * ((44 + 273.15) ** 4 - (30 + 273.15) ** 4)
    assert hot == pytest.approx(expected)
    assert thermal.ground_temperature_c(np.array([32.0]), CoachParams())[0] == 44.0


def test_door_effect_only_when_open_and_on_the_lower_deck():
    closed = flows(T=20.0, t_amb_c=0.0, door_open=0.0)
    opened = flows(T=20.0, t_amb_c=0.0, door_open=1.0)
    assert closed[FLOW["door"]] == 0.0
    assert opened[FLOW["door"]] == pytest.approx(-0.25 * 1005 * 20)
    assert dict(thermal.EXTERNAL_FLOWS)["door"] == 2  # T_room,low


def test_passengers_and_solar_enter_their_decks():
    f = flows(T=20.0, t_amb_c=20.0, passengers=[10, 0, 5], q_side_w_m2=300.0, q_roof_w_m2=500.0)
    assert f[FLOW["occupancy_up"]] == 1000.0 and f[FLOW["occupancy_low"]] == 500.0
    assert f[FLOW["solar_window_up"]] == pytest.approx(0.40 * 5.5 * 300.0)
    assert f[FLOW["solar_roof"]] == pytest.approx(0.6 * 35.0 * 500.0)
    assert f[FLOW["solar_side_chassis_low"]] == pytest.approx(0.45 * 17.3 * 300.0)


def synthetic_env(hours=24.0, dt=10.0):
    """A day with everything moving: weather, sun, speed, doors, passengers, modes."""
    t = pd.date_range("2022-03-28 03:00", periods=int(hours * 3600 / dt), freq=f"{dt:g}s", tz="UTC")
    h = np.arange(len(t)) * dt / 3600.0
    day = np.clip(np.sin((h - 3) / 24 * 2 * np.pi), 0, None)
    mode = np.where((h > 1) & (h < 21), MODE_REGULAR, MODE_OFF)
    trip = (h * 60) % 12  # a stop every 12 minutes
    speed = np.where((mode == MODE_REGULAR) & (trip > 1.0), 100.0 * np.minimum(trip - 1, 1), 0.0)
    door = ((mode == MODE_REGULAR) & (trip > 0.2) & (trip < 0.8)).astype(float)
    col = lambda x: np.asarray(x, dtype=float)[:, None]  # noqa: E731
    return Environment(
        time=t,
        t_amb_c=col(2 + 12 * day),
        ghi_w_m2=col(700 * day),
        zenith_deg=col(90 - 50 * day),
        azimuth_deg=col(90 + 180 * h / 24),
        heading_deg=col(np.where((h * 60) % 24 < 12, 30.0, 210.0)),
        speed_kmh=col(speed),
        occupancy_pct=col(np.where(mode == MODE_REGULAR, 40 + 30 * day, 0)),
        door_open=col(door),
        mode=col(mode).astype(int),
    )


def step_drivers(result, ps, k):
    """The drivers the simulator held during step(s) ``k`` (an int or a slice)."""
    env = result.env
    q_in = np.concatenate([result.q_hvac_w[k], result.q_fw_w[k]], axis=-1).reshape(-1, 6)
    return thermal.Drivers(
        q_act_w=np.einsum("nij,nj->ni", ps.distribution, q_in),
        t_amb_c=env.t_amb_c[k].ravel(),
        speed_kmh=env.speed_kmh[k].ravel(),
        q_roof_w_m2=env.q_roof_w_m2[k].ravel(),
        q_side_w_m2=env.q_side_w_m2[k].ravel(),
        passengers=env.occupancy_pct[k].reshape(-1, 1) / 100 * ps.seats,
        door_open=env.door_open[k].ravel(),
        fresh_air_kg_s=hvac.fresh_air_mass_flow(result.fresh_fraction[k].ravel(), ps),
    )


def reference_states(result, p: CoachParams, rhs_per_step):
    """Integrate the coach block step by step with scipy's DOP853 at tight tolerance, holding
    each step's inputs, starting from the simulator's initial state."""
    x = result.states_c[0, 0].copy()
    out = np.empty_like(result.states_c[:, 0])
    for k in range(len(result.time)):
        out[k] = x
        sol = solve_ivp(
            rhs_per_step(k), (0.0, result.dt_s), x, method="DOP853", rtol=1e-10, atol=1e-10
        )
        x = sol.y[:, -1]
    return out, x


def nonlinear_rhs(result, p):
    ps = stack([p])
    inv_cap = 1 / thermal.capacities(ps)

    def rhs_for_step(k):
        drv = step_drivers(result, ps, slice(k, k + 1))
        return lambda _t, y: thermal.derivative(y[None, :], drv, ps, inv_cap)[0]

    return rhs_for_step


def affine_rhs(result, p):
    """Without ground radiation (T_amb < 20 °C) the coach block is affine in T for held inputs:
    dT/dt = A_k T + b_k. Extract A_k, b_k for every step at once from the model itself (checking
    affinity), so the tight reference integration of a whole day stays fast."""
    s = len(result.time)
    ps = stack([p] * s)
    drv = step_drivers(result, ps, slice(0, s))
    inv_cap = 1 / thermal.capacities(ps)
    b = thermal.derivative(np.zeros((s, 9)), drv, ps, inv_cap)
    A = np.stack(
        [thermal.derivative(np.tile(np.eye(9)[i], (s, 1)), drv, ps, inv_cap) - b for i in range(9)],
        axis=2,
    )
    T = np.random.default_rng(0).uniform(-10, 40, size=(s, 9))
    np.testing.assert_allclose(
        thermal.derivative(T, drv, ps, inv_cap),
        np.einsum("sij,sj->si", A, T) + b,
        rtol=1e-9,
        atol=1e-12,
    )
    return lambda k: lambda _t, y, a=A[k], c=b[k]: a @ y + c


@pytest.mark.slow
def test_rk4_matches_a_tight_reference_integration_over_a_day():
    p = CoachParams()
    sim = FleetSimulator(p, synthetic_env(), seed=1)
    sim.run()
    result = sim.result()
    assert result.env.t_amb_c.max() < p.ground_threshold_c
    ref, ref_final = reference_states(result, p, affine_rhs(result, p))
    assert np.abs(result.states_c[:, 0] - ref).max() < 0.05
    assert np.abs(result.final_states_c[0] - ref_final).max() < 0.05
    # the day really exercised the model: a big swing, heating and doors
    assert np.ptp(result.t_room_c[:, 0]) > 5.0
    assert result.total_power_w.max() > 5e3


def test_rk4_matches_the_reference_with_ground_radiation():
    env = synthetic_env(hours=2.0)
    env.t_amb_c = env.t_amb_c + 25.0  # a hot afternoon: ground radiation active, cooling
    p = CoachParams()
    sim = FleetSimulator(p, env, seed=1)
    sim.run()
    result = sim.result()
    assert result.env.t_amb_c.min() > p.ground_threshold_c
    ref, _ = reference_states(result, p, nonlinear_rhs(result, p))
    assert np.abs(result.states_c[:, 0] - ref).max() < 0.05


def test_energy_balance_closes():
    env = synthetic_env(hours=8.0)
    sim = FleetSimulator(CoachParams(), env, seed=2, record_flows=True)
    sim.run()
    r = sim.result()
    cap = thermal.capacities(sim.p)[0]
    stored_j = float(cap @ (r.final_states_c[0] - r.states_c[0, 0]))
    external = r.flows_w[:, 0, thermal.N_INTERNAL :]
    net_j = float(external.sum() * r.dt_s)
    gross_j = float(np.abs(external).sum() * r.dt_s)
    assert abs(stored_j - net_j) <= 1e-3 * abs(stored_j)
    assert abs(stored_j - net_j) <= 1e-3 * gross_j
    # and per step: C · ΔT equals dt × the net external flow of that step
    per_step = np.diff(r.states_c[:, 0], axis=0) @ cap
    np.testing.assert_allclose(per_step, external[:-1].sum(axis=1) * r.dt_s, rtol=1e-6, atol=1e-3)
