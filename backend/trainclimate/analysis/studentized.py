"""The studentized bootstrap of a difference of two groups' means, for many rows at once: each
resample drawn as :func:`scipy.stats.bootstrap` draws it (``default_rng(seed).integers(0, n,
(n_resamples, n))``, the first group then the second), written as a counts matrix C (how often
each observation is drawn), so that a resample's mean is C·x / n and its variance follows from
C·x² (Efron & Tibshirani 1993, *An Introduction to the Bootstrap*, ch. 6): a matrix product
instead of a gathered copy per resample. With few days most resamples repeat one another (of 3
days there are 10 distinct resamples, of 4 days 35): each distinct pair of the groups' columns
is then computed once and counted as often as it was drawn, which gives the same order
statistics, so the same quantiles. :mod:`.trial` uses it for the pair trials' intervals; the
tests hold it equal to scipy's.
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


@functools.lru_cache(maxsize=64)
def distinct_resamples(
    n_a: int, n_b: int, n_resamples: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The resamples of :func:`resample_counts`, each distinct one (the same columns of both
    groups) once, with how often it was drawn: counts matrices (n_a, k) and (n_b, k) and the
    draws (k,), which add up to ``n_resamples``. Where more than half the resamples are
    distinct (many days), the resamples as drawn and None. Read-only (they are cached)."""
    counts_a, counts_b = resample_counts(n_a, n_b, n_resamples, seed)
    distinct, draws = np.unique(np.concatenate([counts_a, counts_b]).T, axis=0, return_counts=True)
    if 2 * len(draws) > n_resamples:
        return counts_a, counts_b, None
    out = [np.ascontiguousarray(distinct[:, :n_a].T), np.ascontiguousarray(distinct[:, n_a:].T)]
    for x in (*out, draws):
        x.flags.writeable = False
    return out[0], out[1], draws


