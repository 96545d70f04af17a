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
import datetime
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats
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
#: The default subset: every knob, each kept at its base value where the data do not identify it.
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
#: Without --params, of two knobs correlated beyond this one is held at its base value (with
#: --params: a warning between this and MAX_CORRELATION).
HOLD_CORRELATION = 0.9
#: Bootstrap replicates by default, the Gauss–Newton steps of each re-fit, their damping
#: (Levenberg–Marquardt, relative to the diagonal) and the most parameter sets simulated as one
#: fleet (bounds the memory: each set runs every training trajectory).
BOOTSTRAP_REPLICATES, BOOTSTRAP_ITERATIONS, GAUSS_NEWTON_DAMPING, MAX_SETS = 20, 2, 1e-3, 24
#: Fewest days a bootstrap over days resamples: of one day every replicate is that day, an
#: interval of zero width whatever the day says.
MIN_BOOTSTRAP_DAYS = 2
#: A 95 % interval reaching beyond this share of its value on a side is wide; one this many
#: times wider than 1.96 standard errors says the Jacobian understates the uncertainty.
WIDE_INTERVAL, UNDERSTATED = 0.25, 3.0
#: Width of the ambient-temperature bands the held-out errors are reported in (K), the fewest
#: scored minutes a band needs, and the energy error a band may have and be validated (%).
BAND_K, MIN_BAND_MINUTES, VALID_ENERGY_PCT = 5.0, 60, 5.0


#: The entries of ``ua_room_chassis_w_k`` (deck rows, chassis columns) through the outer
#: envelope: the upper deck to the upper chassis, the middle deck to the upper and lower
#: chassis, the lower deck to the lower chassis (not the middle floor's interior film).
_OUTER = np.array([[True, False, False], [True, False, True], [False, False, True]])


#: The calibrated quantities set to their value; the others are scales of the base parameters.
QUANTITIES = ("fan_supply_w", "fresh_air_base_fraction")


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
        elif name in QUANTITIES:
            changes[name] = float(v)
        else:
            raise CalibrationError(f"unknown calibration parameter {name!r}")
    return dataclasses.replace(base, **changes)


def nominal(base: CoachParams, name: str) -> float:
    """The value of calibrated quantity ``name`` in ``base`` (scales: 1)."""
    return float(getattr(base, name)) if name in QUANTITIES else 1.0


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


def errors(
    rep: Replay, y: np.ndarray, p: np.ndarray, minutes: np.ndarray | None = None
) -> dict[str, float | None]:
    """The twin's errors on the scored minutes (or on ``minutes``, a mask of them): deck
    temperature MAE (K), power MAE (kW) and the metered energy's relative error (%; minutes
    with a metered power only; None without any)."""
    scored = rep.scored if minutes is None else minutes
    power = scored & np.isfinite(rep.p_kw)
    logged = rep.p_kw[power].sum()
    return {
        "t_room_mae_c": float(np.abs(y - rep.y)[scored].mean()),
        "power_mae_kw": float(np.abs(p - rep.p_kw)[power].mean()) if power.any() else None,
        "energy_error_pct": (
            float(100.0 * (p[power].sum() - logged) / logged) if logged > 0 else None
        ),
        "minutes": int(scored.sum()),
    }


def t_amb_minutes(rep: Replay) -> np.ndarray:
    """The logged T_amb of each replayed minute (minutes, columns). [°C]"""
    return rep.env.t_amb_c[:: rep.per_minute][: len(rep.y)]


def band_errors(rep: Replay, y: np.ndarray, p: np.ndarray) -> list[dict]:
    """:func:`errors` per :data:`BAND_K`-wide band of the logged T_amb (``t_amb_c``: [low,
    high) in °C), of the bands with at least :data:`MIN_BAND_MINUTES` scored minutes."""
    band = np.floor(t_amb_minutes(rep) / BAND_K) * BAND_K
    out = []
    for low in np.unique(band[rep.scored]):
        mask = rep.scored & (band == low)
        if mask.sum() >= MIN_BAND_MINUTES:
            out.append({"t_amb_c": [float(low), float(low + BAND_K)], **errors(rep, y, p, mask)})
    return out


