"""Trials on a pair of coaches: which coach runs the layer on which day, and savings that cancel
the coaches' own difference and say how sure they are.

Two coaches of one train are never the same coach: their envelopes, HVAC units and sensors differ
by as much as the layer saves (±10–15 % in energy). A pair with one coach always activated
measures the layer *and* the coaches (its figure is confounded); the paper names a methodology
accounting for the variability between coaches as its first future work. This module is that
methodology, shared by the simulator's ground-truth trials and the service.

The trial's calendar and plans (service days, and which coach is activated on which day) are in
:mod:`trainclimate.analysis.trial_plan`.

**Estimators.** Per service day *d*, the energies E0(d), E1(d) of the two coaches over the
windows counted for both, and which coach was activated. With a multiplicative model
E_c(d) = a_c · b_d · (1 − s)^[c activated on d] (coach level a_c, day level b_d — weather,
operation — and the saving s), the log-ratio x(d) = ln(E0(d) / E1(d)) = ln(a0/a1) ± ln(1 − s):
the day level cancels within each day, the coach level between days:

- ``crossover`` (both coaches have activated days): ln(1 − s) = (mean x | coach 0 on −
  mean x | coach 1 on) / 2;
- ``fixed_reference`` (one coach activated, plus reference days): ln(1 − s) = ±(mean x | on −
  mean x | reference);
- ``fixed_naive`` (one coach activated, no reference): 1 − ΣE_act / ΣE_deact, the coaches'
  difference included — reported without an interval, labelled as confounded.

The 95 % interval is a bootstrap over service days — the day is the independent unit, windows
within a day are not — each group of days resampled on its own, with the draws of
scipy.stats.bootstrap (:func:`estimate_many` computes them for many pairs at once). It is a
bootstrap-t interval: the resampled statistic is the estimate studentized by its standard error,
which keeps its coverage near 95 % with the week or two of days a trial has (a percentile or BCa
interval of the estimate itself covers about 90 % with seven days a group).
``days_to_target`` scales the interval's half-width as 1/√days to a target half-width;
``meets_guideline_14`` is ASHRAE Guideline 14's criterion (the savings' uncertainty at 68 %
confidence below 50 % of the savings). Trains pool into a fleet figure in
:mod:`trainclimate.analysis.trial_pool`.

References
----------
.. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal Energy
   Management, Section VI (future work).
.. [2] B. Jones and M. G. Kenward, Design and Analysis of Cross-Over Trials, 3rd ed., CRC, 2014.
.. [3] B. Efron and R. J. Tibshirani, An Introduction to the Bootstrap, Chapman & Hall, 1993,
   ch. 12 (bootstrap-t).
.. [4] ASHRAE Guideline 14-2014, Measurement of Energy, Demand, and Water Savings, §4.2 and
   Annex B (savings uncertainty).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from trainclimate.analysis import studentized
from trainclimate.analysis.arrays import pieces
from trainclimate.analysis.trial_plan import NEITHER

#: The estimators, by what the days allow.
ESTIMATORS = ("crossover", "fixed_reference", "fixed_naive")
#: Days of a group a bootstrap needs at least.
MIN_GROUP_DAYS = 3
#: Default target half-width of the 95 % interval for ``days_to_target``. [percentage points]
TARGET_HALF_WIDTH_PCT = 2.0
#: Threads computing the bootstraps of many pairs (:func:`estimate_many`): the products, the
#: elementwise steps and the sorts release the interpreter's lock. On two cores a new
#: 30-day fleet summary of 450 trains took ≈ 10 ms less with two threads than with one
#: (median 320-325 against 331-335 ms, measured through the app).
BOOTSTRAP_THREADS = 2
#: Pairs of one bootstrap job (of the same group sizes): blocks of rows for
#: :func:`.studentized.pivot_quantiles`.
_JOB_PAIRS = 32


@dataclass
class TrialDays:
    """A pair's energy per service day over the windows counted for both coaches.

    Attributes
    ----------
    day : numpy.ndarray of int, shape (n,)
        Service days (ordinals), ascending.
    energy_kwh : numpy.ndarray of shape (n, 2)
        Energy of coach 0 and coach 1. [kWh]
    activated : numpy.ndarray of int, shape (n,)
        0, 1, or :data:`NEITHER`.
    windows : numpy.ndarray of int, shape (n,)
        Windows counted that day.
    dropped : dict
        Days not used, by reason → count.
    """

    day: np.ndarray
    energy_kwh: np.ndarray
    activated: np.ndarray
    windows: np.ndarray
    dropped: dict = field(default_factory=dict)


def daily(
    day: np.ndarray,
    energy_kwh: np.ndarray,
    activated: np.ndarray,
    counted: np.ndarray,
    min_windows: int = 4,
) -> TrialDays:
    """Windows summed into service days.

    Parameters
    ----------
    day : numpy.ndarray of int, shape (W,)
        Each window's service day (:func:`~trainclimate.analysis.trial_plan.service_days` of
        its start).
    energy_kwh : numpy.ndarray of shape (W, 2)
        Each coach's energy per window. [kWh]
    activated : numpy.ndarray of int, shape (W,)
        The coach running the layer in each window (0, 1, :data:`NEITHER`).
    counted : numpy.ndarray of bool, shape (W,)
        Windows that count (both coaches clean, the activated one under the layer).
    min_windows : int, default 4
        Fewer counted windows make no day (dropped as ``too_few_windows``).

    Returns
    -------
    TrialDays
        A day whose counted windows do not all have one activated coach (a plan changed within
        it) is dropped as ``mixed_activation``; a day where a coach used no energy as
        ``no_energy``.
    """
    day = np.asarray(day, np.int64)
    energy = np.asarray(energy_kwh, float).reshape(len(day), 2)
    return daily_many(
        day, energy[None], np.asarray(activated)[None], np.asarray(counted)[None], min_windows
    )[0]


def daily_many(
    day: np.ndarray,
    energy_kwh: np.ndarray,
    activated: np.ndarray,
    counted: np.ndarray,
    min_windows: int = 4,
) -> list[TrialDays]:
    """:func:`daily` of several pairs over the same windows at once.

    Parameters
    ----------
    day : numpy.ndarray of int, shape (W,)
        Each window's service day.
    energy_kwh : numpy.ndarray of shape (P, W, 2)
        Each pair's coaches' energy per window. [kWh]
    activated : numpy.ndarray of int, shape (P, W)
        The coach running the layer (0, 1, :data:`NEITHER`; any value where not counted).
    counted : numpy.ndarray of bool, shape (P, W)

    Returns
    -------
    list of TrialDays
        One per pair, as :func:`daily` gives it.

    Raises
    ------
    ValueError
        If a counted window's ``activated`` is not 0, 1 or :data:`NEITHER`.
    """
    days, which = np.unique(np.asarray(day, np.int64), return_inverse=True)
    n, total, present = daily_sums(which, len(days), energy_kwh, activated, counted)
    return days_from_sums(np.broadcast_to(days, n.shape), n, total, present, min_windows)


def daily_sums(
    which: np.ndarray,
    n_days: int,
    energy_kwh: np.ndarray,
    activated: np.ndarray,
    counted: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`days_from_sums` judges each service day by, summed over its counted windows
    (several pairs over the same windows at once; the sums of two parts of a day add up).

    Parameters
    ----------
    which : numpy.ndarray of int, shape (W,)
        Each window's day, 0 … ``n_days`` − 1.
    n_days : int
    energy_kwh : numpy.ndarray of shape (P, W, 2)
        Each pair's coaches' energy per window. [kWh]
    activated : numpy.ndarray of int, shape (P, W)
        The coach running the layer (0, 1, :data:`NEITHER`; any value where not counted).
    counted : numpy.ndarray of bool, shape (P, W)

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Counted windows per day (P, D), each coach's energy over them (P, D, 2) [kWh] and how
        many of them had coach 0, coach 1 and neither activated (P, D, 3).

    Raises
    ------
    ValueError
        If a counted window's ``activated`` is not 0, 1 or :data:`NEITHER`.
    """
    keep = np.asarray(counted, bool)
    act = np.asarray(activated, np.int64)
    energy = np.asarray(energy_kwh, float).reshape(*keep.shape, 2)
    if np.any(keep & (act != 0) & (act != 1) & (act != NEITHER)):
        raise ValueError("a counted window's activated coach must be 0, 1 or NEITHER")
    one_hot = np.zeros((len(which), n_days))
    one_hot[np.arange(len(which)), which] = 1.0
    n = keep.astype(float) @ one_hot  # (P, D) counted windows per day
    total = np.swapaxes(
        np.swapaxes(np.where(keep[..., None], energy, 0.0), -1, -2) @ one_hot, -1, -2
    )
    present = np.stack([(keep & (act == g)).astype(float) @ one_hot for g in (0, 1, NEITHER)], -1)
    return n, total, present


