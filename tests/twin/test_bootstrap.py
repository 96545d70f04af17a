"""The bootstrap over whole days behind ``calibrate``'s 95 % intervals, on a problem whose answer
is known: each day's minutes scatter around the true value plus the day's own offset (the days
disagree, as a model structure the knobs do not span makes them), and the re-fit is the weighted
mean of the minutes — the least-squares fit of one constant."""

import numpy as np
import pytest

from trainclimate.twin.bootstrap import MIN_BOOTSTRAP_DAYS, day_bootstrap, interval_warnings

#: The value every day scatters around.
TRUE = 3.0
#: Minute-to-minute noise of the synthetic residuals, small beside the days' offsets.
NOISE = 0.05


def campaign(seed: int, days: int, minutes: int, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """The day of each minute and the minutes' values: ``TRUE`` + the day's offset (normal,
    standard deviation ``spread``) + noise (``NOISE``)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0.0, spread, days)
    day_of = np.repeat(np.arange(days), minutes)
    return day_of, TRUE + offsets[day_of] + rng.normal(0.0, NOISE, day_of.size)


def mean_refit(values: np.ndarray):
    """The re-fit of one constant to ``values`` under the resamples' weights: (1, resamples)."""
    return lambda w: ((w @ values) / w.sum(axis=1))[None, :]


def interval(seed: int, days: int, minutes: int, spread: float, replicates: int = 199):
    """The bootstrap's (low, high) of the constant on one synthetic campaign."""
    day_of, values = campaign(seed, days, minutes, spread)
    low, high = day_bootstrap(days, day_of, mean_refit(values), replicates, seed)
    return float(low[0]), float(high[0])


def test_the_interval_contains_the_true_value_about_as_often_as_it_says():
    """Over 200 campaigns of 10 days the percentile interval covers the truth in 85–99 % of
    them (measured 91.5 %: a percentile bootstrap of 10 days is a little short of 95 %), and
    its half-width is about 1.96 standard errors of a mean of 10 days (the days' spread, not
    the minutes' noise, sets it)."""
    spread, days = 0.3, 10
    intervals = np.array([interval(seed, days, 60, spread) for seed in range(200)])
    covered = np.mean((intervals[:, 0] <= TRUE) & (intervals[:, 1] >= TRUE))
    assert 0.85 <= covered <= 0.99
    half = np.mean(intervals[:, 1] - intervals[:, 0]) / 2
    assert half / (1.96 * spread / np.sqrt(days)) == pytest.approx(1.0, abs=0.15)


def test_the_interval_widens_with_the_days_disagreement():
    """The same campaign with the days' offsets doubled: the interval twice as wide (the
    minutes' noise, unchanged, keeps it from exactly 2); with the days agreeing, over 10 times
    narrower."""
    base = interval(1, 8, 60, 0.2)
    doubled = interval(1, 8, 60, 0.4)
    agreeing = interval(1, 8, 60, 0.0)
    width = base[1] - base[0]
    assert (doubled[1] - doubled[0]) / width == pytest.approx(2.0, abs=0.1)
    assert (agreeing[1] - agreeing[0]) < width / 10


def test_whole_days_are_resampled_with_repeats():
    """The re-fit is given weights that are, for every minute of a day, the times that day was
    drawn: whole days, some drawn twice or more and some not at all, as many draws as days."""
    days, minutes, replicates = 6, 30, 50
    day_of, values = campaign(2, days, minutes, 0.3)
    given = []

    def recording(w):
        given.append(w)
        return mean_refit(values)(w)

    day_bootstrap(days, day_of, recording, replicates, 0)
    w = np.vstack(given)
    assert w.shape == (replicates, days * minutes)
    per_day = w.reshape(replicates, days, minutes)
    assert np.all(per_day == per_day[:, :, :1])
    counts = per_day[:, :, 0]
    assert np.all(counts == np.round(counts)) and np.all(counts.sum(axis=1) == days)
    assert np.any(counts >= 2) and np.any(counts == 0)
    assert len({tuple(c) for c in counts}) > replicates // 2


def test_more_minutes_per_day_do_not_narrow_the_interval():
    """Ten times the minutes of the same days leave the interval's width within 10 %: the
    number of days, not of minutes, is what it counts (a bootstrap over minutes would narrow
    it by √10)."""
    few = interval(3, 8, 30, 0.3)
    many = interval(3, 8, 300, 0.3)
    assert (many[1] - many[0]) / (few[1] - few[0]) == pytest.approx(1.0, abs=0.1)


def test_one_day_gives_no_interval_and_two_span_both_days():
    """One day: None and no re-fit (every replicate would be that day: an interval of zero
    width). Two days: the interval reaches from one day's own value to the other's, not a tight
    number between them."""
    assert MIN_BOOTSTRAP_DAYS == 2
    day_of, values = campaign(4, 1, 60, 0.3)
    calls = []
    assert day_bootstrap(1, day_of, lambda w: calls.append(w), 20, 0) is None
    assert calls == []
    day_of, values = campaign(4, 2, 60, 0.3)
    low, high = day_bootstrap(2, day_of, mean_refit(values), 199, 0)
    own = sorted(values[day_of == d].mean() for d in range(2))
    assert own[1] - own[0] > 0.1
    assert (low[0], high[0]) == pytest.approx(own)


def test_a_fit_outside_its_own_interval_is_warned_about():
    """The second structure's case: the re-fits settle away from a fit that stalled at its
    start — the value outside its own interval is a warning, not a tight number."""
    fitted = {
        "fan_supply_w": {"value": 1100.0, "std": 32.0, "ci95": [1150.0, 1365.0]},
        "cop_level": {"value": 1.0, "std": 0.07, "ci95": [0.88, 1.12]},
    }
    (warning,) = interval_warnings(fitted)
    assert warning.startswith("fan_supply_w: the fit 1100 lies outside its own 95 % interval")


def test_days_that_disagree_on_one_knob_are_a_warning_for_every_knob():
    """The second structure's case after the compass search: the windows' g-value shows as
    days that disagree on the solar aperture, while the fans' interval, tight and around its
    value, misses the coach's own 1 100 W (they carry the extra fresh air per passenger). The
    fans are not named on their own, but the closing warning covers every knob."""
    fitted = {
        "solar_scale": {"value": 1.08, "std": 0.0015, "ci95": [1.0754, 1.0996]},
        "fan_supply_w": {"value": 1325.6, "std": 28.6, "ci95": [1151.4, 1375.6]},
        "cop_level": {"value": 1.105, "std": 0.074, "ci95": [0.931, 1.199]},
    }
    first, last = interval_warnings(fitted)
    assert first.startswith("solar_scale: the days disagree")
    assert last.startswith("the days disagree on solar_scale: the logs' coach may differ")
    assert "every fitted value may carry part of that difference" in last
    calm = {n: f for n, f in fitted.items() if n != "solar_scale"}
    assert interval_warnings(calm) == []
