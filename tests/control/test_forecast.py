"""The disturbance forecasts: perfect, persistence and the seeded noisy one."""

from __future__ import annotations

import numpy as np
import pytest

from trainclimate.control.forecast import (
    FORECASTS,
    NoisyForecast,
    PerfectForecast,
    PersistenceForecast,
)

TICKS = 300


def make_truth():
    """A day of 5-min disturbances: T_amb 10–20 °C, a solar bell, occupancy and speed steps."""
    k = np.arange(TICKS + 20)
    sun = np.clip(np.sin((k - 70) / 180 * np.pi), 0.0, None)
    table = np.column_stack(
        [
            15.0 + 5.0 * np.sin(k / 288 * 2 * np.pi),
            600 * sun,
            250 * sun,
            (k % 24) * 4.0,
            k % 7 * 20.0,
        ]
    )

    def truth(tick: int, steps: int) -> np.ndarray:
        return table[tick : tick + steps].copy()

    return truth, table


def test_names():
    assert FORECASTS == ("perfect", "persistence", "noisy")


def test_perfect_is_the_truth():
    truth, table = make_truth()
    f = PerfectForecast(truth)
    for tick in (0, 17, 200):
        np.testing.assert_array_equal(f.forecast(tick, 6, table[tick]), table[tick + 1 : tick + 7])


def test_persistence_repeats_the_last_sample():
    last = np.array([3.0, 120.0, 40.0, 12.0, 80.0])
    out = PersistenceForecast().forecast(5, 6, last)
    assert out.shape == (6, 5)
    np.testing.assert_array_equal(out, np.tile(last, (6, 1)))


def test_noisy_is_seeded():
    truth, table = make_truth()
    a, b = NoisyForecast(truth, seed=3), NoisyForecast(truth, seed=3)
    np.testing.assert_array_equal(a.forecast(40, 6, table[40]), b.forecast(40, 6, table[40]))
    # the same tick again: the same forecast; another tick or seed: another error path
    np.testing.assert_array_equal(a.forecast(40, 6, table[40]), a.forecast(40, 6, table[40]))
    assert not np.array_equal(
        a.forecast(41, 6, table[41]) - table[42:48], a.forecast(40, 6, table[40]) - table[41:47]
    )
    c = NoisyForecast(truth, seed=4)
    assert not np.array_equal(c.forecast(40, 6, table[40]), a.forecast(40, 6, table[40]))


def test_noisy_errors_grow_with_lead_time():
    """AR(1) errors with σ = 0.5 K, φ = 0.9: the RMS temperature error at lead k is
    0.5 √((1 − 0.81ᵏ) / 0.19) — 0.50, 0.67, 0.79, 0.87, 0.93, 0.97 K (measured over 300 ticks:
    0.51, 0.71, 0.79, 0.85, 0.90, 0.95 K, within 6 %; mean error −0.08 K)."""
    truth, table = make_truth()
    f = NoisyForecast(truth, seed=0)
    err = np.array(
        [f.forecast(t, 6, table[t])[:, 0] - table[t + 1 : t + 7, 0] for t in range(TICKS)]
    )
    rms = np.sqrt(np.mean(err**2, axis=0))
    expected = 0.5 * np.sqrt((1 - 0.81 ** np.arange(1, 7)) / 0.19)
    np.testing.assert_allclose(rms, expected, rtol=0.15)
    assert np.all(np.diff(rms) > 0)
    assert abs(err.mean()) < 0.15  # unbiased


def test_noisy_irradiance_stays_physical():
    truth, table = make_truth()
    f = NoisyForecast(truth, seed=1, solar_sigma=0.8)  # large relative errors: would go negative
    out = np.array([f.forecast(t, 6, table[t]) for t in range(TICKS)])
    assert np.all(out[..., 1:3] >= 0.0)
    assert np.any(out[..., 1:3] == 0.0) and np.any(out[..., 1] > 0)
    # night stays dark, occupancy and speed (the timetable's) are exact
    truths = np.array([table[t + 1 : t + 7] for t in range(TICKS)])
    np.testing.assert_array_equal(out[truths[..., 1] == 0.0][:, 1], 0.0)
    np.testing.assert_array_equal(out[..., 3:], truths[..., 3:])


@pytest.mark.parametrize("horizon", [1, 6, 12])
def test_shapes(horizon):
    truth, table = make_truth()
    for f in (PerfectForecast(truth), PersistenceForecast(), NoisyForecast(truth)):
        assert f.forecast(10, horizon, table[10]).shape == (horizon, 5)