def days_from_sums(
    day: np.ndarray,
    n: np.ndarray,
    total: np.ndarray,
    present: np.ndarray,
    min_windows: int = 4,
) -> list[TrialDays]:
    """Each pair's :class:`TrialDays` from its days' :func:`daily_sums`: a day with fewer than
    ``min_windows`` counted windows is dropped as ``too_few_windows``, one whose counted windows
    do not all have one activated coach (a plan changed within it) as ``mixed_activation``, one
    where a coach used no energy as ``no_energy``; days without a counted window are left out.

    Parameters
    ----------
    day : numpy.ndarray of int, shape (P, D)
        Each pair's service days (ordinals), ascending among those with counted windows.
    n, total, present : numpy.ndarray
        From :func:`daily_sums`, shapes (P, D), (P, D, 2) and (P, D, 3).
    min_windows : int, default 4
    """
    has = present > 0
    label = np.select([has[..., 0], has[..., 1], has[..., 2]], [0, 1, NEITHER], default=NEITHER)
    reason = np.select(
        [n < min_windows, has.sum(axis=-1) > 1, ~np.all(total > 0, axis=-1)],
        [1, 2, 3],
        default=0,
    )
    names = ("too_few_windows", "mixed_activation", "no_energy")
    some = n > 0
    good = some & (reason == 0)
    # (P, 3): each pair's days with counted windows dropped for each reason
    dropped = np.stack([(some & (reason == c)).sum(axis=-1) for c in (1, 2, 3)], -1).tolist()
    if not len(n):
        return []
    # the good days of every pair in one array each, cut into the pairs' (views)
    bounds = np.cumsum(good.sum(axis=-1))[:-1]
    day = np.broadcast_to(day, good.shape)
    parts = (
        pieces(x[good], bounds) for x in (day, total, label.astype(np.int64), n.astype(np.int64))
    )
    return [
        TrialDays(d, e, a, w, {name: k for name, k in zip(names, drop, strict=True) if k})
        for d, e, a, w, drop in zip(*parts, dropped, strict=True)
    ]


