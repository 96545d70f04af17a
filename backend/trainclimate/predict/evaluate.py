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
    """The validation coaches: the last quarter (rounded up) of each campaign's coaches.

    In sorted order — 2 of the 8 Winter/Spring and 1 of the 4 Summer coaches, as in the paper's
    split (6 + 3 train, 2 + 1 validate). A campaign of one coach keeps it for training.

    Parameters
    ----------
    trajectories : sequence of Trajectory
        Trajectories with ``campaign`` and ``coach`` labels.

    Returns
    -------
    list of str
        The held-out coaches, sorted.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section IV.A.
    """
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
    """Split trajectories by coach into training and validation sets.

    Parameters
    ----------
    trajectories : sequence of Trajectory
        All trajectories.
    validation : sequence of str, optional
        Validation coaches (default: :func:`held_out_coaches`).

    Returns
    -------
    train, validation : list of Trajectory
    """
    held = set(held_out_coaches(trajectories) if validation is None else validation)
    train = [t for t in trajectories if t.coach not in held]
    val = [t for t in trajectories if t.coach in held]
    return train, val


def validation_windows(trajectories: Sequence[Trajectory], depth: int) -> np.ndarray:
    """Every window of ``depth`` samples of the trajectories.

    Parameters
    ----------
    trajectories : sequence of Trajectory
        The trajectories; windows never straddle two of them.
    depth : int
        Window length ρ + T.

    Returns
    -------
    numpy.ndarray of shape (m, depth·9)
        One window per row (:func:`~trainclimate.predict.hankel.windows`).
    """
    parts = [windows(stacked(t), depth) for t in trajectories]
    parts = [p for p in parts if len(p)]
    return np.concatenate(parts) if parts else np.empty((0, depth * NZ))


def mae_per_step(predictor: MultistepPredictor, trajectories: Sequence[Trajectory]) -> np.ndarray:
    """Mean absolute prediction error of each step and deck over every validation window.

    Parameters
    ----------
    predictor : MultistepPredictor
        A fitted predictor.
    trajectories : sequence of Trajectory
        Validation trajectories.

    Returns
    -------
    numpy.ndarray of shape (T, 3)
        MAE of step 1 … T for the decks up, mid, low. [K]

    Raises
    ------
    PredictorDataError
        If no trajectory has the ρ + T samples of one window.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section IV.A.
    """
    depth = predictor.rho + predictor.horizon
    w = validation_windows(trajectories, depth)
    if not len(w):
        raise PredictorDataError(f"no validation trajectory has the {depth} samples of one window")
    y_true = w.reshape(len(w), depth, NZ)[:, predictor.rho :, :NY]
    return np.abs(predictor.predict_windows(w) - y_true).mean(axis=0)


def causality_violation(predictor: MultistepPredictor) -> float:
    """How far Ĥ is from causal: its largest entry mapping u(t+j) or d(t+j) to y(t+i), j ≥ i.

    Parameters
    ----------
    predictor : MultistepPredictor
        A fitted predictor.

    Returns
    -------
    float
        The largest such |Ĥ| entry; 0 for a causal model (the Transient Predictor). [K per
        signal unit]
    """
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
    """Read the trajectories of one sampling time and split them by coach.

    Parameters
    ----------
    data_dir : str or pathlib.Path
        Directory holding ``trajectories_{sampling_min}min.parquet``.
    sampling_min : int
        Sampling time, 1, 5 or 10. [min]

    Returns
    -------
    train, validation : list of Trajectory
        As :func:`split_by_coach`.

    Raises
    ------
    PredictorDataError
        If the file does not exist.
    """
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
    """Fit a predictor on the training coaches and measure it on the held-out ones.

    Parameters
    ----------
    method : str
        A key of :data:`~trainclimate.predict.METHODS`.
    sampling_min : int
        Sampling time. [min]
    rho, horizon : int
        Lead-in ρ and horizon T.
    data_dir : str or pathlib.Path
        Directory of the trajectory files (unused when ``split`` is given).
    split : (list of Trajectory, list of Trajectory), optional
        An already loaded (training, validation) pair to reuse.

    Returns
    -------
    predictor : MultistepPredictor
        The fitted predictor.
    result : dict
        JSON-ready: ``mae_per_step_c`` (T, mean over decks, K), ``mae_per_step_deck_c``
        (T × 3, K), their mean ``mae_mean_c`` (K), ``prediction_minutes``,
        ``causality_violation``, the coaches, trajectories and windows it was fitted and
        measured on, ``fit_seconds`` (s) and ``data_hash``.

    Raises
    ------
    ValueError
        For an unknown method.
    PredictorDataError
        If the data are missing, too few or rank-deficient.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section IV.A.
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
