"""A one-step ARX model of order ρ iterated over the horizon, the second baseline.

y(t+1) = Θ z_p(t): the next output from the last ρ samples of [y, u, d], fitted by least squares
(the streaming LQ of [Z_p; Y_1], Θ = L21 L11⁻¹). Predicting T steps feeds each prediction back
into the window; Ĥ is the composition of those steps, exact because every step is linear.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import scipy.linalg as sla

from trainclimate.predict.base import MultistepPredictor, unscale_h
from trainclimate.predict.hankel import ND, NU, NY, NZ, TrajectoryLike


class ARXPredictor(MultistepPredictor):
    """A one-step ARX model of order ρ iterated over the horizon (the second baseline).

    Same API as :class:`~trainclimate.predict.transient.TransientPredictor`.

    Attributes
    ----------
    theta : numpy.ndarray of shape (3, 9ρ)
        The one-step map Θ, y(t+1) = Θ z_p(t), in the signals' units, after :meth:`fit`.
    """

    method = "arx"

    def fit(self, trajectories: Iterable[TrajectoryLike]) -> ARXPredictor:
        """Fit Θ by least squares and compose Ĥ from T iterated steps.

        Sets :attr:`theta` and :attr:`H`.

        Parameters, Returns (``self``) and Raises as in
        :meth:`~trainclimate.predict.base.MultistepPredictor.fit`.
        """
        rho = self.rho
        n = NZ * rho
        L = self._factor(trajectories, rho + 1, np.arange(n + NY))
        theta = sla.solve_triangular(L[:n, :n], L[n:, :n].T, trans="T", lower=True).T
        self.theta = unscale_h(theta, rho, 0)
        self.H = self._compose(self.theta)
        return self

    def _compose(self, theta: np.ndarray) -> np.ndarray:
        """Ĥ (3T × (9ρ + 6T)) of iterating y(k+1) = Θ [z(k−ρ+1), …, z(k)] from t to t+T−1.

        Every sample of the sliding window is kept as a linear map of x = [z_p; u_f; d_f]:
        measured ones select entries of x, predicted outputs are Θ applied to the window.
        """
        rho, T = self.rho, self.horizon
        n_x = self.n_inputs
        u0, d0 = NZ * rho, NZ * rho + NU * T
        window = [np.eye(n_x)[NZ * i : NZ * (i + 1)] for i in range(rho)]  # z(t-ρ+1) … z(t)
        rows = []
        for j in range(T):
            y_next = theta @ np.vstack(window)  # y(t+j+1), (3, n_x)
            rows.append(y_next)
            u_next = np.eye(n_x)[u0 + j : u0 + j + 1]
            d_next = np.eye(n_x)[d0 + ND * j : d0 + ND * (j + 1)]
            window = [*window[1:], np.vstack([y_next, u_next, d_next])]
        return np.vstack(rows)
