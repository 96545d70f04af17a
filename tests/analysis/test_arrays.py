"""The analysis's numpy helpers."""

from __future__ import annotations

import numpy as np

from trainclimate.analysis.arrays import pieces


def test_pieces_are_numpy_splits_views():
    rng = np.random.default_rng(3)
    for n in (0, 1, 7, 450):
        a = rng.normal(size=(n, 4))
        for _ in range(20):
            bounds = np.sort(rng.integers(0, n + 1, size=int(rng.integers(0, 12))))
            got, want = pieces(a, bounds), np.split(a, bounds)
            assert len(got) == len(want)
            for x, y in zip(got, want, strict=True):
                assert x.shape == y.shape and np.array_equal(x, y)
                assert x.size == 0 or np.shares_memory(x, a)  # views, as numpy's
