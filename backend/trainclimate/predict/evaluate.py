"""Model evaluation of the paper's Section IV.A: MAE per prediction step on held-out coaches.

The split follows the paper: of the 8 Winter/Spring and 4 Summer coaches, 6 + 3 train the model
and 2 + 1 validate it — here the last quarter of each campaign's coaches, in sorted order, are
held out (:func:`split_by_coach`). The MAE is taken over every sliding window of ρ + T samples of
the validation trajectories: the predictor sees the window's first ρ samples and its future u and
d (measured, as in the paper), and predicts the T outputs after them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from trainclimate.data.trajectory import Trajectory, read_trajectories
from trainclimate.predict import METHODS, MultistepPredictor, PredictorDataError
from trainclimate.predict.hankel import NY, NZ, stacked, windows


def held_out_coaches(trajectories: Sequence[Trajectory]) -> list[str]:
    """The validation coaches: the last quarter (rounded up) of each campaign's coaches in
    sorted order — 2 of the 8 Winter/Spring and 1 of the 4 Summer coaches."""
    by_campaign: dict[str, set[str]] = {}
    for t in trajectories:
        by_campaign.setdefault(t.campaign, set()).add(t.coach)
    held = []
    for coaches in by_campaign.values():
        ordered = sorted(coaches)
        n_val = math.ceil(len(ordered) / 4) if len(ordered) > 1 else 0
        held += ordered[len(ordered) - n_val :]
    return sorted(held)


def split_by_coach(
    trajectories: Sequence[Trajectory], validation: Sequence[str] | None = None
) -> tuple[list[Trajectory], list[Trajectory]]:
    """(training, validation) trajectories, split by coach (default: :func:`held_out_coaches`)."""
    held = set(held_out_coaches(trajectories) if validation is None else validation)
    train = [t for t in trajectories if t.coach not in held]
    val = [t for t in trajectories if t.coach in held]
    return train, val


def validation_windows(trajectories: Sequence[Trajectory], depth: int) -> np.ndarray:
    """Every window of ``depth`` samples of the trajectories, (m, depth·9)."""
    parts = [windows(stacked(t), depth) for t in trajectories]
    parts = [p for p in parts if len(p)]
    return np.concatenate(parts) if parts else np.empty((0, depth * NZ))


def mae_per_step(predictor: MultistepPredictor, trajectories: Sequence[Trajectory]) -> np.ndarray:
    """Mean absolute error (K) of each prediction step and deck, (T, 3), over every window."""
    depth = predictor.rho + predictor.horizon
    w = validation_windows(trajectories, depth)
    if not len(w):
        raise PredictorDataError(f"no validation trajectory has the {depth} samples of one window")
    y_true = w.reshape(len(w), depth, NZ)[:, predictor.rho :, :NY]
    return np.abs(predictor.predict_windows(w) - y_true).mean(axis=0)


def causality_violation(predictor: MultistepPredictor) -> float:
    """Largest |Ĥ| entry mapping u(t+j) or d(t+j) to y(t+i) with j ≥ i (0 for a causal model)."""
    H = predictor.require_fit()
    rho, T = predictor.rho, predictor.horizon
    worst = 0.0
    for i in range(1, T + 1):
        rows = slice(NY * (i - 1), NY * i)
        for j in range(i, T + 1):
            u_col = NZ * rho + (j - 1)
            d_cols = slice(NZ * rho + T + 5 * (j - 1), NZ * rho + T + 5 * j)
            worst = max(
                worst, float(np.abs(H[rows, u_col]).max()), float(np.abs(H[rows, d_cols]).max())
            )
    return worst


def load_split(data_dir: str | Path, sampling_min: int):
    """The trajectories of one sampling time under ``data_dir``, split by coach."""
    path = Path(data_dir) / f"trajectories_{sampling_min}min.parquet"
    if not path.exists():
        raise PredictorDataError(f"no {sampling_min}-min trajectories in {data_dir} ({path.name})")
    return split_by_coach(read_trajectories(path))


def evaluate(
    method: str,
    sampling_min: int,
    rho: int,
    horizon: int,
    data_dir: str | Path,
    split=None,
) -> tuple[MultistepPredictor, dict]:
    """Fit ``method`` on the training coaches and measure it on the held-out ones.

    Returns the fitted predictor and a JSON-ready dict with ``mae_per_step_c`` (T, mean over
    decks), ``mae_per_step_deck_c`` (T × 3), their mean ``mae_mean_c`` and what it was fitted
    and measured on. ``split`` reuses an already loaded (training, validation) pair.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    train, val = split if split is not None else load_split(data_dir, sampling_min)
    t0 = time.perf_counter()
    predictor = METHODS[method](rho, horizon).fit(train)
    fit_s = time.perf_counter() - t0
    mae = mae_per_step(predictor, val)
    return predictor, {
        "method": method,
        "sampling_min": sampling_min,
        "rho": rho,
        "horizon": horizon,
        "mae_per_step_c": mae.mean(axis=1).tolist(),
        "mae_per_step_deck_c": mae.tolist(),
        "mae_mean_c": float(mae.mean()),
        "prediction_minutes": [sampling_min * (k + 1) for k in range(horizon)],
        "causality_violation": causality_violation(predictor),
        "train_coaches": sorted({t.coach for t in train}),
        "validation_coaches": sorted({t.coach for t in val}),
        "train_trajectories": len(train),
        "validation_trajectories": len(val),
        "validation_windows": len(validation_windows(val, rho + horizon)),
        "hankel_columns": predictor.n_columns,
        "fit_seconds": fit_s,
        "data_hash": predictor.data_hash,
    }
