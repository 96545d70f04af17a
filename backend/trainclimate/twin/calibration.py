"""Fitting the simulator to one real coach: a twin from its logged trajectories.

The coach's 1-min trajectories are replayed through the simulator
(:mod:`~trainclimate.twin.replay`). The knobs of :data:`~trainclimate.twin.knobs.CALIBRATED` are
then chosen to minimise the simulation error — deck temperatures and electrical power together —
with scipy's bounded ``least_squares`` from several starts (:mod:`~trainclimate.twin.fit`), on
the coach's training days; a knob the data do not identify is held at its base value. The
intervals come from a bootstrap over whole days (:mod:`~trainclimate.twin.bootstrap`), and the
twin is judged on held-out days (:mod:`~trainclimate.twin.validation`), there also on its
response to the logged setpoint changes (:mod:`~trainclimate.twin.response`; docs/model.md,
"Calibration").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from trainclimate.data.trajectory import Trajectory
from trainclimate.sim.params import CoachParams
from trainclimate.twin import response
from trainclimate.twin.bootstrap import BOOTSTRAP_REPLICATES, fit_intervals, interval_warnings
from trainclimate.twin.fit import (
    STALLED_SHARE,
    Problem,
    correlated_pairs,
    estimates,
    predicted_fall,
)
from trainclimate.twin.knobs import CALIBRATED, DEFAULT_PARAMS, CalibrationError
from trainclimate.twin.replay import WARMUP_MIN, replay, residuals_of_sets, simulate
from trainclimate.twin.validation import (
    band_errors,
    errors,
    split_days,
    t_amb_minutes,
    validated_range,
)

#: Scored training minutes needed at least.
MIN_TRAIN_MINUTES = 12 * 60
#: Two starts' fits within RIVAL_COST of each other's cost whose parameters differ by more than
#: RIVAL_SPREAD (relative) are rivals: the data do not single out one answer.
RIVAL_COST, RIVAL_SPREAD = 0.05, 0.10
#: Points of the Latin hypercube screened for the starts of the fit.
SCREENED = 16
#: A fit is refused when a parameter's standard error exceeds this share of its value, or two
#: parameters' estimates are correlated beyond this (the data cannot tell them apart).
MAX_RELATIVE_STD, MAX_CORRELATION = 0.5, 0.95
#: Without --params, of two knobs correlated beyond this one is held at its base value (with
#: --params: a warning between this and MAX_CORRELATION).
HOLD_CORRELATION = 0.9


@dataclass
class Calibration:
    """One coach's fit: the parameters, the values fitted with their standard errors and
    bootstrap intervals, the knobs held at their base value and why, the twin's errors on the
    training and held-out days (and per ambient band, and on the setpoint changes), the ambient
    range it is validated for, and warnings."""

    coach: str
    params: CoachParams
    fitted: dict[str, dict]
    train: dict
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
    """Fit ``names`` (:data:`~trainclimate.twin.knobs.CALIBRATED`; None: what the data
    identify of ``among``) of ``base`` (default :class:`CoachParams`) to one coach's 1-min
    trajectories by simulation-error minimisation, with ``bootstrap`` replicates over whole
    training days for the 95 % intervals (0: none).

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
    problem = Problem(rep, names, base)
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
    problem = Problem(rep, names, base)
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
        values, std, corr = estimates(best, problem.unit)
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
        tangled = correlated_pairs(names, corr, MAX_CORRELATION if explicit else HOLD_CORRELATION)
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
            for i, j in correlated_pairs(names, corr, HOLD_CORRELATION)
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
        problem = Problem(rep, names, base)
        candidates = (start / problem.unit)[None, :]

    warnings += rival
    fall = predicted_fall(best.fun, best.jac, best.x, problem.lo, problem.hi)
    if fall > STALLED_SHARE:
        warnings.append(
            f"the fit stopped short of a minimum ({best.message.rstrip('.')}): one "
            f"Gauss–Newton step from it still predicts {fall:.0%} less error, which a compass "
            "search around it did not find (a kink of the error), so its values may not be "
            "the coach's"
        )
    params = problem.params_at(best.x)
    y, p = simulate(rep, [params])
    on_train = {**errors(rep, y, p), "setpoint_response": response.score(rep, p)}
    fitted = {
        n: {"value": float(v), "std": float(s), "unit": CALIBRATED[n].unit}
        for n, v, s in zip(names, values, std, strict=True)
    }
    on_holdout: dict = {}
    validated = None
    if holdout:
        rep_h = replay(holdout)
        y, p = simulate(rep_h, [params])
        on_holdout = {
            **errors(rep_h, y, p),
            "bands": band_errors(rep_h, y, p),
            "setpoint_response": response.score(rep_h, p),
        }
        validated, warned = validated_range(t_amb_minutes(rep)[rep.scored], on_holdout["bands"])
        warnings += warned
        warnings += response.warnings(
            on_holdout["setpoint_response"], on_train["setpoint_response"]
        )
    replicas = None
    if bootstrap > 0:
        replicas = fit_intervals(
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
        warnings += interval_warnings(fitted)
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