def validated_range(
    train_t_amb_c: np.ndarray, bands: list[dict]
) -> tuple[list[float] | None, list[str]]:
    """The ambient temperatures the twin is validated for, and warnings.

    The training minutes' T_amb (2nd to 98th percentile, ``train_t_amb_c`` in °C), widened by
    each held-out band (:func:`band_errors`) next to it whose energy error is within
    :data:`VALID_ENERGY_PCT`, outwards until one is not; a held-out band beyond that error
    is warned of and cut from the range on its side. None (and a warning) when nothing is left.
    """
    low, high = (float(v) for v in np.percentile(train_t_amb_c, [2, 98]))
    middle = (low + high) / 2

    def good(b: dict) -> bool:
        e = b["energy_error_pct"]
        return e is not None and abs(e) <= VALID_ENERGY_PCT

    warnings = [
        f"held out at {b['t_amb_c'][0]:g} to {b['t_amb_c'][1]:g} °C the twin's energy is "
        + ("not metered" if b["energy_error_pct"] is None else f"{b['energy_error_pct']:+.1f} %")
        + f" off (beyond ±{VALID_ENERGY_PCT:g} %): not validated there"
        for b in bands
        if not good(b)
    ]
    for b in sorted((b for b in bands if b["t_amb_c"][0] < low), key=lambda b: -b["t_amb_c"][0]):
        if not good(b) or b["t_amb_c"][1] < np.floor(low / BAND_K) * BAND_K:
            break
        low = b["t_amb_c"][0]
    for b in sorted((b for b in bands if b["t_amb_c"][1] > high), key=lambda b: b["t_amb_c"][0]):
        if not good(b) or b["t_amb_c"][0] > np.ceil(high / BAND_K) * BAND_K:
            break
        high = b["t_amb_c"][1]
    for b in bands:
        a, z = b["t_amb_c"]
        if not good(b) and a < high and z > low:
            if (a + z) / 2 < middle:
                low = max(low, z)
            else:
                high = min(high, a)
    if not low < high:
        return None, [*warnings, "the twin is validated at no ambient temperature"]
    return [round(low, 1), round(high, 1)], warnings


# --- fitting ----------------------------------------------------------------------------------
def local_day(t: Trajectory) -> datetime.date:
    """The local (Europe/Zurich) date ``t`` starts on."""
    return t.time[0].tz_convert("Europe/Zurich").date()