def effect(coef: float, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ln(1 − s) = coef (mean a − mean b) and its standard error |coef| √(var a/na + var b/nb)
    of each row of ``a`` (rows, na) and ``b`` (rows, nb) (sample variances; NaN for a group of
    one day). The sums are those ``numpy.mean`` and ``numpy.var`` take of each row, in the
    same order, without their checks."""
    moments = []
    with np.errstate(all="ignore"):
        for x in (a, b):
            n = x.shape[1]
            mean = np.add.reduce(x, axis=1) / n
            d = x - mean[:, None]
            moments.append((mean, np.add.reduce(d * d, axis=1) / (n - 1) / n))
    (mean_a, var_a), (mean_b, var_b) = moments
    return coef * (mean_a - mean_b), abs(coef) * np.sqrt(var_a + var_b)


#: Rows studentized together: the elementwise steps and the quantiles of a block of rows cost
#: less per row than row by row (450 pairs of 15 + 15 days: 96 ms row by row, 73-78 ms in
#: blocks of 4-8, measured). A block of 8 rows' (8, 4 999) arrays (320 kB) may still be handed
#: back to the kernel by glibc's allocator when freed and fault in again when next allocated
#: (46 000 page faults for 450 pairs in a process where that happens); larger blocks made that
#: cost more than they saved (16 rows took longer than one by one).
BLOCK_ROWS = 8


def pivot_quantiles(
    a: np.ndarray,
    b: np.ndarray,
    coef: np.ndarray,
    counts_a: np.ndarray,
    counts_b: np.ndarray,
    draws: np.ndarray | None = None,
) -> np.ndarray:
    """The quantiles :data:`QUANTILES` of each row's studentized bootstrap distribution
    (θ* − θ) / se* of θ = coef (mean a − mean b), shape (rows, 4), from the counts matrices of
    the groups' resamples (:func:`resample_counts`, or the distinct ones and their ``draws``,
    :func:`distinct_resamples`; ``a`` (rows, n_a), ``b`` (rows, n_b), ``coef`` (rows,)). A
    resample without spread studentizes to ±inf (0/0 to 0). Each row's quantiles are the same
    whatever rows it comes with (its matrix products are its own: the matrix library's rounding
    depends on a product's shape); the rows are taken :data:`BLOCK_ROWS` at a time."""
    a, b, coef = np.asarray(a), np.asarray(b), np.asarray(coef)
    return np.concatenate(
        [
            _block(
                a[i : i + BLOCK_ROWS],
                b[i : i + BLOCK_ROWS],
                coef[i : i + BLOCK_ROWS],
                counts_a,
                counts_b,
                draws,
            )
            for i in range(0, len(a), BLOCK_ROWS)
        ]
        or [np.zeros((0, len(QUANTILES)))]
    )


def _block(a, b, coef, counts_a, counts_b, draws) -> np.ndarray:
    """:func:`pivot_quantiles` of a block of rows. Its (rows, resamples) arrays are worked in
    place: each new one of 320 kB may be handed back to the kernel when freed and fault in
    again (see :data:`BLOCK_ROWS`); 1.6 against 1.4 ms for 8 rows of 15 + 15 days, measured."""
    rows = len(a)
    moments = []
    for x, counts in ((a, counts_a), (b, counts_b)):
        centred = x - x.mean(axis=1, keepdims=True)
        n = centred.shape[1]
        # per row: the resample's mean less the group's, C·x / n, and the variance of the
        # resample's mean, var / n = (C·x² − n·mean²) / (n (n − 1)) with var the sample
        # variance (ddof 1); the divisors are applied to x, before the products, each row's
        # three one product of shape (3, n) × (n, resamples)
        scaled = centred / (n * (n - 1))
        factors = np.stack([centred / n, scaled * centred, scaled], axis=1)  # (rows, 3, n)
        stacked = np.empty((rows, 3, counts.shape[1]))
        for r in range(rows):
            np.matmul(factors[r], counts, out=stacked[r])
        mean, squares, sums = stacked[:, 0], stacked[:, 1], stacked[:, 2]
        # squares − sums·mean; rounding leaves a resample without spread a little off 0, or
        # below: clipped, as np.var
        np.multiply(sums, mean, out=sums)
        np.subtract(squares, sums, out=squares)
        np.maximum(squares, 0.0, out=squares)
        moments.append((mean, squares))
    (mean_a, var_a), (mean_b, var_b) = moments
    # (θ* − θ) / se* = coef (mean_a − mean_b) / (|coef| √(var_a + var_b)): |coef| cancels
    t_star = np.subtract(mean_a, mean_b)
    t_star *= np.sign(coef)[:, None]
    with np.errstate(all="ignore"):
        np.add(var_a, var_b, out=var_a)
        np.sqrt(var_a, out=var_a)
        np.divide(t_star, var_a, out=t_star)
    if not np.isfinite(t_star).all():  # only where a resample has no spread (few days)
        np.nan_to_num(t_star, copy=False, nan=0.0)
    return quantiles(t_star, draws)


def quantiles(t: np.ndarray, draws: np.ndarray | None = None) -> np.ndarray:
    """The quantiles :data:`QUANTILES` of each row of ``t`` (each column counted ``draws``
    times; default once), shape (rows, 4): those of ``numpy.quantile`` of the values so
    counted (linear interpolation between the neighbouring order statistics, from the nearer
    one), read off each row sorted; with ``draws``, the k-th order statistic is the first value
    whose draws so far exceed k."""
    n = t.shape[1] if draws is None else int(draws.sum())
    position = np.asarray(QUANTILES) * (n - 1)
    below = np.floor(position).astype(np.int64)
    above = np.minimum(below + 1, n - 1)
    frac = position - below
    if draws is None:
        # sorted: numpy's vectorised sort of a row costs a quarter of a partition at these
        # eight places (34 against 137 µs for 4 999 values, measured); the same order statistics
        ordered = np.sort(t, axis=1)
        low, high = ordered[:, below], ordered[:, above]
    else:
        order = np.argsort(t, axis=1)
        drawn = np.cumsum(draws[order], axis=1)  # (rows, distinct): order statistics so far
        rows = np.arange(len(t))[:, None]
        at = [order[rows, (drawn[:, :, None] <= k).sum(axis=1)] for k in (below, above)]
        low, high = t[rows, at[0]], t[rows, at[1]]
    step = high - low
    return np.where(frac >= 0.5, high - step * (1.0 - frac), low + step * frac)
