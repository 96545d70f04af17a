"""The savings' interval: a two-way bootstrap over coaches and days (pure arithmetic, no
simulation)."""

from __future__ import annotations

import numpy as np
import pytest

from trainclimate.study.bootstrap import crossed_sums, savings_interval


def table(coaches: int = 6, days: int = 10, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Energies (kWh) with a coach effect, a day effect and noise; a saving of ≈ 6 % that
    varies from day to day."""
    rng = np.random.default_rng(seed)
    base = (
        100.0
        + rng.normal(0, 10, (coaches, 1))
        + rng.normal(0, 30, (1, days))
        + rng.normal(0, 5, (coaches, days))
    )
    return base, base * (0.94 + rng.normal(0, 0.02, (1, days)))


def saving(base, other) -> float:
    return 100.0 * (1.0 - other.sum() / base.sum())


def test_the_interval_brackets_the_saving_and_is_reproducible_with_its_seed():
    base, other = table()
    ci = savings_interval(base, other, seed=7)
    assert ci.reason is None
    low, high = ci.pct
    assert low < saving(base, other) < high
    assert high - low < 5.0
    assert savings_interval(base, other, seed=7) == ci
    assert savings_interval(base, other, seed=8).pct != ci.pct


def test_crossed_sums_count_each_cell_as_often_as_its_coach_and_its_day_were_drawn():
    t = np.arange(12.0).reshape(3, 4)
    coach_draws = np.array([[0, 0, 2], [1, 2, 2]])
    day_draws = np.array([[3, 1, 1, 0], [2, 2, 2, 2]])
    expected = [
        sum(t[c, d] for c in cs for d in ds) for cs, ds in zip(coach_draws, day_draws, strict=True)
    ]
    assert crossed_sums(t, coach_draws, day_draws).tolist() == expected


def test_days_are_resampled_too():
    # every coach saves the same share each day, the share varies over the days: resampling the
    # coaches alone would give an interval of zero width
    shares = np.linspace(0.02, 0.10, 8)
    base = np.outer(np.linspace(80, 120, 5), np.linspace(50, 150, 8))
    low, high = savings_interval(base, base * (1.0 - shares), seed=1).pct
    assert high - low > 1.0


@pytest.mark.parametrize(
    ("shape", "needle"), [((1, 10), "2 coaches and 2 days (1 × 10"), ((6, 1), "(6 × 1")]
)
def test_one_coach_or_one_day_gives_no_interval_and_says_why(shape, needle):
    base, other = table(*shape)
    ci = savings_interval(base, other, seed=1)
    assert ci.pct is None and needle in ci.reason


def test_resamples_without_baseline_energy_are_left_out_unless_too_many():
    base = np.zeros((4, 5))
    base[0, 0] = 10.0  # a situation on one coach-day only
    ci = savings_interval(base, 0.9 * base, seed=1)
    assert ci.pct is None and "% of the resamples have no baseline energy (more than 1 %)" in (
        ci.reason
    )
    # 2 of 6 coaches never in the situation: (1/3)⁶ ≈ 0.14 % of the resamples draw only them
    base, other = table(6, 10)
    base[:2], other[:2] = 0.0, 0.0
    low, high = savings_interval(base, other, seed=1).pct
    assert low < saving(base, other) < high
    assert savings_interval(np.zeros((4, 5)), np.zeros((4, 5)), seed=1).reason == (
        "the baseline uses no energy"
    )