def split_days(trajectories: list[Trajectory]) -> tuple[list[Trajectory], list[Trajectory]]:
    """Training and held-out trajectories, by the local date a trajectory starts on, held out
    by condition: of the coach's days ranked by their mean logged T_amb, the coldest, the
    warmest, the next coldest, … — ``round(HOLDOUT_SHARE · days)`` of them, at least one and,
    from 3 days on, at least two — so that the held-out days test the twin beyond the
    conditions it was fitted on."""
    days = sorted({local_day(t) for t in trajectories})
    if len(days) < 2:
        raise CalibrationError(
            f"calibration needs trajectories on at least 2 days (training and held out); "
            f"got {len(days)}"
        )
    warmth = {
        day: float(
            np.nanmean(np.concatenate([t.d[:, 0] for t in trajectories if local_day(t) == day]))
        )
        for day in days
    }
    ranked = sorted(days, key=lambda day: (warmth[day], day))
    count = max(1 if len(days) < 3 else 2, round(HOLDOUT_SHARE * len(days)))
    held = {ranked[k // 2] if k % 2 == 0 else ranked[-1 - k // 2] for k in range(count)}
    train = [t for t in trajectories if local_day(t) not in held]
    holdout = [t for t in trajectories if local_day(t) in held]
    return train, holdout


@dataclass
class Calibration:
    """One coach's fit: the parameters, the values fitted with their standard errors and
    bootstrap intervals, the knobs held at their base value and why, the twin's errors on the
    training and held-out days (and per ambient band), the ambient range it is validated for,
    and warnings."""

    coach: str
    params: CoachParams
    fitted: dict[str, dict]
    train: dict[str, float]
    holdout: dict
    starts: int
    not_identified: list[dict[str, str]] = dataclasses.field(default_factory=list)
    warnings: list[str] = dataclasses.field(default_factory=list)
    validated_t_amb_c: list[float] | None = None
    bootstrap: int = 0

    def to_dict(self) -> dict:
        """The ``calibrate --json`` object of the coach."""
        return {
            "coach": self.coach,
            "params": self.params.to_dict(),
            "fitted": self.fitted,
            "not_identified": self.not_identified,
            "train": self.train,
            "holdout": self.holdout,
            "validated_t_amb_c": self.validated_t_amb_c,
            "bootstrap": self.bootstrap,
            "warnings": self.warnings,
            "starts": self.starts,
        }


class _Problem:
    """The least-squares problem of fitting ``names`` of ``base`` to the replay ``rep``, on
    values scaled by their nominal (all of order 1)."""

    def __init__(self, rep: Replay, names: tuple[str, ...], base: CoachParams):
        self.rep, self.names, self.base = rep, names, base
        x0 = np.array([nominal(base, n) for n in names])
        self.unit = np.where(x0 != 0, np.abs(x0), 1.0)
        self.z0 = x0 / self.unit
        self.lo = np.array([CALIBRATED[n].bounds[0] for n in names]) / self.unit
        self.hi = np.array([CALIBRATED[n].bounds[1] for n in names]) / self.unit
        self._cache: dict[bytes, np.ndarray] = {}

    def params_at(self, z: np.ndarray) -> CoachParams:
        return apply(self.base, dict(zip(self.names, z * self.unit, strict=True)))

    def fun(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in self._cache:
            [r] = residuals_of_sets(self.rep, [self.params_at(z)])
            self._cache = {key: r}
        return self._cache[key]

    def jac(self, z: np.ndarray) -> np.ndarray:
        [(r, j)] = self.linearised([z])
        self._cache = {z.tobytes(): r}
        return j

    def linearised(self, points: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        """The residuals and their Jacobian (forward differences of :data:`JACOBIAN_STEP`) at
        each of ``points``, simulated as few fleets of at most :data:`MAX_SETS` sets."""
        k = len(self.names)
        per_fleet = max(1, MAX_SETS // (k + 1))
        out = []
        for i in range(0, len(points), per_fleet):
            chunk, sets, steps = points[i : i + per_fleet], [], []
            for z in chunk:
                h = JACOBIAN_STEP * np.maximum(np.abs(z), 0.1)
                # a step backwards where a forward one would leave the bounds
                h = np.where(z + h > self.hi, -h, h)
                steps.append(h)
                sets += [self.params_at(z)] + [
                    self.params_at(z + s * e) for s, e in zip(h, np.eye(k), strict=True)
                ]
            r = residuals_of_sets(self.rep, sets)
            for j, h in enumerate(steps):
                rj = r[j * (k + 1) : (j + 1) * (k + 1)]
                out.append(
                    (
                        rj[0],
                        np.column_stack(
                            [(ri - rj[0]) / s for ri, s in zip(rj[1:], h, strict=True)]
                        ),
                    )
                )
        return out

    def solve(self, candidates: np.ndarray) -> list:
        """``least_squares`` from each of ``candidates`` (scaled values)."""
        return [
            least_squares(
                self.fun,
                np.clip(z0, self.lo, self.hi),
                jac=self.jac,
                bounds=(self.lo, self.hi),
                x_scale="jac",
                max_nfev=MAX_EVALUATIONS,
            )
            for z0 in candidates
        ]

    def step(self, z: np.ndarray, r: np.ndarray, j: np.ndarray, w: np.ndarray) -> np.ndarray:
        """One damped Gauss–Newton step from ``z`` on the residuals ``r`` (Jacobian ``j``)
        weighted by ``w``, kept in the bounds."""
        a = j.T @ (w[:, None] * j)
        a += GAUSS_NEWTON_DAMPING * np.diag(np.diag(a))
        delta = np.linalg.lstsq(a, -(j.T @ (w * r)), rcond=None)[0]
        return np.clip(z + delta, self.lo, self.hi)


def _statistics(fit, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Values, standard errors (σ = sqrt(diag((JᵀJ)⁻¹) · SSR / (m − k))) and correlations of
    the estimates of the ``least_squares`` result ``fit``, in the parameters' units."""
    values = fit.x * unit
    dof = max(1, len(fit.fun) - len(values))
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * (2.0 * fit.cost / dof)
    except np.linalg.LinAlgError:
        cov = np.full((len(values), len(values)), np.inf)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    return values, sd * unit, corr


def _pairs(names: tuple[str, ...], corr: np.ndarray, limit: float) -> list[tuple[int, int]]:
    """The pairs of ``names`` whose estimates are correlated beyond ±``limit`` (or unknown),
    the most correlated first."""
    pairs = [
        (i, j)
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if not abs(corr[i, j]) <= limit
    ]
    return sorted(pairs, key=lambda ij: -np.nan_to_num(abs(corr[ij]), nan=np.inf))


def calibrate(
    coach: str,
    trajectories: list[Trajectory],
    names: tuple[str, ...] | None = None,
    base: CoachParams | None = None,
    starts: int = 3,
    seed: int = 0,
    bootstrap: int = BOOTSTRAP_REPLICATES,
    among: tuple[str, ...] = DEFAULT_PARAMS,
) -> Calibration:
    """Fit ``names`` (:data:`CALIBRATED`; None: what the data identify of ``among``) of
    ``base`` (default :class:`CoachParams`) to one coach's 1-min trajectories by
    simulation-error minimisation, with ``bootstrap`` replicates over whole training days for
    the 95 % intervals (0: none).

    Bounded ``scipy.optimize.least_squares`` (trust-region reflective) from the ``starts``
    best of the nominal values and :data:`SCREENED` points of a Latin hypercube over the bounds
    (``seed``), all screened in one simulation; the best fit is kept. Standard errors come from
    the Jacobian at the optimum, σ = sqrt(diag((JᵀJ)⁻¹) · SSR / (m − k)), scaled back to each
    parameter's unit. Without ``names`` a knob nothing logged depends on, one the data leave
    undetermined (relative standard error above :data:`MAX_RELATIVE_STD`) or one of two the
    data cannot tell apart (correlation beyond :data:`HOLD_CORRELATION`; the one of the pair
    with the larger relative standard error) is held at its base value, listed in
    ``not_identified`` with the reason, and the rest re-fitted from the fit so far.

    Raises
    ------
    CalibrationError
        On an unknown parameter name, too few days or training minutes, training days without
        any metered power, nothing left to fit, or — for ``names`` given — a fit that the data
        do not determine (a parameter nothing logged depends on, a standard error above
        :data:`MAX_RELATIVE_STD` of its value, two parameters correlated beyond
        :data:`MAX_CORRELATION`, or rival fits): a refusal, not a wild fit.
    """
    base = base or CoachParams()
    explicit = names is not None
    names = tuple(names) if explicit else tuple(among)
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

    held: list[dict[str, str]] = []
    warnings: list[str] = []
    problem = _Problem(rep, names, base)
    # a parameter these days do not depend on at all (the COP without a minute of cooling)
    sensitivity = np.linalg.norm(problem.jac(problem.z0), axis=0)
    inert = [n for n, g in zip(names, sensitivity, strict=True) if not g > 1e-9]
    if inert and explicit:
        raise CalibrationError(
            f"coach {coach}: nothing logged on the training days depends on "
            f"{', '.join(inert)} (e.g. the COP without any cooling): calibrate it on other "
            "days, or leave it out of --params"
        )
    held += [
        {"param": n, "reason": "nothing logged on the training days depends on it"} for n in inert
    ]
    names = tuple(n for n in names if n not in inert)
    if not names:
        raise CalibrationError(f"coach {coach}: nothing logged depends on any parameter")
    problem = _Problem(rep, names, base)
    # the starts: the best of the nominal values and a Latin hypercube over the bounds, all
    # simulated at once (one fleet, a column block per candidate)
    sample = qmc.LatinHypercube(d=len(names), seed=seed).random(SCREENED)
    screened = np.vstack([problem.z0, qmc.scale(sample, problem.lo, problem.hi)])
    costs = [
        float(np.sum(r**2))
        for r in residuals_of_sets(rep, [problem.params_at(z) for z in screened])
    ]
    candidates = screened[np.argsort(costs)[:starts]]
    n_starts = len(candidates)
    while True:
        rival: list[str] = []
        fits = problem.solve(candidates)
        best = min(fits, key=lambda f: f.cost)
        values, std, corr = _statistics(best, problem.unit)
        # another start ending as good a fit elsewhere: these days do not single out one answer
        rivals = [
            f for f in fits if f.cost <= (1 + RIVAL_COST) * best.cost
            and np.any(np.abs(f.x - best.x) > RIVAL_SPREAD * np.abs(best.x))
        ]  # fmt: skip
        if rivals:
            other = ", ".join(
                f"{n} {a:.3g} or {b:.3g}"
                for n, a, b in zip(names, values, rivals[0].x * problem.unit, strict=True)
            )
            if explicit:
                raise CalibrationError(
                    f"coach {coach}: these days fit several parameter sets equally well "
                    f"({other}): calibrate fewer --params, or add days of other weather"
                )
            rival = [f"these days fit several parameter sets about as well ({other})"]
        relative = std / np.maximum(np.abs(values), 1e-12)
        vague = [i for i, r in enumerate(relative) if not r <= MAX_RELATIVE_STD]
        if vague and explicit:
            raise CalibrationError(
                f"coach {coach}: the data do not determine "
                + ", ".join(f"{names[i]} ({relative[i]:.0%})" for i in vague)
                + " (relative standard error); give days with more varied weather and "
                "operation, or fewer --params"
            )
        tangled = _pairs(names, corr, MAX_CORRELATION if explicit else HOLD_CORRELATION)
        if tangled and explicit:
            raise CalibrationError(
                f"coach {coach}: these data cannot tell apart "
                + "; ".join(
                    f"{names[i]} and {names[j]} (correlation {corr[i, j]:+.2f})" for i, j in tangled
                )
                + ": calibrate one of each pair (--params), or add days of other seasons"
            )
        warnings += [
            f"{names[i]} and {names[j]} are correlated {corr[i, j]:+.2f}: the data hardly "
            "tell them apart"
            for i, j in _pairs(names, corr, HOLD_CORRELATION)
            if explicit
        ]
        if vague:
            drop = max(vague, key=lambda i: relative[i])
            reason = f"the data do not determine it (relative standard error {relative[drop]:.0%})"
        elif tangled:
            i, j = tangled[0]
            drop = i if relative[i] >= relative[j] else j
            other = names[j if drop == i else i]
            reason = (
                f"not told apart from {other} (correlation {corr[i, j]:+.2f}): held at its "
                f"base value, {other} fitted"
            )
            warnings.append(
                f"{names[i]} and {names[j]} are correlated {corr[i, j]:+.2f}: "
                f"{names[drop]} held at its base value"
            )
        else:
            break
        held.append({"param": names[drop], "reason": reason})
        keep = [k for k in range(len(names)) if k != drop]
        if not keep:
            raise CalibrationError(f"coach {coach}: the data determine none of the parameters")
        names = tuple(names[k] for k in keep)
        start = best.x[keep] * problem.unit[keep]
        problem = _Problem(rep, names, base)
        candidates = (start / problem.unit)[None, :]

    warnings += rival
    params = problem.params_at(best.x)
    y, p = simulate(rep, [params])
    on_train = errors(rep, y, p)
    fitted = {
        n: {"value": float(v), "std": float(s), "unit": CALIBRATED[n].unit}
        for n, v, s in zip(names, values, std, strict=True)
    }
    on_holdout: dict = {}
    validated = None
    if holdout:
        rep_h = replay(holdout)
        y, p = simulate(rep_h, [params])
        on_holdout = {**errors(rep_h, y, p), "bands": band_errors(rep_h, y, p)}
        validated, warned = validated_range(t_amb_minutes(rep)[rep.scored], on_holdout["bands"])
        warnings += warned
    replicas = None
    if bootstrap > 0:
        replicas = _bootstrap(
            problem, best, train, replay(holdout) if holdout else None, bootstrap, seed
        )
        if replicas is None:
            warnings.append("one training day: no bootstrap interval (it resamples whole days)")
            bootstrap = 0
    if replicas is not None:
        for n, interval in zip(names, replicas["values"], strict=True):
            fitted[n]["ci95"] = interval
        if holdout:
            on_holdout["energy_error_ci95_pct"] = replicas["energy"]
        warnings += _interval_warnings(fitted)
    return Calibration(
        coach,
        params,
        fitted,
        on_train,
        on_holdout,
        n_starts,
        held,
        warnings,
        validated,
        bootstrap,
    )


def day_bootstrap(
    days: int, day_of: np.ndarray, refit, replicates: int, seed: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """95 % intervals (percentile) of the statistics ``refit`` returns, from ``replicates``
    resamples of whole days drawn with replacement (``scipy.stats.bootstrap`` over the day
    indices, its generator seeded by ``seed``).

    ``day_of`` gives the day (0, 1, …, ``days`` − 1) of each residual. ``refit(w)`` takes the
    residuals' weights, shape (resamples, residuals): the times each residual's day was drawn,
    the same for every residual of a day; it returns the statistics, shape (statistics,
    resamples). Returns the lower and upper ends, one per statistic, or None with fewer than
    :data:`MIN_BOOTSTRAP_DAYS` days (``refit`` not called).
    """
    if days < MIN_BOOTSTRAP_DAYS:
        return None

    def statistic(drawn: np.ndarray, axis: int = -1) -> np.ndarray:
        counts = np.stack([np.bincount(d, minlength=days) for d in np.atleast_2d(drawn)])
        return refit(counts[:, day_of].astype(float))

    result = stats.bootstrap(
        (np.arange(days),),
        statistic,
        n_resamples=replicates,
        vectorized=True,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    low, high = result.confidence_interval
    return np.asarray(low), np.asarray(high)


def _bootstrap(
    problem: _Problem,
    best,
    train: list[Trajectory],
    rep_h: Replay | None,
    replicates: int,
    seed: int,
) -> dict | None:
    """95 % intervals (percentile) of the fitted values and of the held-out energy error from
    ``replicates`` re-fits on the training days resampled whole (:func:`day_bootstrap`); None
    with fewer than :data:`MIN_BOOTSTRAP_DAYS` training days.

    Each replicate weights the residuals of a day by the times it was drawn and re-fits from
    the optimum by :data:`BOOTSTRAP_ITERATIONS` damped Gauss–Newton steps: the first on the
    optimum's Jacobian, each further one on the replicate's own (all replicates' parameter
    sets simulated as one fleet); the re-fitted twins are then run on the held-out days.
    """
    day_index = {d: i for i, d in enumerate(sorted({local_day(t) for t in train}))}
    column_day = np.array([day_index[local_day(t)] for t in train])
    residual_day = column_day[residual_columns(problem.rep)]
    r0, j0 = best.fun, best.jac

    def refit(w: np.ndarray) -> np.ndarray:
        z = [problem.step(best.x, r0, j0, wb) for wb in w]
        for _ in range(BOOTSTRAP_ITERATIONS - 1):
            z = [
                problem.step(zb, r, j, wb)
                for zb, (r, j), wb in zip(z, problem.linearised(z), w, strict=True)
            ]
        values = np.array(z) * problem.unit
        energy = np.full(len(z), np.nan)
        if rep_h is not None:
            sets = [problem.params_at(zb) for zb in z]
            n = rep_h.env.n_coaches
            for i in range(0, len(sets), MAX_SETS):
                y, p = simulate(rep_h, sets[i : i + MAX_SETS])
                for k in range(len(sets[i : i + MAX_SETS])):
                    e = errors(rep_h, y[:, k * n : (k + 1) * n], p[:, k * n : (k + 1) * n])
                    energy[i + k] = (
                        np.nan if e["energy_error_pct"] is None else e["energy_error_pct"]
                    )
        return np.vstack([values.T, energy])

    interval = day_bootstrap(len(day_index), residual_day, refit, replicates, seed)
    if interval is None:
        return None
    low, high = interval
    energy = [float(low[-1]), float(high[-1])] if np.isfinite([low[-1], high[-1]]).all() else None
    return {
        "values": [[float(a), float(b)] for a, b in zip(low[:-1], high[:-1], strict=True)],
        "energy": energy,
    }


def _interval_warnings(fitted: dict[str, dict]) -> list[str]:
    """Warnings of the fitted values whose 95 % interval is wide (beyond
    :data:`WIDE_INTERVAL` of the value on either side) or far wider than the Jacobian's
    standard error says (half-width above :data:`UNDERSTATED` × 1.96 σ: the days disagree,
    which a model structure the knobs do not span does), and those whose interval leaves out
    the fitted value itself (the re-fits on resampled days settle elsewhere: the fit did not
    reach the optimum those days have, or has several)."""
    out = []
    for n, f in fitted.items():
        low, high = f["ci95"]
        if not low <= f["value"] <= high:
            out.append(
                f"{n}: the fit {f['value']:.4g} lies outside its own 95 % interval "
                f"[{low:.4g}, {high:.4g}]: re-fits on resampled days settle elsewhere, so the "
                "value is not to be trusted"
            )
        elif max(f["value"] - low, high - f["value"]) > WIDE_INTERVAL * abs(f["value"]):
            out.append(
                f"{n}: 95 % interval [{low:.4g}, {high:.4g}] is wide (beyond ±"
                f"{WIDE_INTERVAL:.0%} of {f['value']:.4g}): the data do not pin it down"
            )
        elif (high - low) / 2 > UNDERSTATED * 1.96 * f["std"]:
            out.append(
                f"{n}: the days disagree: 95 % interval [{low:.4g}, {high:.4g}] is over "
                f"{UNDERSTATED:g} times what its standard error {f['std']:.2g} says"
            )
    return out
