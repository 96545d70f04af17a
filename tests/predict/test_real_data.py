"""The Transient Predictor on a small dataset from the seeded fleet logs (2 days, 4 coaches of
each campaign), at 5 min with ρ = T = 6 (a 30-min lead-in and horizon)."""

import numpy as np
import pytest

from trainclimate.predict import TransientPredictor
from trainclimate.predict.evaluate import (
    causality_violation,
    load_split,
    mae_per_step,
    validation_windows,
)

RHO, T = 6, 6


@pytest.fixture(scope="module")
def split(small_dataset):
    return load_split(small_dataset, 5)


@pytest.fixture(scope="module")
def model(split):
    train, _ = split
    return TransientPredictor(RHO, T).fit(train)


def test_the_split_holds_out_the_last_coach_of_each_campaign(split):
    train, val = split
    assert sorted({t.coach for t in val}) == ["66A", "66B"]
    assert sorted({t.coach for t in train}) == ["124A", "124B", "17A", "17B", "44A", "44B"]


def test_held_out_mae_is_below_a_quarter_kelvin_at_every_step(model, split):
    _, val = split
    mae = mae_per_step(model, val)
    assert mae.shape == (T, 3)
    # measured: 0.107–0.152 K (up, mid) and 0.224–0.268 K (low) per deck and step; 0.15–0.19 K
    # mean over decks (this small fleet; on the default dataset every deck and step stays below
    # 0.22 K, docs/experiments.md). The lower deck floats while the coach cools, which its
    # door and the room-chosen HVAC state make the hardest to predict.
    assert np.all(mae < 0.3)
    assert np.all(mae.mean(axis=1) < 0.2)
    # and far better than persistence, y(t+j) = y(t): measured 0.19 … 0.43 K mean over decks
    w = validation_windows(val, RHO + T).reshape(-1, RHO + T, 9)
    persistence = np.abs(w[:, RHO:, :3] - w[:, RHO - 1 : RHO, :3]).mean(axis=0)
    assert np.all(mae.mean(axis=1) < persistence.mean(axis=1))
    assert mae[-1].mean() < 0.5 * persistence[-1].mean()


def test_the_fit_is_causal(model):
    assert causality_violation(model) == 0.0


def test_the_steady_state_gain_from_setpoint_to_room_is_one(model):
    # With every signal held constant, y = Σ_y-columns·y + Σ_u-columns·u + …: the last step's
    # fixed point gives dy/du = (I − A)⁻¹ b, with A the sums of the last step's y_past columns
    # per deck and b the sums of its u columns (past and future). The HVAC tracks its setpoint,
    # so each deck follows it 1:1. Measured 0.9996, 0.9967, 0.9922; tolerance ±0.03. (The raw
    # sum of the u columns alone is 0.59–0.78: 30 minutes are not yet steady state.)
    last = model.H[-3:]
    u_cols = [9 * k + 3 for k in range(RHO)] + [9 * RHO + j for j in range(T)]
    A = np.array(
        [[last[i, [9 * k + j for k in range(RHO)]].sum() for j in range(3)] for i in range(3)]
    )
    gain = np.linalg.solve(np.eye(3) - A, last[:, u_cols].sum(axis=1))
    np.testing.assert_allclose(gain, 1.0, atol=0.03)
