"""The Subspace Predictor (Favoreel, De Moor & Van Overschee 1999), the first baseline.

Ĥ is the least-squares regression of the whole future output y_f on [z_p; u_f; d_f] at once:
min ‖Y_f − Ĥ X‖_F. It is not causal by construction — y(t+i) may draw on u(t+j), d(t+j) for
j ≥ i — which is the difference the Transient Predictor removes (paper, Section III.B). Solved
from the streaming LQ factor of [X; Y_f]: with L = [[L11, 0], [L21, L22]], Ĥ = L21 L11⁻¹ (a
triangular solve).

``causal=True`` is an ablation: each y(t+i) regressed by least squares on z_p and the inputs
u, d of steps t+1 … t+i−1 only (the same regressors the Transient Predictor may use, minus the
intermediate outputs). With X ordered [z_p; u(t+1); d(t+1); …], every such regression is one on a
*prefix* of X's rows, so one factorisation gives all of them: the coefficients of y(t+i) on the
first k rows are L21[i, :k] L11[:k, :k]⁻¹.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import scipy.linalg as sla

from trainclimate.predict.base import MultistepPredictor, future_columns, unscale_h
from trainclimate.predict.hankel import ND, NU, NY, NZ, TrajectoryLike


class SubspacePredictor(MultistepPredictor):
    """The Subspace Predictor baseline: one least-squares fit of the whole y_f.

    Same API as :class:`~trainclimate.predict.transient.TransientPredictor`.

    Parameters
    ----------
    rho, horizon : int
        Lead-in ρ and horizon T.
    causal : bool, default False
        Restrict each step to causal regressors (an ablation, see the module docstring;
        :attr:`method` becomes ``"subspace-causal"``).
    chunk : int, default 4096
        Hankel windows streamed at a time.

    References
    ----------
    .. [1] W. Favoreel, B. De Moor et al., 1999: the Subspace Predictor, as cited in [2].
    .. [2] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.B.
    """

    method = "subspace"

    def __init__(self, rho: int, horizon: int, *, causal: bool = False, chunk: int = 4096):
        super().__init__(rho, horizon, chunk=chunk)
        self.causal = bool(causal)
        if self.causal:
            self.method = "subspace-causal"

    def fit(self, trajectories: Iterable[TrajectoryLike]) -> SubspacePredictor:
        """Fit Ĥ by least squares, min ‖Y_f − Ĥ X‖_F (per step on causal regressors if causal).

        Sets :attr:`H`.

        Parameters, Returns (``self``) and Raises as in
        :meth:`~trainclimate.predict.base.MultistepPredictor.fit`.
        """
        rho, T = self.rho, self.horizon
        y, u, d = future_columns(rho, T)
        if not self.causal:
            x_rows = [*range(NZ * rho), *u, *d]
            L = self._factor(trajectories, rho + T, np.array([*x_rows, *y]))
            n = len(x_rows)
            H = sla.solve_triangular(L[:n, :n], L[n:, :n].T, trans="T", lower=True).T
            self.H = unscale_h(H, rho, T)
            return self
        # X interleaved step by step: z_p, then (u, d) of t+1, t+2, …
        steps = [[u[j], *d[ND * j : ND * (j + 1)]] for j in range(T)]
        x_rows = [*range(NZ * rho), *(i for step in steps for i in step)]
        L = self._factor(trajectories, rho + T, np.array([*x_rows, *y]))
        n = len(x_rows)
        H_interleaved = np.zeros((NY * T, n))
        for i in range(T):
            k = NZ * rho + (NU + ND) * i  # regressors before y(t+i+1)
            rows = slice(NY * i, NY * (i + 1))
            H_interleaved[rows, :k] = sla.solve_triangular(
                L[:k, :k], L[n + NY * i : n + NY * (i + 1), :k].T, trans="T", lower=True
            ).T
        # back to the layout [z_p; u_f; d_f]
        order = [*range(NZ * rho)]
        order += [NZ * rho + (NU + ND) * j for j in range(T)]
        order += [NZ * rho + (NU + ND) * j + NU + k for j in range(T) for k in range(ND)]
        self.H = unscale_h(H_interleaved[:, order], rho, T)
        return self
