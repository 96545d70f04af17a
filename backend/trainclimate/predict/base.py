"""What every multistep linear predictor shares: the model y_f = Ĥ [z_p; u_f; d_f] (paper, Eq. (2)).

With ρ lead-in samples and horizon T:

- z_p = [y(t-ρ+1), u(t-ρ+1), d(t-ρ+1), …, y(t), u(t), d(t)] (9ρ values, oldest first);
- u_f = [u(t+1), …, u(t+T)] (T values), d_f = [d(t+1), …, d(t+T)] (5T values);
- y_f = [y(t+1), …, y(t+T)] (3T values).

Ĥ is 3T × (9ρ + 6T). The predictors fit it from trajectories streamed a chunk of windows at a
time (:mod:`~trainclimate.predict.hankel`, :mod:`~trainclimate.predict.streaming_lq`), with each
signal divided by a fixed physical scale (1 K for temperatures, 100 W/m² for irradiance, 10 % for
occupancy, 10 km/h for speed) so the factorisation and its rank test see comparable numbers; Ĥ is
returned in the signals' own units.
"""

from __future__ import annotations

import hashlib
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator

import numpy as np

from trainclimate.predict.hankel import ND, NU, NY, NZ, Z_SIGNALS, TrajectoryLike, column_chunks
from trainclimate.predict.streaming_lq import StreamingLQ

#: Physical scale of each z signal (y up, mid, low, u, T_amb, Q_Gt, Q_Gs, P, V).
Z_SCALE = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 100.0, 100.0, 10.0, 10.0])
#: A row of 𝒵 whose part not explained by the earlier rows is below this fraction of its norm is
#: treated as a linear combination of them (constant, zero or collinear signal).
COLLINEAR_TOL = 1e-7


class PredictorDataError(ValueError):
    """Too little, or too uniform, training data for a well-posed fit."""


class _Tracker:
    """Iterates over training trajectories while checking them, counting them and hashing their
    data (SHA-256 of every y, u, d in order), so a single streaming pass does it all."""

    def __init__(self, trajectories: Iterable[TrajectoryLike], depth: int):
        self.source = trajectories
        self.depth = depth
        self.count = 0
        self.usable = 0
        self.samples = 0
        self.sampling_min: float | None = None
        self._hash = hashlib.sha256()

    def __iter__(self) -> Iterator[TrajectoryLike]:
        for traj in self.source:
            step = getattr(traj, "sampling_min", None)
            if step is not None:
                if self.sampling_min is None:
                    self.sampling_min = float(step)
                elif float(step) != self.sampling_min:
                    raise PredictorDataError(
                        f"trajectories of different sampling times ({self.sampling_min:g} and "
                        f"{float(step):g} min) cannot train one predictor"
                    )
            n = len(np.asarray(traj.y))
            self.count += 1
            self.samples += n
            self.usable += n >= self.depth
            for name in ("y", "u", "d"):
                self._hash.update(np.ascontiguousarray(getattr(traj, name), dtype=float).tobytes())
            yield traj

    @property
    def digest(self) -> str:
        return self._hash.hexdigest()