@dataclass
class TrialEstimate:
    """A pair's (or a fleet's) savings with their uncertainty; :meth:`to_dict` is what the API and
    the CLI print.

    Attributes
    ----------
    estimator : str or None
        One of :data:`ESTIMATORS`; None without any day.
    savings_pct : float or None
        The estimate. [%]
    savings_ci95_pct : list of float or None
        [low, high], 95 % interval; None with ``ci_reason``. [%]
    ci_reason : str or None
        Why there is no interval.
    naive_savings_pct : float or None
        1 − ΣE_act / ΣE_deact over the activated days, the coaches' difference included. [%]
    days : dict
        Days used: ``coach_0``, ``coach_1`` (activated), ``reference``; ``dropped`` by reason.
    standard_error_pct : float or None
        The bootstrap's standard error of the estimate. [percentage points]
    days_to_target : int or None
        Further days for the half-width to reach the target at the observed spread.
    meets_guideline_14 : bool or None
        ASHRAE Guideline 14's criterion (uncertainty at 68 % below 50 % of the savings).
    """

    estimator: str | None
    savings_pct: float | None
    savings_ci95_pct: list[float] | None
    ci_reason: str | None
    naive_savings_pct: float | None
    days: dict
    standard_error_pct: float | None = None
    days_to_target: int | None = None
    meets_guideline_14: bool | None = None

    @property
    def distinguishable(self) -> bool | None:
        """Whether the interval excludes 0 (None without an interval)."""
        if self.savings_ci95_pct is None:
            return None
        low, high = self.savings_ci95_pct
        return low > 0 or high < 0

    def to_dict(self) -> dict:
        """JSON-ready: the attributes and ``distinguishable_from_zero``."""
        return {
            "estimator": self.estimator,
            "savings_pct": self.savings_pct,
            "savings_ci95_pct": self.savings_ci95_pct,
            "savings_ci95_reason": self.ci_reason,
            "naive_savings_pct": self.naive_savings_pct,
            "days": self.days,
            "standard_error_pct": self.standard_error_pct,
            "days_to_target": self.days_to_target,
            "meets_guideline_14": self.meets_guideline_14,
            "distinguishable_from_zero": self.distinguishable,
        }


