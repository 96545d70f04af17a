"""Replaying a coach's logged trajectories through the simulator, and the errors the fit scores.

The coach's 1-min trajectories (room temperatures y, setpoint u, disturbances d and the metered
HVAC power, :mod:`trainclimate.data.trajectory`) are replayed through the
:class:`~trainclimate.sim.simulator.FleetSimulator`: the logged T_ref drives the HVAC's own
control, the logged T_amb, irradiance, occupancy and speed are the environment
(docs/model.md, "Calibration").

Replaying a trajectory needs what the logs do not hold, chosen so:

- the logged projections Q_Gt = |G cos z| and Q_Gs = |G sin z sin(β − θ)| are reproduced by a
  sun at zenith z = atan2(Q_Gs, Q_Gt) with G = hypot(Q_Gt, Q_Gs), abeam of the train (exactly,
  but for z kept below 89.99°: a roof irradiance off by at most 2 × 10⁻⁴ of the side's);
- the lower-deck door is open for the share of a minute the train stood (the trajectories'
  ``standing``; else a mean speed below 1 km/h) during a trip (occupancy above 0) — the stops —
  and for the first and last :data:`TURNAROUND_DOOR_MIN` minutes of a standstill between trips
  (a turnaround); the doors are not logged;
- the chassis and inventory start at the logged room temperatures and the first
  :data:`WARMUP_MIN` minutes of each trajectory are not scored, so the unknown initial state
  has settled;
- the simulated sensors have the coach's noise and quantisation, one seeded draw shared by every
  parameter set: the HVAC's controller acts on noisy readings, and its clipped output turns
  that noise into extra power (without it a replay of the true parameters under-reads the
  metered energy by 13 % on the summer campaign's days).

Each simulation runs every trajectory as a column of one vectorised fleet, and a Jacobian runs
the perturbed parameter sets as further columns of the same fleet: one simulation per iteration,
not one per parameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.data.trajectory import Trajectory
from trainclimate.sim import thermal
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams
from trainclimate.sim.simulator import FleetSimulator
from trainclimate.twin.knobs import CalibrationError

#: Minutes of each trajectory the replay runs before it is scored.
WARMUP_MIN = 60
#: Minutes the doors stand open at the start and the end of a turnaround.
TURNAROUND_DOOR_MIN = 2
#: The simulator's step under the replayed minutes. [s]
STEP_S = 10.0
#: Scale of the two residuals: a deck-temperature error of this many K weighs as much as a power
#: error of ``POWER_SCALE_KW``.
TEMPERATURE_SCALE_K, POWER_SCALE_KW = 0.2, 1.0
#: The errors are scored on means over blocks of this many minutes: the switching of the HVAC's
#: logic on quantised readings makes minute values chaotic, their means not.
BLOCK_MIN = 15


@dataclass
class Replay:
    """Trajectories of one coach made ready to simulate side by side.

    ``env`` has one column per trajectory at :data:`STEP_S` (shorter ones padded with their
    last minute), ``t_ref_c`` (steps, columns) the logged setpoint held over each minute,
    ``initial_c`` (columns, 9) the initial temperatures, ``y`` (minutes, columns, 3) and
    ``p_kw`` (minutes, columns) the logged values and ``scored`` (minutes, columns) which
    minutes count.
    """

    env: Environment
    t_ref_c: np.ndarray
    initial_c: np.ndarray
    y: np.ndarray
    p_kw: np.ndarray
    scored: np.ndarray

    @property
    def per_minute(self) -> int:
        return round(60.0 / STEP_S)


def replay(trajectories: list[Trajectory]) -> Replay:
    """Make ``trajectories`` (1-min, one coach) ready to simulate (see the module docstring)."""
    if not trajectories:
        raise CalibrationError("no trajectory to replay")
    if any(t.sampling_min != 1 for t in trajectories):
        raise CalibrationError("calibration replays 1-min trajectories")
    minutes = max(len(t) for t in trajectories)
    per = round(60.0 / STEP_S)

    def padded(values: np.ndarray) -> np.ndarray:
        return np.concatenate([values, np.repeat(values[-1:], minutes - len(values), axis=0)])

    d = np.stack([padded(t.d) for t in trajectories], axis=1)  # (minutes, n, 5)
    u = np.stack([padded(t.u[:, 0]) for t in trajectories], axis=1)
    y = np.stack([padded(t.y) for t in trajectories], axis=1)
    p = np.stack([padded(t.p_kw) for t in trajectories], axis=1)
    standing = np.stack([padded(t.standing) for t in trajectories], axis=1)
    length = np.array([len(t) for t in trajectories])
    scored = (np.arange(minutes)[:, None] >= WARMUP_MIN) & (np.arange(minutes)[:, None] < length)

    def steps(values: np.ndarray) -> np.ndarray:
        return np.repeat(values, per, axis=0)

    t_amb, q_gt, q_gs, occupancy, speed = (steps(d[:, :, j]) for j in range(5))
    time = pd.date_range("2000-01-01", periods=minutes * per, freq=f"{STEP_S:g}s", tz="UTC")
    env = Environment(
        time=time,
        t_amb_c=t_amb,
        ghi_w_m2=np.hypot(q_gt, q_gs),
        # (a sun on the horizon counts as below it: kept a hair above)
        zenith_deg=np.minimum(np.degrees(np.arctan2(q_gs, q_gt)), 89.99),
        azimuth_deg=np.full_like(t_amb, 90.0),  # abeam of a train heading north
        heading_deg=np.zeros_like(t_amb),
        speed_kmh=speed,
        occupancy_pct=occupancy,
        door_open=steps(_doors(d[:, :, 4], d[:, :, 3], standing)),
        mode=np.full(t_amb.shape, MODE_REGULAR),
    )
    first = np.array([t.y[0] for t in trajectories])  # (n, 3)
    initial = np.column_stack([first, first, first])
    return Replay(env, steps(u), initial, y, p, scored & np.isfinite(y).all(axis=2))


def _doors(
    speed_kmh: np.ndarray, occupancy_pct: np.ndarray, standing_share: np.ndarray | None = None
) -> np.ndarray:
    """The share of each minute (minutes, columns) the lower-deck door is open, from the logged
    speed, occupancy and share of the minute the train stood (see the module docstring)."""
    standing = speed_kmh < 1.0
    share = standing.astype(float)
    if standing_share is not None:
        share = np.where(np.isfinite(standing_share), standing_share, share)
    doors = np.where(occupancy_pct > 0.0, share, 0.0)
    between = standing & (occupancy_pct <= 0.0)
    for j in range(between.shape[1]):
        edges = np.diff(np.concatenate([[0], between[:, j].astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            # (a standstill at a trajectory's edge is a turnaround only if a trip is on both sides)
            if a > 0 and b < len(between):
                doors[a : min(b, a + TURNAROUND_DOOR_MIN), j] = 1.0
                doors[max(a, b - TURNAROUND_DOOR_MIN) : b, j] = 1.0
    return doors


class _ReplaySimulator(FleetSimulator):
    """The fleet simulator whose sensors read the same noise in every parameter set."""

    def __init__(self, params, env, *, noise: np.ndarray, **kwargs):
        super().__init__(params, env, **kwargs)
        self.noise = noise  # (steps, columns, 3), tiled over the sets

    def measure(self) -> np.ndarray:
        noisy = self.T[:, thermal.ROOM] + self.noise[self.k] * self.p.sensor_noise_k[:, None]
        q = self.p.sensor_quantum_k[:, None]
        return np.where(q > 0, np.round(noisy / np.where(q > 0, q, 1.0)) * q, noisy)


def simulate(
    rep: Replay, params: list[CoachParams], seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Deck temperatures (minutes, columns·sets, 3) at each minute's start and mean electrical
    power (minutes, columns·sets) over each minute, in kW, of the replay under each of the
    parameter sets ``params`` (every trajectory once per set, sets after one another; the
    sensor noise drawn from ``seed``, the same for every set)."""
    sets = len(params)
    n = rep.env.n_coaches
    env = rep.env.coaches(list(range(n)) * sets)
    noise = np.random.default_rng(seed).standard_normal((len(env.time), n, 3))
    sim = _ReplaySimulator(
        [q for q in params for _ in range(n)],
        env,
        noise=np.tile(noise, (1, sets, 1)),
        initial_c=np.tile(rep.initial_c, (sets, 1)),
    )
    t_ref = np.tile(rep.t_ref_c, (1, sets))
    sim.run(lambda k, _: t_ref[k])
    result = sim.result()
    per = rep.per_minute
    y = result.states_c[::per, :, thermal.ROOM]
    p = result.total_power_w.reshape(-1, per, n * sets).mean(axis=1) / 1e3
    return y, p


