"""The streaming LQ factor and the Hankel windows it is fed: L Lᵀ = 𝒵𝒵ᵀ for any split of 𝒵's
columns into blocks, and windows that never straddle two trajectories."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trainclimate.predict.hankel import column_chunks, stacked, windows
from trainclimate.predict.streaming_lq import StreamingLQ


def gram_error(L, Z):
    G = Z @ Z.T  # the test may form the Gram matrix; the library never does
    return np.linalg.norm(L @ L.T - G) / np.linalg.norm(G)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    rows=st.integers(1, 8),
    cuts=st.lists(st.integers(0, 40), min_size=1, max_size=6),
)
def test_l_lt_is_the_gram_matrix_for_any_split_into_blocks(seed, rows, cuts):
    rng = np.random.default_rng(seed)
    blocks = [rng.standard_normal((m, rows)) * rng.uniform(0.1, 100) for m in cuts]
    Z = np.vstack(blocks).T  # rows × columns
    lq = StreamingLQ(rows)
    for b in blocks:
        lq.add(b)
    L = lq.L
    assert lq.n_columns == Z.shape[1]
    assert L.shape == (rows, min(rows, Z.shape[1]))
    assert np.all(np.triu(L, 1) == 0.0)
    if Z.shape[1]:
        assert gram_error(L, Z) <= 1e-13


def test_l_of_a_small_matrix_by_hand():
    Z = np.array([[1.0, 2.0, 2.0, 0.0], [0.0, 3.0, 4.0, 0.0], [1.0, 0.0, 0.0, 1.0]])
    lq = StreamingLQ(3)
    lq.add(Z.T[:1])
    lq.add(Z.T[1:3])
    lq.add(Z.T[3:])
    # Cholesky of 𝒵𝒵ᵀ = [[9, 14, 1], [14, 25, 0], [1, 0, 2]] by hand
    r29 = np.sqrt(29.0)
    expected = np.array(
        [[3.0, 0.0, 0.0], [14 / 3, r29 / 3, 0.0], [1 / 3, -14 / (3 * r29), np.sqrt(33 / 29)]]
    )
    # L is unique up to the signs of its columns (LAPACK's choice)
    np.testing.assert_allclose(np.abs(lq.L), np.abs(expected), rtol=1e-14, atol=1e-15)
    assert gram_error(lq.L, Z) <= 1e-15


def test_blocks_are_checked():
    lq = StreamingLQ(3)
    with pytest.raises(ValueError, match="3 columns"):
        lq.add(np.ones((4, 2)))
    with pytest.raises(ValueError, match="3 columns"):
        lq.add(np.ones(3))
    bad = np.ones((4, 3))
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        lq.add(bad)
    bad[2, 1] = np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        lq.add(bad)
    lq.add(np.empty((0, 3)))
    assert lq.n_columns == 0 and lq.L.shape == (3, 0)


def traj(n, offset=0.0):
    z = offset + np.arange(n * 9, dtype=float).reshape(n, 9)
    return SimpleNamespace(y=z[:, :3], u=z[:, 3:4], d=z[:, 4:])


def test_windows_are_oldest_first_and_stack_y_u_d():
    t = traj(5)
    w = windows(stacked(t), 3)
    assert w.shape == (3, 27)
    np.testing.assert_array_equal(w[1], np.arange(9, 36))  # samples 1, 2, 3
    assert windows(stacked(t), 6).shape == (0, 54)


@pytest.mark.parametrize("chunk", [1, 4, 5, 1000])
def test_column_chunks_never_straddle_trajectories(chunk):
    data = [traj(6), traj(2, 1000.0), traj(4, 2000.0)]  # 4, 0 and 2 windows of depth 3
    blocks = list(column_chunks(data, 3, chunk))
    assert all(0 < len(b) <= chunk for b in blocks)
    assert all(b.flags.c_contiguous for b in blocks)
    got = np.vstack(blocks)
    expected = np.vstack([windows(stacked(t), 3) for t in data])
    np.testing.assert_array_equal(got, expected)
    assert len(got) == 6


def test_stacked_checks_the_widths():
    t = traj(5)
    with pytest.raises(ValueError, match="y"):
        stacked(SimpleNamespace(y=t.y[:, :2], u=t.u, d=t.d))
    with pytest.raises(ValueError, match="same number of samples"):
        stacked(SimpleNamespace(y=t.y, u=t.u[:4], d=t.d))
    with pytest.raises(ValueError):
        stacked(SimpleNamespace(y=t.y, u=t.u[:, 0], d=t.d))
