"""The runs of simulated trials (:mod:`.trial_sim`): each plan's estimate beside the
counterfactual truth, and how the plans' estimates fared over many seeds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trainclimate.analysis.trial import TrialEstimate
from trainclimate.coach.meters import HEADLINE_METER


@dataclass
class TrialRun:
    """One plan of a simulated trial: the estimate a trial makes and the truth beside it.

    Attributes
    ----------
    scenario : str
        The scenario's name.
    plan : str
        One of :data:`~trainclimate.analysis.trial_sim.TRIAL_PLANS`.
    seed : int
        The trial's seed (weather, operation, coaches, sensor noise, randomized plan, bootstrap).
    coach_spread : float
        The coaches' parameter spread. [–]
    forecast : str
        The layer's disturbance forecast.
    switch_hour : int
        Local hour a service day starts. [h]
    lead_in_min : float
        Excluded after each switch. [min]
    days_simulated : int
        Service days simulated.
    estimate : TrialEstimate
        What the trial estimates from the plan's run.
    true_savings_pct : float or None
        The counterfactual saving over the counted windows of the estimate's days. [%]
    true_savings_by_coach_pct : list of float or None
        The same, per coach. [%]
    counted_windows : int
        Windows counted (of the days the estimate used).
    wall_s : float
        Wall-clock time of the whole simulation (all its plans). [s]
    """

    scenario: str
    plan: str
    seed: int
    coach_spread: float
    forecast: str
    switch_hour: int
    lead_in_min: float
    days_simulated: int
    estimate: TrialEstimate
    true_savings_pct: float | None
    true_savings_by_coach_pct: list[float | None]
    counted_windows: int
    wall_s: float

    @property
    def error_pct(self) -> float | None:
        """The estimate less the truth (None without either). [percentage points]"""
        return _difference(self.estimate.savings_pct, self.true_savings_pct)

    @property
    def naive_error_pct(self) -> float | None:
        """The naive figure less the truth (None without either). [percentage points]"""
        return _difference(self.estimate.naive_savings_pct, self.true_savings_pct)

    @property
    def covered(self) -> bool | None:
        """Whether the 95 % interval holds the truth (None without either)."""
        ci = self.estimate.savings_ci95_pct
        if ci is None or self.true_savings_pct is None:
            return None
        return bool(ci[0] <= self.true_savings_pct <= ci[1])

    def to_dict(self) -> dict:
        """The JSON of ``trainclimate experiment trial``.

        Returns
        -------
        dict
            The run's inputs, the estimate (:meth:`TrialEstimate.to_dict`: savings and interval
            in %, days by group), ``true_savings_pct`` and per coach (%), ``error_pct`` and
            ``naive_error_pct`` (percentage points), ``covered``, ``counted_windows``, ``meter``
            and ``wall_seconds`` (s).
        """
        return {
            "scenario": self.scenario,
            "plan": self.plan,
            "seed": self.seed,
            "coach_spread": self.coach_spread,
            "forecast": self.forecast,
            "switch_hour": self.switch_hour,
            "lead_in_min": self.lead_in_min,
            "days_simulated": self.days_simulated,
            "meter": HEADLINE_METER,
            **self.estimate.to_dict(),
            "true_savings_pct": self.true_savings_pct,
            "true_savings_by_coach_pct": self.true_savings_by_coach_pct,
            "error_pct": self.error_pct,
            "naive_error_pct": self.naive_error_pct,
            "covered": self.covered,
            "counted_windows": self.counted_windows,
            "wall_seconds": self.wall_s,
        }


def _difference(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else float(a - b)


def summarize(runs: list[TrialRun]) -> dict[str, dict]:
    """How the plans' estimates fared against the truth over several seeds.

    Parameters
    ----------
    runs : list of TrialRun
        Any number of seeds and plans.

    Returns
    -------
    dict
        Plan → ``runs``, ``with_interval``, ``coverage_pct`` (% of the runs with an interval
        whose interval holds the truth), ``mae_pct`` and ``mean_error_pct`` (the estimate's mean
        absolute and mean error, percentage points), ``mean_half_width_pct`` (percentage
        points), ``mean_days_to_target``, ``guideline_14_pct`` (% of runs meeting it),
        ``naive_mae_pct`` and ``naive_mean_error_pct`` (the naive figure's, percentage points),
        ``mean_true_savings_pct`` (%); None where no run has the value.
    """
    out = {}
    for plan in dict.fromkeys(r.plan for r in runs):
        mine = [r for r in runs if r.plan == plan]
        ci = [r for r in mine if r.covered is not None]
        errors = [r.error_pct for r in mine]
        naive = [r.naive_error_pct for r in mine]
        out[plan] = {
            "runs": len(mine),
            "with_interval": len(ci),
            "coverage_pct": _mean([100.0 * r.covered for r in ci]),
            "mae_pct": _mean([abs(e) for e in errors if e is not None]),
            "mean_error_pct": _mean(errors),
            "mean_half_width_pct": _mean(
                [(r.estimate.savings_ci95_pct[1] - r.estimate.savings_ci95_pct[0]) / 2 for r in ci]
            ),
            "mean_days_to_target": _mean([r.estimate.days_to_target for r in mine]),
            "guideline_14_pct": _mean([100.0 * r.estimate.meets_guideline_14 for r in ci]),
            "naive_mae_pct": _mean([abs(e) for e in naive if e is not None]),
            "naive_mean_error_pct": _mean(naive),
            "mean_true_savings_pct": _mean([r.true_savings_pct for r in mine]),
        }
    return out


def _mean(values: list) -> float | None:
    """The mean of the values that are not None (None if none is)."""
    kept = [float(v) for v in values if v is not None]
    return float(np.mean(kept)) if kept else None