def _savings(log_ratio: np.ndarray) -> np.ndarray:
    """100 (1 − exp(ln(1 − s))) [%]."""
    return 100.0 * (1.0 - np.exp(log_ratio))


def estimate(
    days: TrialDays,
    *,
    target_half_width_pct: float = TARGET_HALF_WIDTH_PCT,
    n_resamples: int = 4999,
    seed: int = 0,
) -> TrialEstimate:
    """The savings of a pair over its service days, with a 95 % bootstrap interval (see the module
    docstring for the estimators): :func:`estimate_many` of the one pair.

    Parameters
    ----------
    days : TrialDays
        From :func:`daily`.
    target_half_width_pct : float, default 2.0
        The half-width ``days_to_target`` aims at. [percentage points]
    n_resamples : int, default 4999
        Bootstrap resamples.
    seed : int, default 0
        The bootstrap's seed (the interval is reproducible).

    Returns
    -------
    TrialEstimate
        ``savings_ci95_pct`` is None, with ``ci_reason``, for a fixed plan without reference
        days (confounded with the coaches), with fewer than :data:`MIN_GROUP_DAYS` days in a
        group, or without day-to-day spread.
    """
    return estimate_many(
        [days], target_half_width_pct=target_half_width_pct, n_resamples=n_resamples, seed=seed
    )[0]


def estimate_many(
    days_list: list[TrialDays],
    *,
    target_half_width_pct: float = TARGET_HALF_WIDTH_PCT,
    n_resamples: int = 4999,
    seed: int = 0,
    threads: int = BOOTSTRAP_THREADS,
) -> list[TrialEstimate]:
    """:func:`estimate` of every pair, the pairs with the same group sizes sharing their
    resamples, in blocks of pairs computed on ``threads`` threads.

    The interval is a bootstrap-t (Efron and Tibshirani 1993, ch. 12): each group of days is
    resampled with replacement, the resampled estimate studentized as (θ* − θ) / se*, and the
    interval of ln(1 − s) is θ − q·se at the quantiles q of that distribution
    (:mod:`.studentized`: the resamples of ``scipy.stats.bootstrap`` as counts matrices, the
    intervals equal to its to floating-point rounding, as the tests hold).

    Parameters
    ----------
    days_list : list of TrialDays
        From :func:`daily`, one per pair.
    target_half_width_pct : float, default 2.0
        The half-width ``days_to_target`` aims at. [percentage points]
    n_resamples : int, default 4999
        Bootstrap resamples.
    seed : int, default 0
        The bootstrap's seed, the same for every pair (each interval is reproducible).
    threads : int, default :data:`BOOTSTRAP_THREADS`
        Threads computing the blocks of pairs (numpy releases the interpreter's lock in the
        products, the elementwise steps and the sorts); the intervals do not depend on it.

    Returns
    -------
    list of TrialEstimate
        In the order of ``days_list``; see :func:`estimate`.

    Raises
    ------
    ValueError
        If ``n_resamples`` is below 1.
    """
    kwargs = {
        "target_half_width_pct": target_half_width_pct,
        "n_resamples": n_resamples,
        "seed": seed,
    }
    if threads <= 1:
        return estimates_later(days_list, None, **kwargs)()
    with ThreadPoolExecutor(threads, thread_name_prefix="bootstrap") as executor:
        return estimates_later(days_list, executor, **kwargs)()


