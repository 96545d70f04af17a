"""Fitting the simulator to one real coach: a twin from its logged trajectories.

The coach's 1-min trajectories (room temperatures y, setpoint u, disturbances d and the metered
HVAC power, :mod:`trainclimate.data.trajectory`) are replayed through the
:class:`~trainclimate.sim.simulator.FleetSimulator`: the logged T_ref drives the HVAC's own
control, the logged T_amb, irradiance, occupancy and speed are the environment. The parameters of
:data:`CALIBRATED` are then chosen to minimise the simulation error — deck temperatures and
electrical power together — with scipy's bounded ``least_squares`` from several starts, on the
coach's training days, and the twin is judged on held-out days (docs/model.md, "Calibration").

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

import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import least_squares
from scipy.stats import qmc

from trainclimate.data.trajectory import Trajectory
from trainclimate.sim import thermal
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams
from trainclimate.sim.rule import MODE_REGULAR
from trainclimate.sim.simulator import FleetSimulator


class CalibrationError(ValueError):
    """The data cannot calibrate the parameters asked for: too little, or not informative."""


@dataclass(frozen=True)
class Knob:
    """A calibrated quantity: its ``bounds``, its nominal value and the unit of ``value``."""

    bounds: tuple[float, float]
    unit: str
    description: str


#: The parameters :func:`calibrate` can fit, each a scale on default fields or a field itself.
CALIBRATED = {
    "envelope_scale": Knob(
        (0.3, 3.0),
        "–",
        "the envelope's U·A: deck air to outer chassis and outer chassis to outside air "
        "(the outer entries of ua_room_chassis_w_k and area_ext_m2 ×)",
    ),
    "capacity_scale": Knob(
        (0.3, 3.0), "–", "every thermal capacity: room air, inventory, chassis (c_*_j_k ×)"
    ),
    "solar_scale": Knob(
        (0.0, 3.0), "–", "solar aperture: roof and side absorptance, window g-value (×)"
    ),
    "cop_level": Knob((0.3, 3.0), "–", "the compressor's COP at every temperature (cop_* ×)"),
    "fan_supply_w": Knob((100.0, 5000.0), "W", "supply fans' power while the unit runs"),
    "fresh_air_base_fraction": Knob((0.02, 0.6), "–", "base fresh-air share of the supply air"),
}
#: The default subset: every knob, identifiable together from winter and summer days.
DEFAULT_PARAMS = tuple(CALIBRATED)
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
#: Scored training minutes needed at least, and the share of days held out.
MIN_TRAIN_MINUTES, HOLDOUT_SHARE = 12 * 60, 0.25
#: Relative step of the Jacobian's finite differences: wide enough to step over the small
#: discontinuities of the HVAC's switching logic, which make the error piecewise smooth.
JACOBIAN_STEP = 0.02
#: Two starts' fits within RIVAL_COST of each other's cost whose parameters differ by more than
#: RIVAL_SPREAD (relative) are rivals: the data do not single out one answer.
RIVAL_COST, RIVAL_SPREAD = 0.05, 0.10
#: Points of the Latin hypercube screened for the starts of the fit.
SCREENED = 16
#: Most simulations one start of the fit may run (each iteration: one, plus one for its Jacobian).
MAX_EVALUATIONS = 100
#: A fit is refused when a parameter's standard error exceeds this share of its value, or two
#: parameters' estimates are correlated beyond this (the data cannot tell them apart).
MAX_RELATIVE_STD, MAX_CORRELATION = 0.5, 0.95


#: The entries of ``ua_room_chassis_w_k`` (deck rows, chassis columns) through the outer
#: envelope: the upper deck to the upper chassis, the middle deck to the upper and lower
#: chassis, the lower deck to the lower chassis (not the middle floor's interior film).
_OUTER = np.array([[True, False, False], [True, False, True], [False, False, True]])


def apply(base: CoachParams, values: dict[str, float]) -> CoachParams:
    """``base`` with the calibrated quantities ``values`` (name → value, :data:`CALIBRATED`)."""
    changes: dict[str, object] = {}
    for name, v in values.items():
        if name == "envelope_scale":
            changes["area_ext_m2"] = base.area_ext_m2 * v
            changes["ua_room_chassis_w_k"] = np.where(_OUTER, v, 1.0) * base.ua_room_chassis_w_k
        elif name == "capacity_scale":
            for field in ("c_room_j_k", "c_inv_j_k", "c_chassis_j_k"):
                changes[field] = getattr(base, field) * v
        elif name == "solar_scale":
            for field in ("roof_absorptance", "side_absorptance", "window_g"):
                changes[field] = getattr(base, field) * v
        elif name == "cop_level":
            for field in ("cop_a", "cop_b", "cop_min", "cop_max", "cop_carnot_efficiency"):
                changes[field] = getattr(base, field) * v
        elif name in ("fan_supply_w", "fresh_air_base_fraction"):
            changes[name] = float(v)
        else:
            raise CalibrationError(f"unknown calibration parameter {name!r}")
    return dataclasses.replace(base, **changes)


def nominal(base: CoachParams, name: str) -> float:
    """The value of calibrated quantity ``name`` in ``base`` (scales: 1)."""
    return (
        float(getattr(base, name)) if name in ("fan_supply_w", "fresh_air_base_fraction") else 1.0
    )


# --- replay -----------------------------------------------------------------------------------
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


def errors(rep: Replay, y: np.ndarray, p: np.ndarray) -> dict[str, float]:
    """The twin's errors on the scored minutes: deck temperature MAE (K), power MAE (kW) and
    the metered energy's relative error (%; minutes with a metered power only)."""
    power = rep.scored & np.isfinite(rep.p_kw)
    logged = rep.p_kw[power].sum()
    return {
        "t_room_mae_c": float(np.abs(y - rep.y)[rep.scored].mean()),
        "power_mae_kw": float(np.abs(p - rep.p_kw)[power].mean()),
        "energy_error_pct": float(100.0 * (p[power].sum() - logged) / logged),
        "minutes": int(rep.scored.sum()),
    }


