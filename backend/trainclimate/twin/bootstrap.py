"""The 95 % intervals of a twin's fitted knobs and of its held-out energy error: a bootstrap over
the training days resampled whole, each replicate re-fitted from the optimum by damped
Gauss–Newton steps; and the warnings of intervals that are wide, or far wider than the
Jacobian's standard errors say (docs/model.md, "Calibration").
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from trainclimate.data.trajectory import Trajectory
from trainclimate.twin.fit import MAX_SETS, Problem
from trainclimate.twin.replay import Replay, residual_columns, simulate
from trainclimate.twin.validation import errors, local_day

#: Bootstrap replicates by default, and the Gauss–Newton steps of each re-fit.
BOOTSTRAP_REPLICATES, BOOTSTRAP_ITERATIONS = 20, 2
#: Fewest days a bootstrap over days resamples: of one day every replicate is that day, an
#: interval of zero width whatever the day says.
MIN_BOOTSTRAP_DAYS = 2
#: A 95 % interval reaching beyond this share of its value on a side is wide; one this many
#: times wider than 1.96 standard errors says the Jacobian understates the uncertainty.
WIDE_INTERVAL, UNDERSTATED = 0.25, 3.0


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


def fit_intervals(
    problem: Problem,
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


def interval_warnings(fitted: dict[str, dict]) -> list[str]:
    """Warnings of the fitted values whose 95 % interval is wide (beyond
    :data:`WIDE_INTERVAL` of the value on either side) or far wider than the Jacobian's
    standard error says (half-width above :data:`UNDERSTATED` × 1.96 σ: the days disagree,
    which a model structure the knobs do not span does), and those whose interval leaves out
    the fitted value itself (the re-fits on resampled days settle elsewhere: the fit did not
    reach the optimum those days have, or has several). Where the days disagree on any knob,
    one more warning says what that means for all of them: the logs' coach may differ from the
    model in ways no knob spans, and each fitted value may carry part of it."""
    out, disagree = [], []
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
            disagree.append(n)
            out.append(
                f"{n}: the days disagree: 95 % interval [{low:.4g}, {high:.4g}] is over "
                f"{UNDERSTATED:g} times what its standard error {f['std']:.2g} says"
            )
    if disagree:
        out.append(
            f"the days disagree on {', '.join(disagree)}: the logs' coach may differ from the "
            "model in ways no knob spans, and then every fitted value may carry part of that "
            "difference (a knob standing in for what the model lacks), its interval missing "
            "the coach's own value"
        )
    return out
