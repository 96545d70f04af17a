"""Model evaluation of Section IV.A: the held-out coaches, the split, and the MAE per step on a
case worked by hand."""

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from trainclimate.data.trajectory import Trajectory
from trainclimate.predict import PredictorDataError, TransientPredictor
from trainclimate.predict.evaluate import (
    evaluate,
    held_out_coaches,
    mae_per_step,
    split_by_coach,
    validation_windows,
)

WINTER = ["124A", "44A", "66A", "17A", "31A", "58A", "93A", "105A"]
SUMMER = ["124B", "44B", "66B", "17B"]


def fleet():
    """Two trajectories per coach of both campaigns (only campaign and coach matter)."""
    return [
        SimpleNamespace(campaign=campaign, coach=coach, k=k)
        for campaign, coaches in (("winter-spring", WINTER), ("summer", SUMMER))
        for coach in coaches
        for k in range(2)
    ]


def test_held_out_coaches_are_the_last_quarter_of_each_campaign_in_sorted_order():
    # sorted: 105A 124A 17A 31A 44A 58A 66A 93A | 124B 17B 44B 66B
    assert held_out_coaches(fleet()) == ["66A", "66B", "93A"]
    assert held_out_coaches(list(reversed(fleet()))) == ["66A", "66B", "93A"]
    winter_only = [t for t in fleet() if t.campaign == "winter-spring"]
    assert held_out_coaches(winter_only) == ["66A", "93A"]
    # 5 coaches: ceil(5/4) = 2 held out; a campaign of one coach keeps it for training
    five = [SimpleNamespace(campaign="c", coach=c) for c in "EDCBA"]
    assert held_out_coaches(five) == ["D", "E"]
    assert held_out_coaches([SimpleNamespace(campaign="c", coach="A")]) == []


def test_split_by_coach_keeps_coaches_apart():
    trajs = fleet()
    train, val = split_by_coach(trajs)
    assert {t.coach for t in val} == {"66A", "66B", "93A"}
    assert len(val) == 6 and len(train) == 18
    assert not {t.coach for t in train} & {t.coach for t in val}
    assert sorted(map(id, train + val)) == sorted(map(id, trajs))
    train, val = split_by_coach(trajs, validation=["44A"])
    assert [t.coach for t in val] == ["44A", "44A"] and len(train) == 22


def hand_made_trajectory(n=6):
    """n samples: y_up = k², y_mid = k, y_low = 0; u = k + 0.5; speed = 10·(−1)^k·k."""
    k = np.arange(float(n))
    y = np.column_stack([k**2, k, np.zeros(n)])
    d = np.zeros((n, 5))
    d[:, 4] = 10 * (-1) ** k * k
    time = pd.date_range("2022-03-01", periods=n, freq="5min", tz="UTC")
    return Trajectory(time, y, (k + 0.5)[:, None], d, campaign="c", coach="X", sampling_min=5)


def hand_made_predictor():
    """ρ = 1, T = 2 with Ĥ set by hand: y_up(t+j) = y_up(t), y_mid(t+j) = u(t+j),
    y_low(t+j) = speed(t+j)/10."""
    p = TransientPredictor(1, 2)
    H = np.zeros((6, 9 + 12))
    for j in range(2):
        H[3 * j, 0] = 1.0  # y_up(t)
        H[3 * j + 1, 9 + j] = 1.0  # u(t+j+1)
        H[3 * j + 2, 9 + 2 + 5 * j + 4] = 0.1  # speed(t+j+1)
    p.H = H
    return p


def test_mae_per_step_of_a_case_worked_by_hand():
    # windows start at t = 0 … 3; errors at step j:
    #   up  (t+j)² − t²      → j=1: 1, 3, 5, 7 (mean 4);  j=2: 4, 8, 12, 16 (mean 10)
    #   mid (t+j+0.5) − (t+j) → 0.5
    #   low |speed(t+j)|/10 = t+j → j=1: mean 2.5; j=2: mean 3.5
    mae = mae_per_step(hand_made_predictor(), [hand_made_trajectory()])
    np.testing.assert_allclose(mae, [[4.0, 0.5, 2.5], [10.0, 0.5, 3.5]], rtol=1e-15)


def test_short_trajectories_add_no_windows():
    long, short = hand_made_trajectory(), hand_made_trajectory(2)
    assert validation_windows([short, long, short], 3).shape == (4, 27)
    mae = mae_per_step(hand_made_predictor(), [short, long])
    np.testing.assert_allclose(mae, [[4.0, 0.5, 2.5], [10.0, 0.5, 3.5]], rtol=1e-15)
    with pytest.raises(PredictorDataError, match="no validation trajectory has the 3 samples"):
        mae_per_step(hand_made_predictor(), [short])


def test_evaluate_reports_the_contract_keys(noise_data):
    def traj(coach, t):
        time = pd.date_range("2022-03-01", periods=len(t.y), freq="5min", tz="UTC")
        return Trajectory(time, t.y, t.u, t.d, campaign="c", coach=coach, sampling_min=5)

    raw = noise_data(41, [70, 70, 70, 50])
    trajs = [traj(c, t) for c, t in zip(["A", "B", "C", "D"], raw, strict=True)]
    model, result = evaluate("transient", 5, 2, 3, data_dir=None, split=split_by_coach(trajs))
    mae = mae_per_step(model, [trajs[3]])
    assert result["validation_coaches"] == ["D"] and result["train_coaches"] == ["A", "B", "C"]
    assert result["mae_per_step_deck_c"] == mae.tolist()
    assert result["mae_per_step_c"] == mae.mean(axis=1).tolist()
    assert len(result["mae_per_step_c"]) == 3
    assert result["mae_mean_c"] == pytest.approx(mae.mean(), rel=1e-15)
    assert result["prediction_minutes"] == [5, 10, 15]
    assert result["validation_windows"] == 46 and result["hankel_columns"] == 3 * 66
    assert result["causality_violation"] == 0.0
    assert result["data_hash"] == model.data_hash
    with pytest.raises(ValueError, match="unknown method 'kalman'"):
        evaluate("kalman", 5, 2, 3, data_dir=None, split=split_by_coach(trajs))