# --- fitting ----------------------------------------------------------------------------------
def split_days(trajectories: list[Trajectory]) -> tuple[list[Trajectory], list[Trajectory]]:
    """Training and held-out trajectories, by the local date a trajectory starts on: of the
    coach's days in order, every ``round(1 / HOLDOUT_SHARE)``-th is held out (the 4th, 8th, …;
    interleaved, so that every season a coach was logged in is in both parts), at least one."""
    days = sorted({t.time[0].tz_convert("Europe/Zurich").date() for t in trajectories})
    if len(days) < 2:
        raise CalibrationError(
            f"calibration needs trajectories on at least 2 days (training and held out); "
            f"got {len(days)}"
        )
    every = round(1 / HOLDOUT_SHARE)
    held = set(days[every - 1 :: every]) or {days[-1]}
    train = [t for t in trajectories if t.time[0].tz_convert("Europe/Zurich").date() not in held]
    holdout = [t for t in trajectories if t.time[0].tz_convert("Europe/Zurich").date() in held]
    return train, holdout


@dataclass
class Calibration:
    """One coach's fit: the parameters, the values fitted with their standard errors, and the
    twin's errors on the training and held-out days."""

    coach: str
    params: CoachParams
    fitted: dict[str, dict[str, float]]
    train: dict[str, float]
    holdout: dict[str, float]
    starts: int

    def to_dict(self) -> dict:
        """The ``calibrate --json`` object of the coach."""
        return {
            "coach": self.coach,
            "params": self.params.to_dict(),
            "fitted": self.fitted,
            "train": self.train,
            "holdout": self.holdout,
            "starts": self.starts,
        }


