"""Multistep linear predictors of the room temperatures (paper, Section III.B and IV.A).

``TransientPredictor`` (Algorithm 1), the baselines ``SubspacePredictor`` and ``ARXPredictor``,
all with ``fit(trajectories)``, ``predict(...)`` and ``H``; ``evaluate`` (MAE per step on
held-out coaches), ``artifact`` (saved models) and ``study`` (the sensitivity studies).
"""

from collections.abc import Callable
from functools import partial

from trainclimate.predict.arx import ARXPredictor
from trainclimate.predict.base import MultistepPredictor, PredictorDataError
from trainclimate.predict.subspace import SubspacePredictor
from trainclimate.predict.transient import TransientPredictor

#: The predictors by name; ``subspace-causal`` is the ablation that explains the difference
#: between the transient and subspace predictors (see :mod:`~trainclimate.predict.subspace`).
METHODS: dict[str, Callable[..., MultistepPredictor]] = {
    "transient": TransientPredictor,
    "subspace": SubspacePredictor,
    "arx": ARXPredictor,
    "subspace-causal": partial(SubspacePredictor, causal=True),
}

__all__ = [
    "METHODS",
    "ARXPredictor",
    "MultistepPredictor",
    "PredictorDataError",
    "SubspacePredictor",
    "TransientPredictor",
]
