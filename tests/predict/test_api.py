"""The Python API of the contract: ``fit`` on any objects with y, u, d; ``predict`` with the
contract's arrays and shapes; Ĥ's layout [z_p; u_f; d_f]."""

from types import SimpleNamespace

import numpy as np
import pytest

from trainclimate.predict import (
    METHODS,
    ARXPredictor,
    SubspacePredictor,
    TransientPredictor,
)
from trainclimate.predict.evaluate import validation_windows

RHO, T = 3, 2


@pytest.fixture(scope="module")
def data(noise_data):
    return noise_data(21, [90, 70, 40], sampling_min=5)


@pytest.fixture(scope="module")
def fitted(data):
    return TransientPredictor(RHO, T).fit(data)


def contract_arrays(traj, t, rho=RHO, horizon=T):
    """The arrays of ``predict`` for time t of a trajectory (samples t−ρ+1 … t and t+1 … t+T)."""
    past, future = slice(t - rho + 1, t + 1), slice(t + 1, t + 1 + horizon)
    return traj.y[past], traj.u[past], traj.d[past], traj.u[future], traj.d[future]


def test_fit_returns_the_predictor_with_h_of_the_contract_shape(data):
    for name, cls in METHODS.items():
        model = cls(RHO, T)
        assert model.fit(data) is model
        assert model.method == name
        assert model.H.shape == (3 * T, 9 * RHO + 6 * T) == (3 * T, model.n_inputs)
        assert model.sampling_min == 5.0
        assert model.n_trajectories == 3


def test_any_iterable_of_objects_with_y_u_d_works(data, fitted):
    plain = [SimpleNamespace(y=t.y, u=t.u, d=t.d) for t in data]
    once = TransientPredictor(RHO, T).fit(t for t in plain)  # a one-pass generator
    np.testing.assert_array_equal(once.H, fitted.H)
    assert once.sampling_min is None  # nothing said it
    lists = [SimpleNamespace(y=t.y.tolist(), u=t.u.tolist(), d=t.d.tolist()) for t in data]
    np.testing.assert_array_equal(TransientPredictor(RHO, T).fit(lists).H, fitted.H)


def test_predict_is_h_times_the_regressor_in_the_contract_order(data, fitted):
    traj = data[0]
    t = 40
    y_past, u_past, d_past, u_future, d_future = contract_arrays(traj, t)
    # z_p = [y(t-ρ+1), u(t-ρ+1), d(t-ρ+1), …, y(t), u(t), d(t)]; u_f, d_f stacked step by step
    z_p = []
    for k in range(t - RHO + 1, t + 1):
        z_p += [*traj.y[k], *traj.u[k], *traj.d[k]]
    u_f = [traj.u[k, 0] for k in range(t + 1, t + 1 + T)]
    d_f = [v for k in range(t + 1, t + 1 + T) for v in traj.d[k]]
    x = np.array(z_p + u_f + d_f)
    y = fitted.predict(y_past, u_past, d_past, u_future, d_future)
    assert y.shape == (T, 3)
    np.testing.assert_allclose(y.ravel(), fitted.H @ x, rtol=1e-12, atol=1e-12)


def test_a_one_dimensional_u_is_accepted(data, fitted):
    y_past, u_past, d_past, u_future, d_future = contract_arrays(data[1], 20)
    expected = fitted.predict(y_past, u_past, d_past, u_future, d_future)
    np.testing.assert_array_equal(
        fitted.predict(y_past, u_past[:, 0], d_past, u_future, d_future), expected
    )
    np.testing.assert_array_equal(
        fitted.predict(y_past, u_past.ravel().tolist(), d_past, u_future[:, 0], d_future),
        expected,
    )


@pytest.mark.parametrize(
    ("name", "position", "shape"),
    [
        ("y_past", 0, (RHO - 1, 3)),
        ("y_past", 0, (RHO, 2)),
        ("y_past", 0, (3 * RHO,)),
        ("u_past", 1, (RHO + 1,)),
        ("u_past", 1, (RHO, 2)),
        ("d_past", 2, (RHO, 4)),
        ("u_future", 3, (T + 1, 1)),
        ("d_future", 4, (T, 5, 1)),
        ("d_future", 4, (5 * T,)),
    ],
)
def test_wrong_shapes_raise_value_errors_naming_the_argument(fitted, name, position, shape):
    args = [np.zeros((RHO, 3)), np.zeros((RHO, 1)), np.zeros((RHO, 5)), np.zeros((T, 1))]
    args.append(np.zeros((T, 5)))
    args[position] = np.zeros(shape)
    with pytest.raises(ValueError, match=f"{name} must have shape"):
        fitted.predict(*args)


@pytest.mark.parametrize("cls", [TransientPredictor, SubspacePredictor, ARXPredictor])
def test_predict_before_fit_raises(cls):
    model = cls(2, 2)
    assert model.H is None
    with pytest.raises(RuntimeError, match="not fitted"):
        model.predict(
            np.zeros((2, 3)), np.zeros(2), np.zeros((2, 5)), np.zeros(2), np.zeros((2, 5))
        )
    with pytest.raises(RuntimeError, match="not fitted"):
        model.predict_windows(np.zeros((1, 36)))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"rho": 0, "horizon": 3},
        {"rho": 3, "horizon": -1},
        {"rho": 1.5, "horizon": 3},
        {"rho": True, "horizon": 3},
        {"rho": "3", "horizon": 3},
        {"rho": 3, "horizon": 3, "chunk": 0},
    ],
)
def test_bad_settings_raise(kwargs):
    with pytest.raises(ValueError, match="must be a positive integer"):
        TransientPredictor(**kwargs)


def test_numpy_integers_are_settings():
    assert TransientPredictor(np.int64(2), np.int32(3)).n_inputs == 9 * 2 + 6 * 3


def test_predict_windows_agrees_with_predict(data, fitted):
    w = validation_windows(data, RHO + T)
    assert w.shape == (86 + 66 + 36, 9 * (RHO + T))
    spoiled = w.copy().reshape(len(w), RHO + T, 9)
    spoiled[:, RHO:, :3] = np.nan  # the future y of a window is never used
    batch = fitted.predict_windows(spoiled.reshape(len(w), -1))
    assert batch.shape == (len(w), T, 3)
    traj = data[1]
    for t in (RHO - 1, 30, len(traj.y) - T - 1):  # the first, a middle and the last window
        one = fitted.predict(*contract_arrays(traj, t))
        np.testing.assert_allclose(batch[86 + t - RHO + 1], one, rtol=1e-12)
