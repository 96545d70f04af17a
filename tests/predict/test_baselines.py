"""The baselines by hand: ARX's Ĥ is its one-step model iterated T times, the subspace
predictor is the least-squares regression of y_f on [z_p; u_f; d_f] (and its causal ablation
the regression of each step on its causal regressors)."""

import numpy as np
import pytest

from trainclimate.predict import ARXPredictor, SubspacePredictor

RHO, T = 3, 4


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.fixture(scope="module")
def data(noise_data):
    return noise_data(11, [80, 5, 140, 60])


def hankel(data, depth):
    """(windows, depth, 9) in the signals' units."""
    out = []
    for t in data:
        z = np.hstack([t.y, t.u, t.d])
        out += [z[k : k + depth] for k in range(len(z) - depth + 1)]
    return np.array(out)


def regressors(w, rho):
    """[z_p; u_f; d_f] of each window (the contract's layout)."""
    m = len(w)
    return np.hstack([w[:, :rho].reshape(m, -1), w[:, rho:, 3], w[:, rho:, 4:].reshape(m, -1)])


def test_arx_theta_is_the_one_step_least_squares_fit(data):
    arx = ARXPredictor(RHO, T).fit(data)
    w = hankel(data, RHO + 1)
    theta, *_ = np.linalg.lstsq(w[:, :RHO].reshape(len(w), -1), w[:, RHO, :3], rcond=None)
    assert arx.theta.shape == (3, 9 * RHO)
    assert rel(arx.theta, theta.T) <= 1e-9


def iterate_by_hand(theta, x, rho, horizon):
    """y(t+1) … y(t+T) by feeding each one-step prediction back into the window."""
    window = list(x[: 9 * rho].reshape(rho, 9))
    u_f = x[9 * rho : 9 * rho + horizon]
    d_f = x[9 * rho + horizon :].reshape(horizon, 5)
    ys = []
    for j in range(horizon):
        y = theta @ np.concatenate(window[-rho:])
        ys.append(y)
        window.append(np.concatenate([y, [u_f[j]], d_f[j]]))
    return np.concatenate(ys)


def test_arx_h_is_its_one_step_model_iterated(data):
    arx = ARXPredictor(RHO, T).fit(data)
    # Ĥ column by column: the response to each unit regressor
    n = arx.n_inputs
    by_hand = np.column_stack([iterate_by_hand(arx.theta, e, RHO, T) for e in np.eye(n)])
    assert rel(arx.H, by_hand) <= 1e-12
    x = np.random.default_rng(0).standard_normal(n)
    np.testing.assert_allclose(arx.H @ x, iterate_by_hand(arx.theta, x, RHO, T), rtol=1e-10)
    # the first step is θ itself, and nothing of the future enters it
    np.testing.assert_array_equal(arx.H[:3, : 9 * RHO], arx.theta)
    assert np.all(arx.H[:3, 9 * RHO :] == 0.0)


def test_subspace_h_is_the_least_squares_regression_of_the_future_outputs(data):
    sp = SubspacePredictor(RHO, T).fit(data)
    w = hankel(data, RHO + T)
    H, *_ = np.linalg.lstsq(regressors(w, RHO), w[:, RHO:, :3].reshape(len(w), -1), rcond=None)
    assert rel(sp.H, H.T) <= 1e-9


def test_causal_subspace_regresses_each_step_on_its_causal_regressors_only(data):
    sp = SubspacePredictor(RHO, T, causal=True).fit(data)
    assert sp.method == "subspace-causal"
    w = hankel(data, RHO + T)
    X = regressors(w, RHO)
    for i in range(T):  # y(t+i+1) on z_p, u(t+1) … u(t+i), d(t+1) … d(t+i)
        cols = [
            *range(9 * RHO),
            *(9 * RHO + j for j in range(i)),
            *(9 * RHO + T + 5 * j + k for j in range(i) for k in range(5)),
        ]
        coef, *_ = np.linalg.lstsq(X[:, cols], w[:, RHO + i, :3], rcond=None)
        rows = sp.H[3 * i : 3 * (i + 1)]
        assert rel(rows[:, cols], coef.T) <= 1e-9
        rest = np.delete(rows, cols, axis=1)
        assert np.all(rest == 0.0)
