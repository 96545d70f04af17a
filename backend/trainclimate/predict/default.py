"""The default prediction models of the controller and the service, fitted once and cached.

The Transient Predictor at the paper's controller setting — 5-min samples, a 60-min lead-in
(ρ = 12) and a 30-min horizon (T = 6) — fitted on every coach of a generated fleet dataset
(:mod:`trainclimate.data.cache`), saved under ``$TRAINCLIMATE_HOME/models`` and loaded from there
afterwards:

- the *default* model, on the full default dataset (≈ 3–6 min to build once);
- the *quick* model, on the quick dataset (≈ 1 min once), which the service starts with on a
  machine that has no default model yet (:func:`startup_predictor`). Its prediction error beside
  the default model's is in ``docs/service.md``.
"""

from __future__ import annotations

from pathlib import Path

from trainclimate.data import cache
from trainclimate.data.trajectory import iter_trajectories
from trainclimate.paths import home, writable_dir
from trainclimate.predict import MultistepPredictor, TransientPredictor
from trainclimate.predict.artifact import load_predictor, save_predictor
from trainclimate.predict.setting import HORIZON, RHO, SAMPLING_MIN


def model_store() -> Path:
    """The directory of the cached models, ``$TRAINCLIMATE_HOME/models`` (created if missing)."""
    return writable_dir(home() / "models", "the model store")


def default_model_path(sampling_min: int = SAMPLING_MIN, rho: int = RHO, horizon: int = HORIZON):
    """Where the cached default model of this setting lives."""
    name = f"{cache.DATASET_VERSION}-transient-{sampling_min}min-rho{rho}-T{horizon}.npz"
    return home() / "models" / name


def quick_model_path() -> Path:
    """Where the cached quick model lives."""
    name = f"{cache.DATASET_VERSION}-quick{cache.QUICK_DAYS}d-transient-{SAMPLING_MIN}min"
    return home() / "models" / f"{name}-rho{RHO}-T{HORIZON}.npz"


def default_predictor(
    sampling_min: int = SAMPLING_MIN, rho: int = RHO, horizon: int = HORIZON, progress=None
) -> MultistepPredictor:
    """The cached default Transient Predictor, fitted first if missing (the dataset too).

    ``progress(stage, done, total)`` is called while the dataset is built.
    """
    path = default_model_path(sampling_min, rho, horizon)
    if not path.exists():
        data = cache.default_dataset(progress)
        with cache.exclusive(model_store() / path.name):
            if not path.exists():
                _fit(data, sampling_min, rho, horizon, path, "every coach of the default dataset")
    return load_predictor(path)


def quick_predictor(progress=None) -> MultistepPredictor:
    """The cached quick Transient Predictor (the paper's controller setting, fitted on the quick
    dataset), fitted first if missing (the dataset too); ``progress`` as for
    :func:`default_predictor`."""
    path = quick_model_path()
    if not path.exists():
        data = cache.quick_dataset(progress)
        with cache.exclusive(model_store() / path.name):
            if not path.exists():
                _fit(data, SAMPLING_MIN, RHO, HORIZON, path, "every coach of the quick dataset")
    return load_predictor(path)


def startup_predictor(progress=None) -> tuple[MultistepPredictor, str]:
    """The model a service without one starts with: the default model if it is cached, else the
    quick model (built if missing). Returns ``(predictor, "default" | "quick")``."""
    if default_model_path().exists():
        return load_predictor(default_model_path()), "default"
    return quick_predictor(progress), "quick"


def _fit(data: Path, sampling_min: int, rho: int, horizon: int, path: Path, note: str) -> None:
    trajectories = iter_trajectories(Path(data) / f"trajectories_{sampling_min}min.parquet")
    predictor = TransientPredictor(rho, horizon).fit(trajectories)
    model_store()
    save_predictor(predictor, path, validation={"note": f"fitted on {note}"})
