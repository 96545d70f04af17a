"""Confidence intervals of a fleet study's savings: a two-way bootstrap over coaches and days.

The coach-days of a study are not independent draws. A coach keeps its parameters over all its
days, and on a day every coach has the same weather (one site, one generated or measured
weather). The energies form a coaches × days table with a coach effect and a day effect, as in
a crossed random-effects model E_cd = μ + a_c + b_d + e_cd. Resampling coach-days one by one
would ignore both effects and give too narrow an interval; resampling coaches alone keeps the
days fixed and ignores the weather's variation (the b_d). The pigeonhole bootstrap [1]_
resamples the rows and the columns independently, with replacement, and evaluates the statistic
over the crossed sample: coaches C* and days D* give the table's cells (c, d) for c in C*,
d in D*, each as often as its coach and its day were drawn. For a mean over such a table its
variance is mildly conservative, too large rather than too small [1]_. The days are drawn one by
one: the weather's persistence from one day to the next (the generator's day anomalies have a
lag-1 correlation of 0.7) is not carried into the resamples, which narrows the interval of a
short study; a study of a few weeks holds fewer independent weather situations than days.

The statistic is the study's own: the saving 100 · (1 − Σ E_layer / Σ E_rule) over the crossed
sample, a ratio of sums (not a mean of per-coach-day ratios), so each resample weighs coach-days
by their energy exactly as the point estimate does.

:func:`scipy.stats.bootstrap` does the resampling: given the coach indices and the day indices
as two samples, it resamples each independently (``paired=False``), which is the crossed
design, and hands the statistic both index draws. The interval is the percentile interval.

References
----------
.. [1] A. B. Owen, "The pigeonhole bootstrap", The Annals of Applied Statistics 1(2), 386–411,
   2007.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy.stats import DegenerateDataWarning, bootstrap

#: Confidence level of the intervals. [–]
CONFIDENCE = 0.95
#: Bootstrap resamples per interval.
RESAMPLES = 9999
#: The largest share of resamples without baseline energy (no saving defined there) left out of
#: the interval; with more there is no interval. [–]
MAX_UNDEFINED = 0.01
#: Resamples evaluated at once (bounds the memory: two counts arrays of this many rows).
BATCH = 1000


class Interval(NamedTuple):
    """A confidence interval, or why there is none.

    Attributes
    ----------
    pct : list of float or None
        ``[low, high]``. [%]
    reason : str or None
        Why ``pct`` is None (None when there is an interval).
    """

    pct: list[float] | None
    reason: str | None


def coach_day_table(
    frame: pd.DataFrame, column: str, coaches: pd.Index, days: pd.Index
) -> np.ndarray:
    """The sum of ``column`` per coach and day, 0 where ``frame`` has no row.

    Parameters
    ----------
    frame : pandas.DataFrame
        Rows with ``coach_index``, ``day`` and ``column`` (a study's rows, or some of them).
    column : str
        The summed column, e.g. ``energy_rule_kwh``.
    coaches, days : pandas.Index
        The table's coach indices and days, in order.

    Returns
    -------
    numpy.ndarray of shape (len(coaches), len(days))
        In the column's unit (kWh for the energies).
    """
    sums = frame.groupby(["coach_index", "day"])[column].sum().unstack("day")
    return sums.reindex(index=coaches, columns=days).fillna(0.0).to_numpy(dtype=float)


def _counts(draws: np.ndarray, n: int) -> np.ndarray:
    """How often each of ``n`` indices was drawn, per resample: (B, n) draws → (B, n) counts."""
    rows = draws.shape[0]
    flat = draws + n * np.arange(rows)[:, None]
    return np.bincount(flat.ravel(), minlength=rows * n).reshape(rows, n).astype(float)


def crossed_sums(table: np.ndarray, coach_draws: np.ndarray, day_draws: np.ndarray) -> np.ndarray:
    """Σ table[c, d] over the crossed sample of each resample's drawn coaches and days.

    Parameters
    ----------
    table : numpy.ndarray of shape (C, D)
        Per coach and day.
    coach_draws : numpy.ndarray of int, shape (B, C)
        Each resample's coach indices.
    day_draws : numpy.ndarray of int, shape (B, D)
        Each resample's day indices.

    Returns
    -------
    numpy.ndarray of shape (B,)
        w_cᵀ · table · w_d with w the draw counts, in the table's unit.
    """
    n_coaches, n_days = table.shape
    w_c = _counts(coach_draws, n_coaches)
    w_d = _counts(day_draws, n_days)
    return np.einsum("bd,bd->b", w_c @ table, w_d)


def savings_interval(
    base: np.ndarray,
    other: np.ndarray,
    *,
    seed: int,
    confidence: float = CONFIDENCE,
    resamples: int = RESAMPLES,
) -> Interval:
    """The confidence interval of the saving 100 · (1 − Σ other / Σ base), by the two-way
    (pigeonhole) percentile bootstrap over coaches and days (module docstring).

    Parameters
    ----------
    base : numpy.ndarray of shape (C, D)
        The baseline's energy per coach and day. [kWh]
    other : numpy.ndarray of shape (C, D)
        The compared controller's, same coaches and days. [kWh]
    seed : int
        Seed of the index draws: the same seed gives the same interval.
    confidence : float, default 0.95
        Confidence level. [–]
    resamples : int, default 9999
        Bootstrap resamples.

    Returns
    -------
    Interval
        ``[low, high]`` in %, or None with the reason: fewer than 2 coaches or 2 days, no
        baseline energy, or more than :data:`MAX_UNDEFINED` of the resamples with no baseline
        energy in their crossed sample (a situation on a few coach-days only: the saving is
        undefined there). Up to that share, those resamples are left out.
    """
    n_coaches, n_days = base.shape
    if n_coaches < 2 or n_days < 2:
        return Interval(None, f"needs at least 2 coaches and 2 days ({n_coaches} × {n_days} here)")
    if base.sum() <= 0:
        return Interval(None, "the baseline uses no energy")

    def saving(coach_draws: np.ndarray, day_draws: np.ndarray, axis: int = -1) -> np.ndarray:
        e_base = crossed_sums(base, coach_draws, day_draws)
        e_other = crossed_sums(other, coach_draws, day_draws)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(e_base > 0, 100.0 * (1.0 - e_other / e_base), np.nan)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        res = bootstrap(
            (np.arange(n_coaches), np.arange(n_days)),
            saving,
            n_resamples=resamples,
            batch=BATCH,
            vectorized=True,
            paired=False,
            confidence_level=confidence,
            method="percentile",
            rng=np.random.default_rng(seed),
        )
    dist = res.bootstrap_distribution
    undefined = np.isnan(dist).mean()
    if undefined > MAX_UNDEFINED:
        return Interval(
            None,
            f"{100 * undefined:.1f} % of the resamples have no baseline energy "
            f"(more than {100 * MAX_UNDEFINED:g} %)",
        )
    if undefined:  # the percentile interval of the resamples that have a saving
        low, high = np.nanquantile(dist, [(1 - confidence) / 2, (1 + confidence) / 2])
    else:
        low, high = res.confidence_interval
    return Interval([float(low), float(high)], None)
