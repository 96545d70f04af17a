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
    """Base of the multistep linear predictors y_f = Ĥ [z_p; u_f; d_f] (Eq. (2)).

    Subclassed by :class:`TransientPredictor`, :class:`SubspacePredictor` and
    :class:`ARXPredictor`, which implement :meth:`fit`.

    Parameters
    ----------
    rho : int
        Number of lead-in samples ρ (≥ 1).
    horizon : int
        Number of prediction steps T (≥ 1).
    chunk : int, default 4096
        Hankel windows streamed into the factorisation at a time (memory, not results).

    Attributes
    ----------
    method : str
        Name of the method, a key of :data:`~trainclimate.predict.METHODS`.
    H : numpy.ndarray of shape (3T, 9ρ + 6T) or None
        Ĥ in the signals' own units (°C, W/m², % of seats, km/h), None before :meth:`fit`.
    sampling_min : float or None
        Sampling time of the training trajectories, if they say. [min]
    n_trajectories, n_columns : int
        Training trajectories and Hankel columns (windows) used by the fit.
    data_hash : str
        SHA-256 of the training data (every y, u, d in order).
    metadata : dict
        What a saved model file said about it (:mod:`~trainclimate.predict.artifact`).

    Raises
    ------
    ValueError
        If ``rho``, ``horizon`` or ``chunk`` is not a positive integer.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.B, Eq. (2).
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
        """Fit Ĥ from training trajectories in one streaming pass.

        Parameters
        ----------
        trajectories : iterable of TrajectoryLike
            Objects with ``y`` (n×3, °C), ``u`` (n×1, °C) and ``d`` (n×5) arrays, each on one
            uniform grid, all of one sampling time.

        Returns
        -------
        MultistepPredictor
            ``self``, fitted.

        Raises
        ------
        PredictorDataError
            If the data are too few for ρ + T, rank-deficient, or of mixed sampling times.
        ValueError
            If a trajectory is malformed or holds NaN or infinite values.
        """

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
        """Length of the regressor [z_p; u_f; d_f], 9ρ + 6T."""
        return NZ * self.rho + (NU + ND) * self.horizon

    def require_fit(self) -> np.ndarray:
        """Return Ĥ, insisting the predictor is fitted.

        Returns
        -------
        numpy.ndarray of shape (3T, 9ρ + 6T)
            :attr:`H`.

        Raises
        ------
        RuntimeError
            If the predictor is not fitted.
        """
        if self.H is None:
            raise RuntimeError(f"the {self.method} predictor is not fitted (call fit first)")
        return self.H

    def regressor(self, y_past, u_past, d_past, u_future, d_future) -> np.ndarray:
        """Assemble the regressor [z_p; u_f; d_f] from the past and future samples.

        Parameters
        ----------
        y_past : array-like of shape (ρ, 3)
            Room temperatures y at t−ρ+1 … t, oldest first. [°C]
        u_past : array-like of shape (ρ, 1) or (ρ,)
            Setpoints u at t−ρ+1 … t; ``u_past[-1]`` is applied from t to t+1. [°C]
        d_past : array-like of shape (ρ, 5)
            Disturbances d = [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h] at
            t−ρ+1 … t.
        u_future : array-like of shape (T, 1) or (T,)
            Setpoints at t+1 … t+T. [°C]
        d_future : array-like of shape (T, 5)
            Disturbances at t+1 … t+T, as ``d_past``.

        Returns
        -------
        numpy.ndarray of shape (9ρ + 6T,)
            z_p (y, u, d per step, oldest first), then u_f, then d_f (step by step).

        Raises
        ------
        ValueError
            If an array has the wrong shape.
        """
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
        """Predict the room temperatures y(t+1) … y(t+T), y_f = Ĥ [z_p; u_f; d_f].

        Parameters
        ----------
        y_past, u_past, d_past, u_future, d_future : array-like
            The past and future samples, shapes and units as in :meth:`regressor`.

        Returns
        -------
        numpy.ndarray of shape (T, 3)
            Predicted T_room up, mid, low at t+1 … t+T. [°C]

        Raises
        ------
        RuntimeError
            If the predictor is not fitted.
        ValueError
            If an array has the wrong shape.

        References
        ----------
        .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
           Energy Management, Eq. (2).
        """
        H = self.require_fit()
        x = self.regressor(y_past, u_past, d_past, u_future, d_future)
        return (H @ x).reshape(self.horizon, NY)

    def predict_windows(self, windows: np.ndarray) -> np.ndarray:
        """Predict for many Hankel windows at once.

        Parameters
        ----------
        windows : numpy.ndarray of shape (m, (ρ+T)·9)
            Each row holds z = [y, u, d] over t−ρ+1 … t+T (see
            :mod:`~trainclimate.predict.hankel`); the future y in it is ignored.

        Returns
        -------
        numpy.ndarray of shape (m, T, 3)
            Predicted room temperatures at t+1 … t+T of each window. [°C]

        Raises
        ------
        RuntimeError
            If the predictor is not fitted.
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
    """Positions of the future outputs, inputs and disturbances in a Hankel window.

    Parameters
    ----------
    rho, horizon : int
        Lead-in ρ and horizon T.

    Returns
    -------
    y, u, d : list of int
        Indices into a (ρ+T)·9 window of y_f (3T), u_f (T) and d_f (5T), each stacked step by
        step.
    """
    base = NZ * rho
    y = [base + NZ * j + k for j in range(horizon) for k in range(NY)]
    u = [base + NZ * j + NY for j in range(horizon)]
    d = [base + NZ * j + NY + NU + k for j in range(horizon) for k in range(ND)]
    return y, u, d


def unscale_h(H_scaled: np.ndarray, rho: int, horizon: int) -> np.ndarray:
    """Convert Ĥ fitted on scaled signals back to the signals' own units.

    Parameters
    ----------
    H_scaled : numpy.ndarray of shape (3T, 9ρ + 6T)
        Ĥ on signals divided by :data:`Z_SCALE` (y's scale is 1 K, so rows need no change).
    rho, horizon : int
        Lead-in ρ and horizon T.

    Returns
    -------
    numpy.ndarray of shape (3T, 9ρ + 6T)
        Ĥ in °C per signal unit.
    """
    _, u, d = future_columns(rho, horizon)
    scale = np.tile(Z_SCALE, rho + horizon)
    col_scale = np.concatenate([scale[: NZ * rho], scale[u], scale[d]])
    return H_scaled / col_scale
