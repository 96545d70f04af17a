"""The Transient Predictor (Moffat et al. 2024) by the paper's Algorithm 1.

With 𝒵 = L Q the LQ decomposition of the extended Hankel matrix (rows z_p, then y, u, d of each
future step), each future output row of 𝒵 splits into its part in the span of the rows before it
and the rest: zeroing the block-diagonal entries of L (the future outputs' own blocks) keeps the
first, so Φ = L_y⁰ L⁻¹ holds, block row by block row, the least-squares regression of y(t+j) on
every entry of z that precedes it — z_p and y, u, d of steps t+1 … t+j−1 — i.e. the one-step
predictor of each future step. Φ is block lower-triangular (causal), and eliminating the future
outputs from its right-hand side gives the multistep model

    Ĥ = (I − Φ_y)⁻¹ [Φ_p, Φ_u, Φ_d]                                  (paper, Algorithm 1, step 5)

with Φ_p, Φ_y, Φ_u, Φ_d Φ's columns of z_p and of the future y, u and d. Both inverses are
triangular solves; no explicit inverse is formed.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import scipy.linalg as sla

from trainclimate.predict.base import COLLINEAR_TOL, MultistepPredictor, future_columns, unscale_h
from trainclimate.predict.hankel import NY, NZ, TrajectoryLike


class TransientPredictor(MultistepPredictor):
    """The Transient Predictor, fitted by Algorithm 1 (see the module docstring).

    ``TransientPredictor(rho, horizon).fit(trajectories)``, then :meth:`predict` and :attr:`H`;
    parameters and attributes as :class:`~trainclimate.predict.base.MultistepPredictor`.

    Attributes
    ----------
    Phi : numpy.ndarray of shape (3T, 9(ρ+T))
        The one-step regressions Φ = [Φ_p, Φ_f] after :meth:`fit`, in scaled units.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.B, Algorithm 1.
    .. [2] K. Moffat et al., 2024: the Transient Predictor, as cited in [1].
    """

    method = "transient"

    def fit(self, trajectories: Iterable[TrajectoryLike]) -> TransientPredictor:
        """Fit Φ and Ĥ by Algorithm 1: L = LQ(𝒵), Φ = L_y⁰ L⁻¹, Ĥ = (I − Φ_y)⁻¹ [Φ_p, Φ_u, Φ_d].

        Sets :attr:`H` and :attr:`Phi`.

        Parameters, Returns (``self``) and Raises as in
        :meth:`~trainclimate.predict.base.MultistepPredictor.fit`.
        """
        rho, T = self.rho, self.horizon
        depth = rho + T
        L = self._factor(trajectories, depth, np.arange(NZ * depth))  # Algorithm 1, step 1
        y_rows, u_cols, d_cols = future_columns(rho, T)
        # A future output that the rows before it explain exactly (noise-free data) leaves a
        # round-off pivot; as a regressor of later steps it adds nothing, so its column is
        # dropped from them rather than dividing round-off by round-off.
        norms = np.linalg.norm(L, axis=1)
        for k in y_rows:
            if abs(L[k, k]) <= COLLINEAR_TOL * norms[k]:
                L[k + 1 :, k] = 0.0
                L[k, k] = 1.0
        L0 = L.copy()
        for j in range(T):  # step 2: the future outputs' block-diagonal terms
            start = NZ * (rho + j)
            L0[start : start + NY, start : start + NY] = 0.0
        Ly0 = L0[y_rows]  # step 3
        # step 4: Φ L = L_y⁰  ⇔  Lᵀ Φᵀ = L_y⁰ᵀ (triangular solve)
        Phi = sla.solve_triangular(L, Ly0.T, trans="T", lower=True, check_finite=False).T
        self.Phi = Phi
        # step 5: Ĥ = (I − Φ_y)⁻¹ [Φ_p, Φ_u, Φ_d], I − Φ_y unit lower-triangular
        rhs = np.hstack([Phi[:, : NZ * rho], Phi[:, u_cols], Phi[:, d_cols]])
        I_minus = np.eye(NY * T) - Phi[:, y_rows]
        H = sla.solve_triangular(I_minus, rhs, lower=True, unit_diagonal=True, check_finite=False)
        self.H = unscale_h(H, rho, T)
        return self
