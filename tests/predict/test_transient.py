"""The Transient Predictor against Algorithm 1 worked by hand: Φ's block rows are the one-step
least-squares regressions, the streaming fit equals a one-shot fit for any chunk size, and
noise-free data of a system of order ≤ ρ is predicted exactly."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trainclimate.predict import METHODS, TransientPredictor
from trainclimate.predict.base import Z_SCALE

NZ = 9


def random_system(rng, n, radius=0.8):
    """x(k+1) = A x(k) + B u(k) + E d(k), y(k) = C x(k): 3 outputs, 1 input, 5 disturbances,
    spectral radius of A = ``radius``. E is divided by the disturbances' physical scales so each
    acts on the state about as much as u does."""
    A = rng.standard_normal((n, n))
    A *= radius / np.max(np.abs(np.linalg.eigvals(A)))
    B = rng.standard_normal((n, 1))
    E = rng.standard_normal((n, 5)) / Z_SCALE[4:]
    C = rng.standard_normal((3, n))
    return A, B, E, C


def simulate(rng, system, lengths, output_noise=0.0, process_noise=0.0):
    """Trajectories of ``system`` driven by white u and d (d of its physical size), with an
    unmeasured white process disturbance and white output noise of the given sizes."""
    A, B, E, C = system
    out = []
    for n in lengths:
        x = rng.standard_normal(len(A))
        u = 22.0 + rng.standard_normal((n, 1))
        d = rng.standard_normal((n, 5)) * Z_SCALE[4:]
        y = np.empty((n, 3))
        for k in range(n):
            y[k] = C @ x
            x = A @ x + B @ u[k] + E @ d[k] + process_noise * rng.standard_normal(len(A))
        y += output_noise * rng.standard_normal(y.shape)
        out.append(SimpleNamespace(y=y, u=u, d=d))
    return out


def hankel_t(trajectories, depth, scaled=True):
    """The transposed extended Hankel matrix by hand: one row per window of ``depth`` samples of
    one trajectory, [y, u, d] of each sample oldest first (divided by Z_SCALE if ``scaled``)."""
    rows = []
    for t in trajectories:
        z = np.hstack([t.y, t.u, t.d]) / (Z_SCALE if scaled else 1.0)
        rows += [z[k : k + depth].ravel() for k in range(len(z) - depth + 1)]
    return np.array(rows)


def future_y(rho, T):
    """Window indices of y(t+1) … y(t+T)."""
    return [NZ * (rho + j) + k for j in range(T) for k in range(3)]


def algorithm_1(Zt, rho, T, scaled=True):
    """Ĥ by the paper's Algorithm 1 from a one-shot QR of 𝒵ᵀ (of signals divided by Z_SCALE if
    ``scaled``), in the signals' units."""
    L = np.linalg.qr(Zt, mode="r").T
    L0 = L.copy()
    for j in range(T):
        s = NZ * (rho + j)
        L0[s : s + 3, s : s + 3] = 0.0
    y = future_y(rho, T)
    Phi = np.linalg.solve(L.T, L0[y].T).T
    u = [NZ * (rho + j) + 3 for j in range(T)]
    d = [NZ * (rho + j) + 4 + k for j in range(T) for k in range(5)]
    H = np.linalg.solve(np.eye(3 * T) - Phi[:, y], Phi[:, [*range(NZ * rho), *u, *d]])
    if not scaled:
        return H
    scale = np.concatenate([np.tile(Z_SCALE, rho), np.full(T, Z_SCALE[3]), np.tile(Z_SCALE[4:], T)])
    return H / scale


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    seed=st.integers(0, 2**32 - 1),
    rho=st.integers(1, 3),
    T=st.integers(1, 3),
    n=st.integers(3, 5),
    output_noise=st.sampled_from([0.0, 1e-3, 1e-2, 0.1]),
    process_noise=st.floats(0.05, 1.0),
    extra=st.lists(st.integers(0, 60), min_size=0, max_size=3),
)
def test_each_block_row_of_phi_is_the_one_step_least_squares_regression(
    seed, rho, T, n, output_noise, process_noise, extra
):
    rng = np.random.default_rng(seed)
    depth = rho + T
    # several trajectories of random lengths (some too short for a window), in all at least
    # three windows per row of 𝒵
    lengths = [depth - 1 + e for e in extra] + [depth - 1 + 3 * NZ * depth]
    data = simulate(rng, random_system(rng, n), lengths, output_noise, process_noise)
    tp = TransientPredictor(rho, T).fit(data)

    Zt = hankel_t(data, depth)
    assert tp.Phi.shape == (3 * T, NZ * depth)
    for j in range(T):  # y(t+j+1) on z_p and y, u, d of t+1 … t+j
        k = NZ * (rho + j)
        coef, *_ = np.linalg.lstsq(Zt[:, :k], Zt[:, k : k + 3], rcond=None)
        block = tp.Phi[3 * j : 3 * (j + 1)]
        assert np.linalg.norm(block[:, :k] - coef.T) <= 1e-6 * np.linalg.norm(coef)
        assert np.all(block[:, k:] == 0.0)  # nothing from y(t+j+1) on


