"""The training data of the tests' small Transient Predictor (the session fixture
``small_predictor`` of tests/conftest.py) and the controller's 5-min sampling of a simulation.

:func:`trajectories` simulates coaches for a small Transient Predictor at the controller's setting
(5 min, ρ = 12, T = 6), fitted in ≈ 1.5–3 s: two in-service coaches of
``winter-day`` and the four parked scenarios, each on a re-seeded day (other weather than the
scenarios the closed-loop tests run), 12 h each, T_ref = T_rule plus a driver's random offset
(piecewise constant in ±2 K for 15–75 min) for excitation. The measured disturbances get a
sensor's noise (0.2 K on T_amb, 5 % on the irradiance): fitted on the simulator's perfectly smooth
disturbances, Ĥ has d-coefficients of ~100 that cancel on smooth inputs and blow up at any kink in a
forecast (measured: the closed loop's T_ref jumped by 0.5 K when the forecast went flat at the end
of a run); with the noise they are ~0.1 and the closed loop is calm. In-sample MAE ≈ 0.09 K per
step (mostly the sensors' noise).
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.simulator import FleetSimulator

RHO, HORIZON, SAMPLING_MIN = 12, 6, 5
TICK_S = 300.0
TRAINING_SCENARIOS = (
    "winter-day",
    "winter-day",
    "parked-heating-nov",
    "parked-cooling-oct",
    "parked-cooling-aug-energy",
    "parked-cooling-aug-conservative",
)
TRAINING_HOURS = 12.0


def tick_samples(result, tick_s: float = TICK_S) -> SimpleNamespace:
    """5-min samples of a simulation by the controller's convention: ``y[k]`` the mean sensor
    reading in the minute before tick k (NaN at tick 0), ``u[k]``, ``d[k]`` the means over
    [tick k, tick k+1), ``states[k]`` the true nine temperatures at tick k, ``regular[k]`` whether
    the whole interval ran in regular mode; leading axes (ticks, coaches)."""
    env = result.env
    spt = round(tick_s / result.dt_s)
    ticks = len(result.time) // spt
    n = env.n_coaches

    def means(a):
        a = np.asarray(a)[: ticks * spt]
        return a.reshape(ticks, spt, *a.shape[1:]).mean(axis=1)

    s = len(result.time)
    d = np.stack(
        [
            means(env.t_amb_c[:s]),
            means(env.q_roof_w_m2[:s]),
            means(env.q_side_w_m2[:s]),
            means(env.occupancy_pct[:s]),
            means(env.speed_kmh[:s]),
        ],
        axis=-1,
    )
    minute = round(60.0 / result.dt_s)
    y = np.full((ticks, n, 3), np.nan)
    for k in range(1, ticks):
        y[k] = result.t_room_meas_c[k * spt - minute : k * spt].mean(axis=0)
    mode = np.asarray(env.mode[: ticks * spt]).reshape(ticks, spt, n)
    return SimpleNamespace(
        y=y,
        u=means(result.t_ref_c),
        d=d,
        states=result.states_c[: ticks * spt : spt],
        regular=np.all(mode == MODE_REGULAR, axis=1),
        time_s=np.array([t.timestamp() for t in result.time[: ticks * spt : spt]]),
    )


def trajectories(seed: int = 1) -> list[SimpleNamespace]:
    """5-min trajectories (regular-mode runs of ≥ ρ + T samples) of the training simulation."""
    envs, params = [], []
    for i, name in enumerate(TRAINING_SCENARIOS):
        base = scenarios.get(name)
        scenario = dataclasses.replace(base, seed=base.seed + 1000 + i)
        env, p = scenarios.build(scenario, hours=TRAINING_HOURS)
        envs.append(env)
        params += p
    env = Environment.side_by_side(envs)
    rng = np.random.default_rng(seed)
    steps, n = len(env.time), env.n_coaches
    offset = np.zeros((steps, n))
    for c in range(n):
        k = 0
        while k < steps:
            length = int(rng.integers(90, 450))  # 15 … 75 min of 10-s steps
            offset[k : k + length, c] = rng.uniform(-2.0, 2.0)
            k += length
    sim = FleetSimulator(params, env, seed=seed)
    sim.run(lambda k, s: s.t_rule(k) + offset[k])
    samples = tick_samples(sim.result())
    d = samples.d.copy()
    d[..., 0] += rng.normal(0.0, 0.2, d[..., 0].shape)
    d[..., 1:3] = np.maximum(d[..., 1:3] * (1.0 + rng.normal(0.0, 0.05, d[..., 1:3].shape)), 0.0)
    ok = samples.regular.copy()
    ok[0] = False  # no y at tick 0
    out = []
    for c in range(n):
        k = 0
        while k < len(ok):
            if not ok[k, c]:
                k += 1
                continue
            j = k
            while j < len(ok) and ok[j, c]:
                j += 1
            if j - k >= RHO + HORIZON:
                out.append(
                    SimpleNamespace(
                        y=samples.y[k:j, c],
                        u=samples.u[k:j, c, None],
                        d=d[k:j, c],
                        sampling_min=SAMPLING_MIN,
                    )
                )
            k = j
    return out
