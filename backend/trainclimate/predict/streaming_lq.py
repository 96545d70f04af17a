"""The LQ decomposition 𝒵 = L Q of a wide matrix, built a block of columns at a time (TSQR).

The LQ factors of 𝒵 are the transposed QR factors of 𝒵ᵀ: 𝒵ᵀ = Q̃ R gives L = Rᵀ. Stacking the
current triangular factor on a new block of rows of 𝒵ᵀ and taking the R of that stack's QR
("tall-skinny QR", Demmel et al. 2012) folds the block in: the R of [R_old; B] is the R of
[A_old; B] up to the signs of its rows, since A_oldᵀA_old = R_oldᵀR_old. Memory is the
(rows × rows) factor plus one block — never the number of columns, and the Gram matrix 𝒵𝒵ᵀ is
never formed (its condition number is the square of 𝒵's).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla


class StreamingLQ:
    """Accumulates the lower-triangular L of 𝒵 = L Q over blocks of 𝒵's columns.

    Feed blocks of 𝒵ᵀ (windows as rows) to :meth:`add`; :attr:`L` is the factor of everything
    added so far. Row signs follow LAPACK; the predictors do not depend on them. This is step 1
    of Algorithm 1 [1]_.

    Parameters
    ----------
    n_rows : int
        Number of rows of 𝒵.

    Attributes
    ----------
    n_columns : int
        Columns of 𝒵 added so far.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Algorithm 1.
    .. [2] J. Demmel et al., 2012: communication-avoiding (tall-skinny) QR.
    """

    def __init__(self, n_rows: int):
        self.n_rows = int(n_rows)
        self.n_columns = 0
        self._r = np.empty((0, self.n_rows))

    def add(self, block_t: np.ndarray) -> None:
        """Fold in a block of columns of 𝒵.

        Parameters
        ----------
        block_t : numpy.ndarray of shape (m, n_rows)
            The block, transposed (windows as rows); an empty block is ignored.

        Raises
        ------
        ValueError
            If the block does not have ``n_rows`` columns or holds NaN or infinite values.
        """
        block_t = np.asarray(block_t, dtype=float)
        if block_t.ndim != 2 or block_t.shape[1] != self.n_rows:
            raise ValueError(f"blocks must have {self.n_rows} columns, got shape {block_t.shape}")
        if not np.all(np.isfinite(block_t)):
            raise ValueError("the training data holds NaN or infinite values")
        if not len(block_t):
            return
        stack = np.vstack([self._r, block_t])
        self._r = sla.qr(stack, mode="r", overwrite_a=True, check_finite=False)[0][: self.n_rows]
        self.n_columns += len(block_t)

    @property
    def L(self) -> np.ndarray:  # noqa: N802 - the paper's name
        """The lower-triangular factor, shape (n_rows, min(n_rows, columns added)); a copy."""
        return self._r.T.copy()
