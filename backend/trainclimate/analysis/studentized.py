"""The studentized bootstrap of a difference of two groups' means, for many rows at once: each
resample drawn as :func:`scipy.stats.bootstrap` draws it (``default_rng(seed).integers(0, n,
(n_resamples, n))``, the first group then the second), written as a counts matrix C (how often
each observation is drawn), so that a resample's mean is C·x / n and its variance follows from
C·x² (Efron & Tibshirani 1993, *An Introduction to the Bootstrap*, ch. 6): a matrix product
instead of a gathered copy per resample. :mod:`.trial` uses it for the pair trials' intervals;
the tests hold it equal to scipy's.
"""

from __future__ import annotations

import functools

import numpy as np

#: Quantiles of the studentized bootstrap distribution: the 95 % and the 68 % intervals.
QUANTILES = (0.025, 0.16, 0.84, 0.975)


@functools.lru_cache(maxsize=64)
def resample_counts(
    n_a: int, n_b: int, n_resamples: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """The counts matrices of scipy.stats.bootstrap's resamples of two groups of ``n_a`` and
    ``n_b`` days: row j, column r holds how often day j is drawn in resample r, shapes
    (n_a, n_resamples) and (n_b, n_resamples), read-only (they are cached)."""
    rng = np.random.default_rng(seed)
    out = []
    for n in (n_a, n_b):
        drawn = rng.integers(0, n, (n_resamples, n)) + n * np.arange(n_resamples)[:, None]
        counts = np.bincount(drawn.ravel(), minlength=n_resamples * n).astype(float)
        counts = np.ascontiguousarray(counts.reshape(n_resamples, n).T)  # rows: the days
        counts.flags.writeable = False
        out.append(counts)
    return out[0], out[1]


def pivot_quantiles(
    a: np.ndarray, b: np.ndarray, coef: np.ndarray, counts_a: np.ndarray, counts_b: np.ndarray
) -> np.ndarray:
    """The quantiles :data:`QUANTILES` of each row's studentized bootstrap distribution
    (θ* − θ) / se* of θ = coef (mean a − mean b), shape (rows, 4), from the counts matrices of
    the groups' resamples (:func:`resample_counts`; ``a`` (rows, n_a), ``b`` (rows, n_b),
    ``coef`` (rows,)). A resample without spread studentizes to ±inf (0/0 to 0)."""
    moments = []
    for x, counts in ((a, counts_a), (b, counts_b)):
        centred = np.asarray(x)
        centred = centred - centred.mean(axis=1, keepdims=True)
        rows, n = centred.shape
        # (rows, resamples): the resample's mean less the group's, C·x / n, and the variance
        # of the resample's mean, var / n = (C·x² − n·mean²) / (n (n − 1)) with var the sample
        # variance (ddof 1); the divisors are applied to x, before the products, which are one
        scaled = centred / (n * (n - 1))
        stacked = np.concatenate([centred / n, scaled * centred, scaled]) @ counts
        mean, squares, sums = stacked[:rows], stacked[rows : 2 * rows], stacked[2 * rows :]
        # rounding leaves a resample without spread a little off 0, or below: clipped, as np.var
        moments.append((mean, np.maximum(squares - sums * mean, 0.0)))
    (mean_a, var_a), (mean_b, var_b) = moments
    # (θ* − θ) / se* = coef (mean_a − mean_b) / (|coef| √(var_a + var_b)): |coef| cancels
    sign = np.sign(coef)[:, None]
    with np.errstate(all="ignore"):
        t_star = sign * (mean_a - mean_b) / np.sqrt(var_a + var_b)
    return quantiles(np.nan_to_num(t_star, nan=0.0))


def quantiles(t: np.ndarray) -> np.ndarray:
    """The quantiles :data:`QUANTILES` of each row of ``t``, shape (rows, 4): those of
    ``numpy.quantile`` (linear interpolation between the neighbouring order statistics, from
    the nearer one), read off each row partitioned at those order statistics, in one call."""
    position = np.asarray(QUANTILES) * (t.shape[1] - 1)
    below = np.floor(position).astype(np.int64)
    above = np.minimum(below + 1, t.shape[1] - 1)
    frac = position - below
    # the order statistics at these places only (what a sort would put there, exactly)
    ordered = np.partition(t, np.unique(np.r_[below, above]), axis=1)
    low, high = ordered[:, below], ordered[:, above]
    step = high - low
    return np.where(frac >= 0.5, high - step * (1.0 - frac), low + step * frac)