def _block_means(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Means of ``values`` (minutes, columns[, k]) over the ``mask``ed minutes of each
    :data:`BLOCK_MIN`-minute block and column (NaN: none), shape (blocks, columns[, k])."""
    m = (len(mask) // BLOCK_MIN) * BLOCK_MIN
    w = mask[:m].reshape(-1, BLOCK_MIN, mask.shape[1]).astype(float)
    v = np.where(mask[:m, :, None] if values.ndim == 3 else mask[:m], values[:m], 0.0)
    v = v.reshape(-1, BLOCK_MIN, *values.shape[1:])
    count = w.sum(axis=1)
    if values.ndim == 3:
        return v.sum(axis=1) / np.where(count > 0, count, np.nan)[:, :, None]
    return v.sum(axis=1) / np.where(count > 0, count, np.nan)


def residuals(rep: Replay, y: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The scored errors of one parameter set's simulation, scaled (see the constants): of the
    :data:`BLOCK_MIN`-minute means of the deck temperatures and of the power."""
    power = rep.scored & np.isfinite(rep.p_kw)
    ey = (_block_means(y, rep.scored) - _block_means(rep.y, rep.scored)) / TEMPERATURE_SCALE_K
    ep = (_block_means(p, power) - _block_means(np.nan_to_num(rep.p_kw), power)) / POWER_SCALE_KW
    return np.concatenate([ey[np.isfinite(ey)], ep[np.isfinite(ep)]])


def residuals_of_sets(rep: Replay, params: list[CoachParams]) -> list[np.ndarray]:
    """:func:`residuals` of each of the parameter sets ``params``, simulated as one fleet."""
    y, p = simulate(rep, params)
    n = rep.env.n_coaches
    return [
        residuals(rep, y[:, i * n : (i + 1) * n], p[:, i * n : (i + 1) * n])
        for i in range(len(params))
    ]


def residual_columns(rep: Replay) -> np.ndarray:
    """The trajectory column of each entry of :func:`residuals` (the same for every parameter
    set: which blocks are scored depends on the logs only)."""
    power = rep.scored & np.isfinite(rep.p_kw)
    ey = _block_means(rep.y, rep.scored)
    ep = _block_means(np.nan_to_num(rep.p_kw), power)
    columns = np.arange(rep.y.shape[1])
    return np.concatenate(
        [
            np.broadcast_to(columns[None, :, None], ey.shape)[np.isfinite(ey)],
            np.broadcast_to(columns[None, :], ep.shape)[np.isfinite(ep)],
        ]
    )