def calibrate(
    coach: str,
    trajectories: list[Trajectory],
    names: tuple[str, ...] = DEFAULT_PARAMS,
    base: CoachParams | None = None,
    starts: int = 3,
    seed: int = 0,
) -> Calibration:
    """Fit ``names`` (:data:`CALIBRATED`) of ``base`` (default :class:`CoachParams`) to one
    coach's 1-min trajectories by simulation-error minimisation.

    Bounded ``scipy.optimize.least_squares`` (trust-region reflective) from the ``starts``
    best of the nominal values and :data:`SCREENED` points of a Latin hypercube over the bounds
    (``seed``), all screened in one simulation; the best fit is kept, unless another start ends
    in an about as good fit elsewhere (:data:`RIVAL_COST`, :data:`RIVAL_SPREAD`).
    Standard errors come from the Jacobian at the optimum, σ = sqrt(diag((JᵀJ)⁻¹) · SSR / (m −
    k)), scaled back to each parameter's unit.

    Raises
    ------
    CalibrationError
        On an unknown parameter name, too few days or training minutes, training days without
        any metered power, or a fit that the data do not determine (a parameter's standard
        error above :data:`MAX_RELATIVE_STD` of its value, two parameters correlated beyond
        :data:`MAX_CORRELATION`, or rival fits): a refusal, not a wild fit.
    """
    base = base or CoachParams()
    unknown = [n for n in names if n not in CALIBRATED]
    if unknown:
        raise CalibrationError(
            f"unknown calibration parameter {unknown[0]!r}; choose from {', '.join(CALIBRATED)}"
        )
    if not names:
        raise CalibrationError("no parameter to calibrate")
    train, holdout = split_days(trajectories)
    rep = replay(train)
    scored = int(rep.scored.sum())
    if scored < MIN_TRAIN_MINUTES:
        raise CalibrationError(
            f"coach {coach}: {scored} scored training minutes; calibration needs at least "
            f"{MIN_TRAIN_MINUTES} (after the {WARMUP_MIN}-min warm-up of each trajectory)"
        )
    if not np.isfinite(rep.p_kw[rep.scored]).any():
        raise CalibrationError(f"coach {coach}: no metered HVAC power on the training days")

    lo = np.array([CALIBRATED[n].bounds[0] for n in names])
    hi = np.array([CALIBRATED[n].bounds[1] for n in names])
    x0 = np.array([nominal(base, n) for n in names])
    # the optimiser works on values scaled by their nominal (all of order 1)
    unit = np.where(x0 != 0, np.abs(x0), 1.0)

    def params_at(z: np.ndarray) -> CoachParams:
        return apply(base, dict(zip(names, z * unit, strict=True)))

    cache: dict[bytes, np.ndarray] = {}

    def fun(z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in cache:
            [r] = residuals_of_sets(rep, [params_at(z)])
            cache.clear()
            cache[key] = r
        return cache[key]

    def jac(z: np.ndarray) -> np.ndarray:
        steps = JACOBIAN_STEP * np.maximum(np.abs(z), 0.1)
        # a step backwards where a forward one would leave the bounds
        steps = np.where(z + steps > hi / unit, -steps, steps)
        sets = [params_at(z)] + [
            params_at(z + h * e) for h, e in zip(steps, np.eye(len(z)), strict=True)
        ]
        r = residuals_of_sets(rep, sets)
        cache.clear()
        cache[z.tobytes()] = r[0]
        return np.column_stack([(ri - r[0]) / h for ri, h in zip(r[1:], steps, strict=True)])

    # a parameter these days do not depend on at all (the COP without a minute of cooling) is
    # refused at once
    sensitivity = np.linalg.norm(jac(x0 / unit), axis=0)
    inert = [n for n, g in zip(names, sensitivity, strict=True) if not g > 1e-9]
    if inert:
        raise CalibrationError(
            f"coach {coach}: nothing logged on the training days depends on "
            f"{', '.join(inert)} (e.g. the COP without any cooling): calibrate it on other "
            "days, or leave it out of --params"
        )
    # the starts: the best of the nominal values and a Latin hypercube over the bounds, all
    # simulated at once (one fleet, a column block per candidate)
    sample = qmc.LatinHypercube(d=len(names), seed=seed).random(SCREENED)
    screened = np.vstack([x0, qmc.scale(sample, lo, hi)]) / unit
    costs = [float(np.sum(r**2)) for r in residuals_of_sets(rep, [params_at(z) for z in screened])]
    candidates = screened[np.argsort(costs)[:starts]]
    fits = [
        least_squares(
            fun,
            np.clip(z0, lo / unit, hi / unit),
            jac=jac,
            bounds=(lo / unit, hi / unit),
            x_scale="jac",
            max_nfev=MAX_EVALUATIONS,
        )
        for z0 in candidates
    ]
    best = min(fits, key=lambda f: f.cost)
    # another start ending as good a fit elsewhere: these days do not single out one answer
    rivals = [
        f for f in fits if f.cost <= (1 + RIVAL_COST) * best.cost
        and np.any(np.abs(f.x - best.x) > RIVAL_SPREAD * np.abs(best.x))
    ]  # fmt: skip
    if rivals:
        other = ", ".join(
            f"{n} {a:.3g} or {b:.3g}"
            for n, a, b in zip(names, best.x * unit, rivals[0].x * unit, strict=True)
        )
        raise CalibrationError(
            f"coach {coach}: these days fit several parameter sets equally well ({other}): "
            "calibrate fewer --params, or add days of other weather"
        )
    values = best.x * unit
    dof = max(1, len(best.fun) - len(values))
    s2 = 2.0 * best.cost / dof
    try:
        cov = np.linalg.inv(best.jac.T @ best.jac) * s2
    except np.linalg.LinAlgError:
        cov = np.full((len(values), len(values)), np.inf)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std = sd * unit
    vague = [
        f"{n} ({s / max(abs(v), 1e-12):.0%})"
        for n, v, s in zip(names, values, std, strict=True)
        if not s <= MAX_RELATIVE_STD * abs(v)
    ]
    if vague:
        raise CalibrationError(
            f"coach {coach}: the data do not determine {', '.join(vague)} (relative standard "
            "error); give days with more varied weather and operation, or fewer --params"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    tangled = [
        f"{names[i]} and {names[j]} (correlation {corr[i, j]:+.2f})"
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if not abs(corr[i, j]) <= MAX_CORRELATION
    ]
    if tangled:
        raise CalibrationError(
            f"coach {coach}: these data cannot tell apart {'; '.join(tangled)}: calibrate one "
            "of each pair (--params), or add days of other seasons"
        )
    params = params_at(best.x)
    y, p = simulate(rep, [params])
    on_train = errors(rep, y, p)
    if holdout:
        rep_h = replay(holdout)
        y, p = simulate(rep_h, [params])
        on_holdout = errors(rep_h, y, p)
    else:
        on_holdout = {}
    fitted = {
        n: {"value": float(v), "std": float(s), "unit": CALIBRATED[n].unit}
        for n, v, s in zip(names, values, std, strict=True)
    }
    return Calibration(coach, params, fitted, on_train, on_holdout, len(candidates))