def estimates_later(
    days_list: list[TrialDays],
    executor: Executor | None,
    *,
    target_half_width_pct: float = TARGET_HALF_WIDTH_PCT,
    n_resamples: int = 4999,
    seed: int = 0,
) -> Callable[[], list[TrialEstimate]]:
    """:func:`estimate_many` with the bootstraps' blocks of pairs handed to ``executor`` (None:
    computed here, now), so that the caller goes on while they run: the function returned
    waits for them and gives the estimates, in the order of ``days_list``. Raises ValueError
    if ``n_resamples`` is below 1."""
    if n_resamples < 1:
        raise ValueError("the bootstrap needs at least one resample")
    out: dict[int, TrialEstimate] = {}
    pending: dict[tuple[int, int], list[tuple[int, _Bootstrap]]] = {}
    for i, prepared in enumerate(_prepare(days_list)):
        if isinstance(prepared, TrialEstimate):
            out[i] = prepared
        else:
            sizes = (len(prepared.a), len(prepared.b))
            pending.setdefault(sizes, []).append((i, prepared))
    # each pair's products are its own: its interval does not depend on the pairs it is
    # computed with, nor on the thread
    jobs = [
        (sizes, group[k : k + _JOB_PAIRS])
        for sizes, group in pending.items()
        for k in range(0, len(group), _JOB_PAIRS)
    ]

    def quantiles(job) -> np.ndarray:
        (n_a, n_b), group = job
        return studentized.pivot_quantiles(
            np.stack([p.a for _, p in group]),
            np.stack([p.b for _, p in group]),
            np.array([p.coef for _, p in group]),
            *studentized.distinct_resamples(n_a, n_b, n_resamples, seed),
        )

    if executor is None or len(jobs) < 2:
        found, futures = [quantiles(job) for job in jobs], []
    else:
        found, futures = [], [executor.submit(quantiles, job) for job in jobs]

    def result() -> list[TrialEstimate]:
        for (_, group), q in zip(jobs, found or [f.result() for f in futures], strict=True):
            estimates = _intervals([p for _, p in group], q, target_half_width_pct)
            for (i, _), estimate in zip(group, estimates, strict=True):
                out[i] = estimate
        return [out[i] for i in range(len(days_list))]

    return result


@dataclass
class _Bootstrap:
    """A pair whose interval awaits the bootstrap: its groups of log-ratios ``a`` and ``b``, the
    effect ln(1 − s) = ``coef`` (mean a − mean b) = ``theta`` and its standard error ``se``, and
    the figures its estimate reports."""

    estimator: str
    coef: float
    a: np.ndarray
    b: np.ndarray
    theta: float
    se: float
    point: float
    naive: float | None
    counts: dict


