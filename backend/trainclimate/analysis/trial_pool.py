"""The fleet's savings from its trains' trial estimates (:mod:`trainclimate.analysis.trial`): a
random-effects meta-analysis (DerSimonian and Laird [1]) of the trains with an interval.

References
----------
.. [1] R. DerSimonian and N. Laird, Meta-analysis in clinical trials, Controlled Clinical Trials
   7 (1986) 177–188.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import stats

from trainclimate.analysis.trial import TrialEstimate


def pool(estimates: list[TrialEstimate]) -> dict:
    """The fleet's savings from its trains' estimates: a random-effects meta-analysis
    (DerSimonian and Laird) of those with an interval (``crossover`` and ``fixed_reference``);
    ``fixed_naive`` trains are not pooled (confounded) and are counted apart. Each train enters
    with the standard error its 95 % interval implies (half its width over 1.96), so that a
    train's small-sample uncertainty (the bootstrap-t's wider quantiles) carries into the pool
    and one train pooled alone keeps its own interval.

    Parameters
    ----------
    estimates : list of TrialEstimate

    Returns
    -------
    dict
        ``savings_pct``, ``savings_ci95_pct`` ([low, high] or None), ``savings_ci95_reason``,
        ``standard_error_pct``, ``tau2`` (between-train variance, %²), ``trains_pooled``,
        ``trains_confounded`` (fixed without reference), ``trains_without_interval``.
    """
    # each usable train's estimate and 95 % interval
    usable = [
        (e.savings_pct, ci)
        for e in estimates
        if (ci := e.savings_ci95_pct) is not None and (e.standard_error_pct or 0) > 0
    ]
    out: dict[str, Any] = {
        "trains_pooled": len(usable),
        "trains_confounded": sum(e.estimator == "fixed_naive" for e in estimates),
        "trains_without_interval": sum(e.savings_ci95_pct is None for e in estimates),
        "savings_pct": None,
        "savings_ci95_pct": None,
        "savings_ci95_reason": None,
        "standard_error_pct": None,
        "tau2": None,
    }
    if not usable:
        out["savings_ci95_reason"] = "no train has an interval yet"
        return out
    y = np.array([point for point, _ in usable])
    z = float(stats.norm.ppf(0.975))
    v = np.array([(ci[1] - ci[0]) / (2 * z) for _, ci in usable]) ** 2
    w = 1.0 / v
    fixed = float(np.sum(w * y) / np.sum(w))
    q = float(np.sum(w * (y - fixed) ** 2))
    c = float(np.sum(w) - np.sum(w**2) / np.sum(w))
    tau2 = max(0.0, (q - (len(y) - 1)) / c) if c > 0 else 0.0
    w_star = 1.0 / (v + tau2)
    mean = float(np.sum(w_star * y) / np.sum(w_star))
    se = float(math.sqrt(1.0 / np.sum(w_star)))
    out.update(
        savings_pct=mean,
        savings_ci95_pct=[mean - z * se, mean + z * se],
        standard_error_pct=se,
        tau2=tau2,
    )
    return out
