"""The least-squares fit of a twin's knobs to a replay, and its uncertainty from the Jacobian.

:class:`Problem` scales the knobs by their nominal values, scores a parameter set by the replay's
residuals (:func:`~trainclimate.twin.replay.residuals`), differentiates them by forward
differences whose parameter sets run as further columns of one fleet, and fits with scipy's
bounded ``least_squares``; :func:`estimates` turns the Jacobian at the optimum into standard
errors and correlations (docs/model.md, "Calibration").
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from trainclimate.sim.params import CoachParams
from trainclimate.twin.knobs import CALIBRATED, apply, nominal
from trainclimate.twin.replay import Replay, residuals_of_sets

#: Relative step of the Jacobian's finite differences: wide enough to step over the small
#: discontinuities of the HVAC's switching logic, which make the error piecewise smooth.
JACOBIAN_STEP = 0.02
#: Most simulations one start of the fit may run (each iteration: one, plus one for its Jacobian).
MAX_EVALUATIONS = 100
#: The damping of a Gauss–Newton step (Levenberg–Marquardt, relative to the diagonal) and the
#: most parameter sets simulated as one fleet (bounds the memory: each set runs every training
#: trajectory).
GAUSS_NEWTON_DAMPING, MAX_SETS = 1e-3, 24
#: A fit has stalled when one Gauss–Newton step from it, within the bounds, predicts the sum of
#: squared residuals to fall by more than this share: it stopped on a kink of the piecewise-smooth
#: error (a tolerance test met), not at a minimum.
STALLED_SHARE = 0.02
#: The compass search that continues a stalled fit: its first step and its finest, relative to
#: each knob's scaled value (at least 0.1, as the Jacobian's), and the most fleets it runs.
COMPASS_STEP, COMPASS_FINEST, COMPASS_ROUNDS = 0.08, 0.005, 24


class Problem:
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
        """A fit from each of ``candidates`` (scaled values): ``least_squares``; where it
        stalled (:func:`predicted_fall` above :data:`STALLED_SHARE`), continued by a
        :func:`compass` search and ``least_squares`` again from where that ends."""
        fits = []
        for z0 in candidates:
            fit = self._least_squares(np.clip(z0, self.lo, self.hi))
            if predicted_fall(fit.fun, fit.jac, fit.x, self.lo, self.hi) > STALLED_SHARE:
                z, r = compass(self._residuals, fit.x, fit.fun, self.lo, self.hi)
                if r @ r < fit.fun @ fit.fun:
                    fit = self._least_squares(z)
            fits.append(fit)
        return fits

    def _least_squares(self, z0: np.ndarray):
        return least_squares(
            self.fun,
            z0,
            jac=self.jac,
            bounds=(self.lo, self.hi),
            x_scale="jac",
            max_nfev=MAX_EVALUATIONS,
        )

    def _residuals(self, points: list[np.ndarray]) -> list[np.ndarray]:
        """The residuals at each of ``points`` (scaled values), simulated as one fleet."""
        return residuals_of_sets(self.rep, [self.params_at(z) for z in points])

    def step(self, z: np.ndarray, r: np.ndarray, j: np.ndarray, w: np.ndarray) -> np.ndarray:
        """One damped Gauss–Newton step from ``z`` on the residuals ``r`` (Jacobian ``j``)
        weighted by ``w``, kept in the bounds."""
        a = j.T @ (w[:, None] * j)
        a += GAUSS_NEWTON_DAMPING * np.diag(np.diag(a))
        delta = np.linalg.lstsq(a, -(j.T @ (w * r)), rcond=None)[0]
        return np.clip(z + delta, self.lo, self.hi)


def predicted_fall(r: np.ndarray, j: np.ndarray, z: np.ndarray, lo, hi) -> float:
    """The share of the sum of squared residuals ‖r‖² that one Gauss–Newton step from ``z``
    (residuals ``r``, Jacobian ``j``), clipped to the bounds [lo, hi], predicts to remove on the
    linearised residuals r + j Δz: 1 − ‖r + j Δz‖² / ‖r‖² (0 at a smooth minimum, where
    jᵀr = 0; 0 for ‖r‖ = 0). [–]"""
    ssr = float(r @ r)
    if not ssr > 0:
        return 0.0
    delta = np.linalg.lstsq(j, -r, rcond=None)[0]
    step = np.clip(z + delta, lo, hi) - z
    after = r + j @ step
    return max(0.0, 1.0 - float(after @ after) / ssr)


def compass(residuals, z, r, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """A compass search from ``z`` (residuals ``r``), which kinks do not stop: the 2k points
    ±h along each axis, clipped to [lo, hi], evaluated together (``residuals(points)``: one
    fleet); the best taken if it lowers ‖r‖², else h halved — from :data:`COMPASS_STEP` to
    :data:`COMPASS_FINEST` of each value (at least 0.1), at most :data:`COMPASS_ROUNDS`
    rounds. Returns the point reached and its residuals (Kolda, Lewis & Torczon, "Optimization
    by direct search", SIAM Review 45(3), 2003: the compass search, §3)."""
    scale = np.maximum(np.abs(z), 0.1)
    h, eye = COMPASS_STEP * scale, np.eye(len(z))
    for _ in range(COMPASS_ROUNDS):
        if np.all(h < COMPASS_FINEST * scale):
            break
        points = [np.clip(z + sign * h * e, lo, hi) for e in eye for sign in (1.0, -1.0)]
        found = residuals(points)
        costs = [float(x @ x) for x in found]
        best = int(np.argmin(costs))
        if costs[best] < float(r @ r):
            z, r = points[best], found[best]
        else:
            h = h / 2
    return z, r


def estimates(fit, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def correlated_pairs(
    names: tuple[str, ...], corr: np.ndarray, limit: float
) -> list[tuple[int, int]]:
    """The pairs of ``names`` whose estimates are correlated beyond ±``limit`` (or unknown),
    the most correlated first."""
    pairs = [
        (i, j)
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if not abs(corr[i, j]) <= limit
    ]
    return sorted(pairs, key=lambda ij: -np.nan_to_num(abs(corr[ij]), nan=np.inf))
