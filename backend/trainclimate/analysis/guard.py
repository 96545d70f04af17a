"""The guard's rule, free of any database: when a pair's own trial estimate says the layer costs
energy, and how the figures it decided on are kept and told.

The estimate is a :class:`trainclimate.analysis.trial.TrialEstimate` over a pair's recent service
days. It *costs energy* only when its 95 % interval lies entirely below 0; ``guard_days``
consecutive daily evaluations that do trip the guard, and the pair goes back to T_rule with the
reason :data:`REASON` until an operator re-enables the layer. An interval containing 0, or no
interval at all (a confounded estimate), never counts. The service keeps the state per train
(:mod:`trainclimate.service.store.guard`).
"""

from __future__ import annotations

from datetime import datetime

import pandas as pd

from trainclimate.analysis import trial

#: The reason code of a setpoint the guard handed back to T_rule.
REASON = "costing_energy"
#: Default: consecutive daily evaluations with the interval below 0 before the guard trips.
GUARD_DAYS = 3
#: The fewest consecutive evaluations that may be set.
MIN_GUARD_DAYS = 1


def costs_energy(estimate: trial.TrialEstimate) -> bool:
    """Whether the estimate says the layer costs energy with confidence: a 95 % interval,
    entirely below 0."""
    ci = estimate.savings_ci95_pct
    return ci is not None and ci[1] < 0.0


def step(below_days: int, costs: bool, guard_days: int) -> tuple[int, bool]:
    """One daily evaluation: the consecutive evaluations with the interval below 0 after it
    (reset to 0 by one that is not), and whether the guard trips (at least ``guard_days``)."""
    below = below_days + 1 if costs else 0
    return below, below >= guard_days


def figures(estimate: trial.TrialEstimate, start: datetime, end: datetime) -> dict:
    """An evaluation's figures as stored and shown: the estimate, its interval, the estimator,
    the service days it used and the range it covered (ISO 8601, UTC)."""
    d = estimate.days
    return {
        "savings_pct": estimate.savings_pct,
        "savings_ci95_pct": estimate.savings_ci95_pct,
        "savings_ci95_reason": estimate.ci_reason,
        "estimator": estimate.estimator,
        "days": d.get("coach_0", 0) + d.get("coach_1", 0) + d.get("reference", 0),
        "start": pd.Timestamp(start).isoformat(),
        "end": pd.Timestamp(end).isoformat(),
    }


def describe(f: dict) -> str:
    """An evaluation's figures in words."""
    if f.get("savings_pct") is None:
        return "no estimate yet"
    ci = f.get("savings_ci95_pct")
    interval = f" (95 % CI {ci[0]:.1f} to {ci[1]:.1f})" if ci else ""
    return f"{f['savings_pct']:.1f} %{interval} over {f['days']} service days ({f['estimator']})"
