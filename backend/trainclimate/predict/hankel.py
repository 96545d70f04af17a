"""Hankel matrices of the paper's Section III.B, built a chunk of columns at a time.

For a trajectory with samples z^k = [y^k, u^k, d^k] (9 values: 3 + 1 + 5), the Hankel matrix of
depth L = ρ + T has one column per window of L consecutive samples, the column stacking
z^l, z^{l+1}, …, z^{l+L-1} (oldest first). Concatenating the columns of every trajectory gives the
extended Hankel matrix 𝒵 = [Z_p; Y_1; U_1; D_1; …; Y_T; U_T; D_T]: the first 9ρ rows are the past
z_p, then each future step's y, u and d in that order.

Nothing here materialises 𝒵: :func:`column_chunks` yields blocks of its *transpose* (windows as
rows), ready for the streaming QR of :mod:`trainclimate.predict.streaming_lq`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Protocol

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

NY, NU, ND = 3, 1, 5
NZ = NY + NU + ND
Z_SIGNALS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c", "t_ref_c",
             "t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh")  # fmt: skip


class TrajectoryLike(Protocol):
    """Anything with 2-D float arrays ``y``, ``u``, ``d`` of n samples on one uniform grid.

    Attributes
    ----------
    y : numpy.ndarray of shape (n, 3)
        Room temperatures T_room up, mid, low. [°C]
    u : numpy.ndarray of shape (n, 1)
        Setpoint T_ref. [°C]
    d : numpy.ndarray of shape (n, 5)
        Disturbances [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h].
    """

    # read-only (properties), so frozen dataclasses such as ``Trajectory`` match it
    @property
    def y(self) -> np.ndarray: ...

    @property
    def u(self) -> np.ndarray: ...

    @property
    def d(self) -> np.ndarray: ...


def stacked(traj: TrajectoryLike) -> np.ndarray:
    """The samples z^k = [y^k, u^k, d^k] of a trajectory.

    One row per sample: the outputs, the input and the disturbances side by side.

    Parameters
    ----------
    traj : TrajectoryLike
        The trajectory.

    Returns
    -------
    numpy.ndarray of shape (n, 9)
        In the order of :data:`Z_SIGNALS`.

    Raises
    ------
    ValueError
        If ``y``, ``u``, ``d`` are not n×3, n×1, n×5 with one n.
    """
    y, u, d = (np.asarray(getattr(traj, name), dtype=float) for name in ("y", "u", "d"))
    widths = tuple(a.shape[1] if a.ndim == 2 else -1 for a in (y, u, d))
    if widths != (NY, NU, ND):
        raise ValueError(
            f"a trajectory needs y (n×{NY}), u (n×{NU}) and d (n×{ND}); got "
            f"{y.shape}, {u.shape}, {d.shape}"
        )
    if not (len(y) == len(u) == len(d)):
        raise ValueError("a trajectory's y, u and d must have the same number of samples")
    return np.hstack([y, u, d])


def windows(z: np.ndarray, depth: int) -> np.ndarray:
    """The sliding windows of a sample array: the columns of its Hankel matrix, as rows.

    Parameters
    ----------
    z : numpy.ndarray of shape (n, 9)
        Samples, oldest first (:func:`stacked`).
    depth : int
        Window length ρ + T.

    Returns
    -------
    numpy.ndarray of shape (m, depth·9)
        Row l is [z^l, …, z^{l+depth-1}]; m = n − depth + 1 (0 when the trajectory is too
        short). A read-only view, no copy.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.B.
    """
    if len(z) < depth:
        return np.empty((0, depth * z.shape[1]))
    view = sliding_window_view(z, (depth, z.shape[1]))[:, 0]  # (m, depth, 9)
    return view.reshape(len(view), depth * z.shape[1])


def column_chunks(
    trajectories: Iterable[TrajectoryLike], depth: int, chunk: int = 4096
) -> Iterator[np.ndarray]:
    """Blocks of the transposed extended Hankel matrix 𝒵ᵀ, at most ``chunk`` windows each.

    Windows never straddle two trajectories.

    Parameters
    ----------
    trajectories : iterable of TrajectoryLike
        Consumed once, in order.
    depth : int
        Window length ρ + T.
    chunk : int, default 4096
        Maximum windows per block.

    Yields
    ------
    numpy.ndarray of shape (≤ chunk, depth·9)
        C-contiguous blocks of windows.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.B.
    """
    pending: list[np.ndarray] = []
    size = 0
    for traj in trajectories:
        w = windows(stacked(traj), depth)
        start = 0
        while start < len(w):
            take = min(chunk - size, len(w) - start)
            pending.append(w[start : start + take])
            size += take
            start += take
            if size == chunk:
                yield np.concatenate(pending)
                pending, size = [], 0
    if size:
        yield np.concatenate(pending)
