"""Causality of Ĥ: no y(t+i) may depend on u(t+j) or d(t+j) with j ≥ i (paper, Section III.B).
Checked with ``causality_violation`` and with indices computed here from the contract's layout
of [z_p; u_f; d_f]."""

from types import SimpleNamespace

import numpy as np
import pytest

from trainclimate.predict import ARXPredictor, SubspacePredictor, TransientPredictor
from trainclimate.predict.evaluate import causality_violation

RHO, T = 2, 3


def noncausal_mask(rho, horizon):
    """True where Ĥ maps u(t+j) or d(t+j) to y(t+i) with j ≥ i, from the contract: rows are
    y(t+1) … y(t+T), 3 each; columns z_p (9ρ), then u(t+1) … u(t+T), then d(t+1) … d(t+T), 5
    each."""
    mask = np.zeros((3 * horizon, 9 * rho + 6 * horizon), dtype=bool)
    for row in range(3 * horizon):
        i = row // 3 + 1
        for c in range(horizon):  # u(t+c+1)
            mask[row, 9 * rho + c] = c + 1 >= i
        for c in range(5 * horizon):  # d(t+c//5+1)
            mask[row, 9 * rho + horizon + c] = c // 5 + 1 >= i
    return mask


def test_the_mask_by_hand():
    mask = noncausal_mask(1, 2)
    # y(t+1) from u(t+1), u(t+2), d(t+1), d(t+2); y(t+2) from u(t+2), d(t+2)
    assert mask[:3].sum(axis=0).tolist() == [0] * 9 + [3, 3] + [3] * 10
    assert mask[3:].sum(axis=0).tolist() == [0] * 9 + [0, 3] + [0] * 5 + [3] * 5
    assert noncausal_mask(RHO, T).sum() == 3 * 6 * (3 + 2 + 1)


@pytest.fixture(scope="module")
def closed_loop():
    """A room under a thermostat: u(k) reacts to y(k), so future inputs carry information about
    future outputs — a regression allowed to look ahead uses it."""
    rng = np.random.default_rng(3)
    out = []
    for n in (300, 250, 200):
        y = np.empty((n, 3))
        u = np.empty((n, 1))
        d = np.column_stack(
            [5 + rng.standard_normal(n), 100 * rng.random((n, 2)), 10 * rng.random((n, 2))]
        )
        x = 21.0
        for k in range(n):
            y[k] = x + 0.05 * rng.standard_normal(3)
            u[k] = 22.0 - 0.8 * (y[k, 0] - 22.0) + 0.05 * rng.standard_normal()
            x = 0.7 * x + 0.3 * u[k, 0] - 0.02 * (x - d[k, 0]) + 0.002 * d[k, 1]
            x += 0.1 * rng.standard_normal()
        out.append(SimpleNamespace(y=y, u=u, d=d))
    return out


@pytest.mark.parametrize(
    "make",
    [
        lambda: TransientPredictor(RHO, T),
        lambda: ARXPredictor(RHO, T),
        lambda: SubspacePredictor(RHO, T, causal=True),
    ],
    ids=["transient", "arx", "subspace-causal"],
)
def test_causal_predictors_map_nothing_from_the_future(make, closed_loop, noise_data):
    for data in (closed_loop, noise_data(5, [120, 150, 90])):
        model = make().fit(data)
        mask = noncausal_mask(RHO, T)
        assert np.abs(model.H[mask]).max() <= 1e-10
        assert causality_violation(model) <= 1e-10
        assert np.abs(model.H[~mask]).max() > 1e-3  # not trivially zero


def test_the_plain_subspace_predictor_is_not_causal(closed_loop):
    model = SubspacePredictor(RHO, T).fit(closed_loop)
    mask = noncausal_mask(RHO, T)
    worst = np.abs(model.H[mask]).max()
    # y_up(t+i) read back from the thermostat's u(t+i) = 22 − 0.8 (y_up(t+i) − 22) + noise:
    # measured 0.94 (y_up(t+3) on u(t+3)); a causal model has exactly 0 there
    assert worst > 0.5
    assert causality_violation(model) == worst


def test_causality_violation_finds_one_hand_placed_entry():
    model = TransientPredictor(RHO, T)
    mask = noncausal_mask(RHO, T)
    rng = np.random.default_rng(0)
    model.H = np.where(mask, 0.0, rng.standard_normal(mask.shape))
    assert causality_violation(model) == 0.0
    # y_low(t+2) from d_speed(t+2): non-causal
    model.H[5, 9 * RHO + T + 5 * 1 + 4] = -0.37
    assert causality_violation(model) == 0.37
    model.H = rng.standard_normal(mask.shape)
    assert causality_violation(model) == np.abs(model.H[mask]).max()
