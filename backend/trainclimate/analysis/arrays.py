"""Small numpy helpers of the analysis, which the service uses too."""

from __future__ import annotations

import numpy as np


def pieces(a: np.ndarray, bounds: np.ndarray) -> list[np.ndarray]:
    """``numpy.split(a, bounds)`` along the first axis — the same views, ``bounds`` ascending —
    by slicing: ``numpy.split`` swaps the axes twice per piece (450 pieces: 0.58 against 0.11 ms,
    measured), and a summary cuts thousands."""
    cuts = np.asarray(bounds, np.int64).tolist()
    return [a[i:j] for i, j in zip([0, *cuts], [*cuts, len(a)], strict=True)]
