"""Saved predictor models: Ĥ with everything needed to use and trust it.

One ``.npz`` file (numpy's zip of arrays; read without pickle) holding ``H`` and a JSON metadata
string: the method, ρ, T, the sampling time, the signals' names and units in the order Ĥ expects
them, the SHA-256 of the training data, its size, the validation MAE per step, when and by which
version it was made. The controller and the service load it with :func:`load_predictor`.
"""

from __future__ import annotations

import io
import json
import zipfile
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from trainclimate import __version__
from trainclimate.data.trajectory import D_NAMES, U_NAMES, UNITS, Y_NAMES
from trainclimate.paths import writable_file
from trainclimate.predict import METHODS, MultistepPredictor

FORMAT = "trainclimate-predictor/1"


class ArtifactError(ValueError):
    """A model file that cannot be used (missing, corrupt, or of another format)."""


def metadata(predictor: MultistepPredictor, validation: dict | None = None) -> dict:
    """The metadata saved beside Ĥ.

    Parameters
    ----------
    predictor : MultistepPredictor
        A fitted predictor.
    validation : dict, optional
        Validation figures (e.g. MAE per step) to store with it.

    Returns
    -------
    dict
        JSON-ready: ``format``, ``method``, ``rho``, ``horizon``, ``sampling_min`` (min), the
        signals' names and units in the order Ĥ expects them, Ĥ's layout, the training data's
        SHA-256 and size, ``validation``, ``created_utc`` (ISO 8601, UTC) and the package
        version.
    """
    return {
        "format": FORMAT,
        "method": predictor.method,
        "rho": predictor.rho,
        "horizon": predictor.horizon,
        "sampling_min": predictor.sampling_min,
        "signals": {
            "y": [{"name": n, "unit": UNITS[n]} for n in Y_NAMES],
            "u": [{"name": n, "unit": UNITS[n]} for n in U_NAMES],
            "d": [{"name": n, "unit": UNITS[n]} for n in D_NAMES],
        },
        "h_layout": "y_f (3T) = H @ [z_p (9 rho: y,u,d per step, oldest first); u_f (T); d_f (5T)]",
        "training": {
            "data_sha256": predictor.data_hash,
            "trajectories": predictor.n_trajectories,
            "hankel_columns": predictor.n_columns,
        },
        "validation": validation or {},
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "trainclimate_version": __version__,
    }


def save_predictor(
    predictor: MultistepPredictor, path: str | Path, validation: dict | None = None
) -> Path:
    """Write a fitted predictor (and its validation figures) to a model file.

    Parameters
    ----------
    predictor : MultistepPredictor
        A fitted predictor.
    path : str or pathlib.Path
        Destination ``.npz`` file.
    validation : dict, optional
        Validation figures to store in the metadata.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    path = writable_file(path, "the model file", hint="choose another path")
    tmp = path.with_name(path.name + ".partial")
    tmp.write_bytes(predictor_bytes(predictor, validation))
    tmp.replace(path)  # whole or not at all, for a reader in another process
    return path


def predictor_bytes(predictor: MultistepPredictor, validation: dict | None = None) -> bytes:
    """A fitted predictor as the bytes of its model file (to store it in a database).

    Parameters
    ----------
    predictor, validation
        As in :func:`metadata`: the fitted predictor and the validation figures to store.

    Returns
    -------
    bytes
        An ``.npz`` archive holding ``H`` and the JSON metadata (:func:`metadata`).

    Raises
    ------
    RuntimeError
        If the predictor is not fitted.
    """
    buffer = io.BytesIO()
    meta = json.dumps(metadata(predictor, validation))
    np.savez(buffer, H=predictor.require_fit(), metadata=np.array(meta))
    return buffer.getvalue()


def load_predictor_bytes(data: bytes) -> MultistepPredictor:
    """Load a predictor from the bytes of a model file, as :func:`load_predictor`.

    Parameters
    ----------
    data : bytes
        The content of a file written by :func:`save_predictor` (or :func:`predictor_bytes`).

    Returns
    -------
    MultistepPredictor

    Raises
    ------
    ArtifactError
        If the bytes are not a valid model file.
    """
    return _load(io.BytesIO(data), "the stored model")


def load_predictor(path: str | Path) -> MultistepPredictor:
    """Load a predictor from a file written by :func:`save_predictor`.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.npz`` model file.

    Returns
    -------
    MultistepPredictor
        Ready to :meth:`~MultistepPredictor.predict`, of the saved method, ρ and T; its
        metadata is in ``.metadata``.

    Raises
    ------
    ArtifactError
        If the file is missing, corrupt, of another format, or its Ĥ has the wrong shape or
        non-finite entries.
    """
    return _load(Path(path), str(path))


def _load(source, path: str) -> MultistepPredictor:
    try:
        with np.load(source, allow_pickle=False) as data:
            H = np.array(data["H"], dtype=float)
            meta = json.loads(str(data["metadata"]))
    except FileNotFoundError:
        raise ArtifactError(f"model file not found: {path}") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ArtifactError(f"{path} is not a trainclimate model file: {exc}") from None
    if not isinstance(meta, dict):
        raise ArtifactError(f"{path}: the metadata is not a JSON object")
    if meta.get("format") != FORMAT or meta.get("method") not in METHODS:
        raise ArtifactError(f"{path}: unsupported model format {meta.get('format')!r}")
    try:
        predictor = METHODS[meta["method"]](int(meta["rho"]), int(meta["horizon"]))
        training = meta["training"]
        data_hash, n_trajectories = training["data_sha256"], training["trajectories"]
        n_columns = training["hankel_columns"]
    except (KeyError, TypeError, ValueError) as exc:
        raise ArtifactError(f"{path}: incomplete model metadata ({exc!r})") from None
    if H.shape != (3 * predictor.horizon, predictor.n_inputs) or not np.all(np.isfinite(H)):
        expected = (3 * predictor.horizon, predictor.n_inputs)
        raise ArtifactError(f"{path}: H has shape {H.shape}, expected {expected}, all finite")
    predictor.H = H
    predictor.sampling_min = meta.get("sampling_min")
    predictor.data_hash = data_hash
    predictor.n_trajectories = n_trajectories
    predictor.n_columns = n_columns
    predictor.metadata = meta
    return predictor