def _prepare(days_list: list[TrialDays]) -> list[TrialEstimate | _Bootstrap]:
    """Each pair's estimate if it has no interval, else what its bootstrap needs. The pairs with
    as many days in each group are taken together, their days gathered into one array per
    group (a pair's days in their order); each row's sums are numpy's of that row alone, so
    every figure is the same to the bit as computed pair by pair."""
    lengths = np.array([len(d.day) for d in days_list], np.int64)
    energy = np.concatenate([d.energy_kwh.reshape(-1, 2) for d in days_list] or [np.zeros((0, 2))])
    activated = np.concatenate(
        [np.asarray(d.activated, np.int64) for d in days_list] or [np.zeros(0, np.int64)]
    )
    group = np.select([activated == 0, activated == 1, activated == NEITHER], [0, 1, 2], 3)
    if np.any(group == 3):
        raise ValueError("a day's activated coach must be 0, 1 or NEITHER")
    x = np.log(energy[:, 0] / energy[:, 1])
    pair = np.repeat(np.arange(len(days_list)), lengths)
    n_in = np.bincount(pair * 3 + group, minlength=3 * len(days_list)).reshape(-1, 3)
    start = np.cumsum(lengths) - lengths
    # each pair's days by group, and its activated days first (as the naive figure sums them)
    by_group = np.argsort(pair * 3 + group, kind="stable")
    on_first = np.argsort(pair * 2 + (group == 2), kind="stable")
    by_sizes: dict[tuple[int, int, int], list[int]] = {}
    for p, sizes in enumerate(map(tuple, n_in.tolist())):
        by_sizes.setdefault(sizes, []).append(p)
    out: list = [None] * len(days_list)
    for (n0, n1, n_ref), pairs in by_sizes.items():
        counts = [
            {
                "coach_0": n0,
                "coach_1": n1,
                "reference": n_ref,
                "dropped": dict(days_list[p].dropped),
            }
            for p in pairs
        ]
        if not (n0 or n1):
            for p, c in zip(pairs, counts, strict=True):
                out[p] = TrialEstimate(None, None, None, "no comparable days yet", None, c)
            continue
        first = start[pairs][:, None]
        on = on_first[first + np.arange(n0 + n1)]
        with np.errstate(all="ignore"):
            act = np.add.reduce(energy[on, activated[on]], axis=1)
            deact = np.add.reduce(energy[on, 1 - activated[on]], axis=1)
            naive = (100.0 * (1.0 - act / deact)).tolist()
        if not ((n0 and n1) or n_ref):
            reason = "fixed plan: the saving is confounded with the coaches' own difference"
            for p, c, v in zip(pairs, counts, naive, strict=True):
                out[p] = TrialEstimate("fixed_naive", v, None, reason, v, c)
            continue
        gathered = x[by_group[first + np.arange(n0 + n1 + n_ref)]]
        groups = (gathered[:, :n0], gathered[:, n0 : n0 + n1], gathered[:, n0 + n1 :])
        if n0 and n1:
            estimator, samples, coef = "crossover", (groups[0], groups[1]), 0.5
        else:
            coef = 1.0 if n0 else -1.0
            estimator, samples = "fixed_reference", (groups[0 if n0 else 1], groups[2])
        theta, se = (v.tolist() for v in studentized.effect(coef, *samples))
        few = min(g.shape[1] for g in samples) < MIN_GROUP_DAYS
        for j, p in enumerate(pairs):
            point = float(_savings(theta[j]))
            if few:
                reason = f"fewer than {MIN_GROUP_DAYS} days in a group of the {estimator} estimate"
                out[p] = TrialEstimate(estimator, point, None, reason, naive[j], counts[j])
            elif not se[j] > 0:
                reason = "no day-to-day spread"
                out[p] = TrialEstimate(estimator, point, None, reason, naive[j], counts[j])
            else:
                a, b = samples[0][j], samples[1][j]
                prepared = (theta[j], se[j], point, naive[j], counts[j])
                out[p] = _Bootstrap(estimator, coef, a, b, *prepared)
    return out


def _intervals(
    group: list[_Bootstrap], q: np.ndarray, target_half_width_pct: float
) -> list[TrialEstimate]:
    """The pairs' estimates from the quantiles ``q`` (rows, 4) of their studentized bootstrap
    distributions (the bounds of all of them computed together, each as alone)."""
    theta = np.array([p.theta for p in group])[:, None]
    se = np.array([p.se for p in group])[:, None]
    # the interval of ln(1 − s) is θ − q·se; the savings fall as ln(1 − s) rises. A resample
    # without spread studentizes to ±inf, stood for by the largest floats: bounds that
    # overflow with them are no interval either
    with np.errstate(all="ignore"):
        bounds = _savings(theta - q * se)
    out = []
    for p, (low, low68, high68, high) in zip(group, bounds.tolist(), strict=True):
        if not math.isfinite(low + high + low68 + high68):
            reason = "the bootstrap is degenerate"
            out.append(TrialEstimate(p.estimator, p.point, None, reason, p.naive, p.counts))
            continue
        n = len(p.a) + len(p.b)
        half = (high - low) / 2.0
        out.append(
            TrialEstimate(
                estimator=p.estimator,
                savings_pct=p.point,
                savings_ci95_pct=[low, high],
                ci_reason=None,
                naive_savings_pct=p.naive,
                days=p.counts,
                standard_error_pct=float(100.0 * np.exp(p.theta) * p.se),
                days_to_target=max(0, math.ceil(n * (half / target_half_width_pct) ** 2 - n)),
                meets_guideline_14=bool((high68 - low68) / 2.0 < 0.5 * abs(p.point)),
            )
        )
    return out