class MultistepPredictor(ABC):
    """Base of :class:`TransientPredictor`, :class:`SubspacePredictor` and :class:`ARXPredictor`.

    ``rho`` lead-in samples, ``horizon`` prediction steps T. After :meth:`fit`: :attr:`H`
    (3T × (9ρ + 6T)), :attr:`sampling_min` (from the trajectories, if they say), and the
    training data's size and SHA-256 (:attr:`data_hash`).
    """

    method = "base"

    def __init__(self, rho: int, horizon: int, *, chunk: int = 4096):
        for name, value in (("rho", rho), ("horizon", horizon), ("chunk", chunk)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self.rho = int(rho)
        self.horizon = int(horizon)
        self.chunk = int(chunk)
        self.H: np.ndarray | None = None
        self.sampling_min: float | None = None
        self.n_trajectories = 0
        self.n_columns = 0
        self.data_hash = ""
        #: what a saved model file said about it (see :mod:`~trainclimate.predict.artifact`)
        self.metadata: dict = {}

    # --- fitting ---------------------------------------------------------------------------
    @abstractmethod
    def fit(self, trajectories: Iterable[TrajectoryLike]) -> MultistepPredictor:
        """Fit Ĥ from trajectories (any objects with ``y``, ``u``, ``d`` arrays on one grid)."""

    def _factor(
        self, trajectories: Iterable[TrajectoryLike], depth: int, order: np.ndarray
    ) -> np.ndarray:
        """The lower-triangular L of the scaled 𝒵 (window depth ``depth``), its rows permuted
        to ``order`` (indices into the depth·9 window entries), by streaming QR."""
        tracker = _Tracker(trajectories, depth)
        scale = np.tile(Z_SCALE, depth)[order]
        lq = StreamingLQ(len(order))
        for block in column_chunks(tracker, depth, self.chunk):
            lq.add(block[:, order] / scale)
        self.sampling_min = tracker.sampling_min
        self.n_trajectories = tracker.count
        self.n_columns = lq.n_columns
        self.data_hash = tracker.digest
        if lq.n_columns < len(order):
            raise PredictorDataError(
                f"too little data for {self.method} with ρ = {self.rho}, T = {self.horizon}: "
                f"the fit needs at least {len(order)} windows of {depth} consecutive samples "
                f"(one more window per extra sample of a trajectory at least {depth} long); "
                f"got {lq.n_columns} from {tracker.usable} of {tracker.count} trajectories "
                f"({tracker.samples} samples)"
            )
        L = lq.L
        self._check_rank(L, depth, order)
        return L

    def _check_rank(self, L: np.ndarray, depth: int, order: np.ndarray) -> None:
        """Raise :class:`PredictorDataError` naming the first row of 𝒵 that is (numerically) a
        linear combination of the rows before it.

        Future outputs are exempt: one the earlier rows explain exactly is perfectly predictable
        (noise-free data of order ≤ ρ), not a defect of the data, and Ĥ stays unique."""
        norms = np.linalg.norm(L, axis=1)
        ratio = np.abs(np.diag(L)) / np.where(norms > 0, norms, 1.0)
        future_y = (order >= NZ * self.rho) & (order % NZ < NY)
        bad = np.flatnonzero(((ratio < COLLINEAR_TOL) | (norms == 0)) & ~future_y)
        if bad.size:
            names = _window_names(self.rho, depth)
            culprit = names[order[bad[0]]]
            raise PredictorDataError(
                f"the training data is rank-deficient: {culprit} is constant, zero or a linear "
                f"combination of earlier signals ({bad.size} such row(s) of the Hankel matrix); "
                f"the fit needs data in which every signal varies independently — more "
                f"trajectories, from varied days and operation"
            )

    # --- predicting ------------------------------------------------------------------------
    @property
    def n_inputs(self) -> int:
        """Length of [z_p; u_f; d_f]: 9ρ + 6T."""
        return NZ * self.rho + (NU + ND) * self.horizon

    def require_fit(self) -> np.ndarray:
        if self.H is None:
            raise RuntimeError(f"the {self.method} predictor is not fitted (call fit first)")
        return self.H

    def regressor(self, y_past, u_past, d_past, u_future, d_future) -> np.ndarray:
        """[z_p; u_f; d_f] from the contract's arrays (shapes checked; see :meth:`predict`)."""
        rho, T = self.rho, self.horizon
        arrays = {}
        for name, value, shape in (
            ("y_past", y_past, (rho, NY)),
            ("u_past", u_past, (rho, NU)),
            ("d_past", d_past, (rho, ND)),
            ("u_future", u_future, (T, NU)),
            ("d_future", d_future, (T, ND)),
        ):
            arr = np.asarray(value, dtype=float)
            if arr.ndim == 1 and shape[1] == 1 and arr.shape == (shape[0],):
                arr = arr[:, None]
            if arr.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
            arrays[name] = arr
        z_p = np.hstack([arrays["y_past"], arrays["u_past"], arrays["d_past"]]).ravel()
        return np.concatenate([z_p, arrays["u_future"].ravel(), arrays["d_future"].ravel()])

    def predict(self, y_past, u_past, d_past, u_future, d_future) -> np.ndarray:
        """y(t+1) … y(t+T) as a (T, 3) array.

        ``y_past`` (ρ×3), ``u_past`` (ρ×1), ``d_past`` (ρ×5): samples t−ρ+1 … t, oldest first
        (``u_past[-1]`` is applied from t to t+1); ``u_future`` (T×1), ``d_future`` (T×5):
        samples t+1 … t+T.
        """
        H = self.require_fit()
        x = self.regressor(y_past, u_past, d_past, u_future, d_future)
        return (H @ x).reshape(self.horizon, NY)

    def predict_windows(self, windows: np.ndarray) -> np.ndarray:
        """Predictions for many (ρ+T)·9 Hankel windows at once → (m, T, 3).

        Each window row holds z over t−ρ+1 … t+T (see :mod:`~trainclimate.predict.hankel`); the
        future y in it is ignored.
        """
        H = self.require_fit()
        rho, T = self.rho, self.horizon
        w = windows.reshape(len(windows), rho + T, NZ)
        x = np.concatenate(
            [
                w[:, :rho].reshape(len(w), -1),
                w[:, rho:, NY],
                w[:, rho:, NY + NU :].reshape(len(w), -1),
            ],
            axis=1,
        )
        return (x @ H.T).reshape(len(w), T, NY)


def _window_names(rho: int, depth: int) -> list[str]:
    """Readable name of each entry of a window of ``depth`` samples whose ρ-th is time t."""
    names = []
    for step in range(depth):
        offset = step - (rho - 1)
        label = "t" if offset == 0 else f"t{offset:+d}"
        names += [f"{signal} at {label}" for signal in Z_SIGNALS]
    return names


def future_columns(rho: int, horizon: int) -> tuple[list[int], list[int], list[int]]:
    """Indices, in a (ρ+T)·9 window, of y_f, u_f and d_f (each stacked step by step)."""
    base = NZ * rho
    y = [base + NZ * j + k for j in range(horizon) for k in range(NY)]
    u = [base + NZ * j + NY for j in range(horizon)]
    d = [base + NZ * j + NY + NU + k for j in range(horizon) for k in range(ND)]
    return y, u, d


def unscale_h(H_scaled: np.ndarray, rho: int, horizon: int) -> np.ndarray:
    """Ĥ in the signals' units from Ĥ fitted on scaled signals (y's scale is 1 K)."""
    _, u, d = future_columns(rho, horizon)
    scale = np.tile(Z_SCALE, rho + horizon)
    col_scale = np.concatenate([scale[: NZ * rho], scale[u], scale[d]])
    return H_scaled / col_scale
