"""The controller's default prediction model: fitted once on the default dataset and cached.

The Transient Predictor at the paper's controller setting — 5-min samples, a 60-min lead-in
(ρ = 12) and a 30-min horizon (T = 6) — fitted on every coach of the default fleet dataset
(:mod:`trainclimate.data.cache`), saved under ``$TRAINCLIMATE_HOME/models`` and loaded from there
afterwards.
"""

from __future__ import annotations

from pathlib import Path

from trainclimate.data import cache
from trainclimate.data.trajectory import iter_trajectories
from trainclimate.predict import TransientPredictor
from trainclimate.predict.artifact import load_predictor, save_predictor

SAMPLING_MIN, RHO, HORIZON = 5, 12, 6


def default_model_path(sampling_min: int = SAMPLING_MIN, rho: int = RHO, horizon: int = HORIZON):
    """Where the cached model of this setting lives."""
    name = f"{cache.DATASET_VERSION}-transient-{sampling_min}min-rho{rho}-T{horizon}.npz"
    return cache.home() / "models" / name


def default_predictor(
    sampling_min: int = SAMPLING_MIN, rho: int = RHO, horizon: int = HORIZON, progress=None
) -> TransientPredictor:
    """The cached Transient Predictor, fitted first if missing (the dataset too, if missing)."""
    path = default_model_path(sampling_min, rho, horizon)
    if not path.exists():
        data = cache.default_dataset(progress)
        trajectories = iter_trajectories(Path(data) / f"trajectories_{sampling_min}min.parquet")
        predictor = TransientPredictor(rho, horizon).fit(trajectories)
        save_predictor(predictor, path, validation={"note": "fitted on every coach"})
    return load_predictor(path)