@pytest.mark.parametrize(("rho", "T"), [(1, 1), (1, 3), (2, 2), (3, 1), (2, 3)])
@pytest.mark.parametrize("method", list(METHODS))
def test_noise_free_data_of_order_at_most_rho_is_predicted_exactly(method, rho, T):
    # 3 outputs and 3ρ states: the last ρ samples determine the state, so y(t+1) … y(t+T) are
    # exact linear functions of [z_p; u_f; d_f] (and the future outputs are perfectly
    # predictable from the rows before them — which must not count as rank deficiency)
    rng = np.random.default_rng(10 * rho + T)
    system = random_system(rng, 3 * rho)
    train = simulate(rng, system, [150, 7, 120])
    test = simulate(rng, system, [200])[0]
    model = METHODS[method](rho, T).fit(train)
    worst = 0.0
    for t in range(rho, 200 - T, 13):
        y = model.predict(
            test.y[t - rho : t],
            test.u[t - rho : t],
            test.d[t - rho : t],
            test.u[t : t + T],
            test.d[t : t + T],
        )
        worst = max(worst, np.abs(y - test.y[t : t + T]).max())
    scale = np.abs(test.y - test.y.mean()).max()  # a few K
    assert worst <= 1e-6 * scale  # measured ≤ 3e-15 relative


def test_an_exactly_predictable_output_leaves_phi_finite_and_h_exact():
    # y_up(k+1) = y_mid(k): the row of y_up(t+1) is a copy of the row of y_mid(t), its pivot
    # round-off. Dividing by it made Φ's later rows ≈ 1e14 before the fix.
    rng = np.random.default_rng(1)
    data = []
    for n in (100, 80):
        z = rng.standard_normal((n + 1, NZ)) * Z_SCALE
        y = z[1:, :3].copy()
        y[1:, 0] = y[:-1, 1]
        data.append(SimpleNamespace(y=y, u=z[1:, 3:4], d=z[1:, 4:]))
    tp = TransientPredictor(1, 2).fit(data)
    assert np.all(np.isfinite(tp.Phi)) and np.abs(tp.Phi).max() < 1e3
    expected = np.zeros(tp.n_inputs)
    expected[1] = 1.0  # y_up(t+1) = y_mid(t)
    np.testing.assert_allclose(tp.H[0], expected, atol=1e-12)


@pytest.fixture(scope="module")
def lti_data():
    rng = np.random.default_rng(7)
    system = random_system(rng, 4)
    # lengths 3 and 4 are shorter than a window of ρ + T = 5: they must be skipped, and no
    # window may straddle two trajectories
    return simulate(rng, system, [60, 3, 45, 4, 90, 33], output_noise=0.02, process_noise=0.3)


def test_streaming_fit_does_not_depend_on_the_chunk_size(lti_data):
    H = {c: TransientPredictor(2, 3, chunk=c).fit(lti_data).H for c in (1, 7, 64, 4096)}
    for c in (1, 7, 64):
        assert rel(H[c], H[4096]) <= 1e-9


def test_streaming_fit_equals_a_one_shot_fit_by_hand(lti_data):
    tp = TransientPredictor(2, 3, chunk=7).fit(lti_data)
    Zt = hankel_t(lti_data, 5)
    assert tp.n_columns == len(Zt) == 56 + 41 + 86 + 29
    assert tp.n_trajectories == 6
    assert rel(tp.H, algorithm_1(Zt, 2, 3)) <= 1e-9


def test_the_internal_scaling_does_not_change_h(lti_data):
    # Algorithm 1 on the raw signals gives the same Ĥ (least squares is scale-equivariant)
    H_raw = algorithm_1(hankel_t(lti_data, 5, scaled=False), 2, 3, scaled=False)
    assert rel(TransientPredictor(2, 3).fit(lti_data).H, H_raw) <= 1e-8
