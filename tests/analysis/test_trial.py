"""Trial plans and the savings estimators that cancel the coaches' own difference."""

import itertools
from concurrent.futures import ThreadPoolExecutor
from datetime import date

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from trainclimate.analysis import studentized
from trainclimate.analysis.trial import (
    TrialDays,
    daily,
    estimate,
    estimate_many,
    estimates_later,
)
from trainclimate.analysis.trial_plan import (
    NEITHER,
    activated,
    day_start,
    service_day,
    service_days,
)
from trainclimate.analysis.trial_pool import pool


def test_a_service_day_starts_at_the_local_switch_hour():
    # 02:59 local on 29 Nov is still the service day of 28 Nov; 03:00 starts the 29th
    assert service_day(pd.Timestamp("2024-11-29 01:59", tz="UTC")) == date(2024, 11, 28)
    assert service_day(pd.Timestamp("2024-11-29 02:00", tz="UTC")) == date(2024, 11, 29)
    assert service_day(pd.Timestamp("2024-07-01 00:59", tz="UTC"), switch_hour=3) == date(
        2024, 6, 30
    )  # summer time: 03:00 local is 01:00 UTC
    times = pd.date_range("2024-11-28 01:00", periods=4, freq="1h", tz="UTC")
    assert list(service_days(times)) == [
        date(2024, 11, 27).toordinal(),
        date(2024, 11, 28).toordinal(),
        date(2024, 11, 28).toordinal(),
        date(2024, 11, 28).toordinal(),
    ]
    # the days service_days gives (numpy integers) are what activated takes
    assert [activated("alternate", d) for d in service_days(times)] == [1, 0, 0, 0]
    assert day_start(date(2024, 11, 28)) == pd.Timestamp("2024-11-28 02:00", tz="UTC")
    # the day the clocks go back is 25 hours long; it still starts at 03:00 local
    assert day_start(date(2024, 10, 27)) == pd.Timestamp("2024-10-27 02:00", tz="UTC")
    assert day_start(date(2024, 10, 28)) == pd.Timestamp("2024-10-28 02:00", tz="UTC")


def test_plans_assign_the_layer_by_day():
    days = range(date(2024, 11, 1).toordinal(), date(2024, 11, 1).toordinal() + 40)
    assert [activated("fixed", d, fixed=1) for d in days] == [1] * 40
    alt = [activated("alternate", d) for d in days]
    assert all(a != b for a, b in itertools.pairwise(alt))
    assert [activated("reference", d) for d in days] == [NEITHER] * 40
    rnd = [activated("randomized", d, seed=7) for d in days]
    start = days[0] + days[0] % 2  # blocks are ordinals 2k, 2k + 1
    for k in range(start, days[-1], 2):
        block = rnd[k - days[0] : k - days[0] + 2]
        assert sorted(block) == [0, 1]  # balanced in every block of two
    assert rnd == [activated("randomized", d, seed=7) for d in days]  # reproducible
    assert rnd != [activated("randomized", d, seed=8) for d in days]
    with pytest.raises(ValueError, match="unknown plan"):
        activated("weekly", days[0])


def _crossover(n_days, saving, coach_ratio, noise, seed, plan="alternate"):
    """Days of a pair whose coach 0 uses ``coach_ratio`` times coach 1's energy, the layer saving
    ``saving``, with a day level and log-normal noise."""
    rng = np.random.default_rng(seed)
    day = np.arange(n_days)
    act = np.array([activated(plan, int(d), seed=seed) for d in day])
    level = 100 * np.exp(rng.normal(0, 0.3, n_days))  # weather, operation: cancels in the ratio
    x = np.log(coach_ratio) + np.select([act == 0, act == 1], [1, -1], 0) * np.log(1 - saving)
    x = x + rng.normal(0, noise, n_days)
    energy = np.c_[level * np.exp(x), level]
    return TrialDays(day, energy, act, np.full(n_days, 40))


def _fixed_with_reference():
    """Ten days of a fixed plan (coach 0 activated) followed by eight reference days."""
    fixed = _crossover(10, 0.06, 1.12, 0.01, 2, plan="fixed")
    ref = _crossover(8, 0.06, 1.12, 0.01, 3, plan="reference")
    return TrialDays(
        np.r_[fixed.day, ref.day + 100],
        np.r_[fixed.energy_kwh, ref.energy_kwh],
        np.r_[fixed.activated, ref.activated],
        np.r_[fixed.windows, ref.windows],
    )


def test_the_crossover_cancels_the_coaches_difference():
    # coach 0 uses 12 % more than coach 1: the naive figure is far off, the crossover is not
    days = _crossover(14, 0.06, 1.12, 1e-3, seed=1)
    e = estimate(days)
    assert e.estimator == "crossover"
    assert e.savings_pct == pytest.approx(6.0, abs=0.1)
    low, high = e.savings_ci95_pct
    assert low < 6.0 < high and high - low < 0.5
    assert e.days == {"coach_0": 7, "coach_1": 7, "reference": 0, "dropped": {}}
    assert abs(e.naive_savings_pct - 6.0) > 0.3  # the naive pools unequal coaches
    assert e.meets_guideline_14 is True
    assert e.distinguishable is True


def test_the_interval_covers_the_saving_at_its_confidence():
    covered = 0
    for seed in range(100):
        e = estimate(_crossover(14, 0.06, 1.1, 0.04, seed), n_resamples=999, seed=seed)
        low, high = e.savings_ci95_pct
        covered += low <= 6.0 <= high
    assert 90 <= covered <= 100  # nominal 95 %: a bootstrap-t keeps it with 7 days a group


def test_days_to_target_follow_the_spread():
    wide = estimate(_crossover(14, 0.06, 1.1, 0.06, 3))
    narrow = estimate(_crossover(14, 0.06, 1.1, 0.01, 3))
    assert narrow.days_to_target == 0
    half = (wide.savings_ci95_pct[1] - wide.savings_ci95_pct[0]) / 2
    assert half > 2.0
    assert wide.days_to_target == pytest.approx(14 * (half / 2.0) ** 2 - 14, abs=1)


def test_a_fixed_plan_is_confounded_unless_a_reference_period_corrects_it():
    fixed = _crossover(10, 0.06, 1.12, 0.01, 2, plan="fixed")
    e = estimate(fixed)
    assert e.estimator == "fixed_naive"
    assert e.savings_ci95_pct is None and "confounded" in e.ci_reason
    assert e.savings_pct == e.naive_savings_pct
    assert e.savings_pct == pytest.approx(100 * (1 - 0.94 * 1.12), abs=1.0)
    both = _fixed_with_reference()
    corrected = estimate(both)
    assert corrected.estimator == "fixed_reference"
    assert corrected.savings_pct == pytest.approx(6.0, abs=0.5)
    assert corrected.savings_ci95_pct[0] < 6.0 < corrected.savings_ci95_pct[1]


def test_too_few_days_give_no_interval_with_a_reason():
    e = estimate(_crossover(4, 0.06, 1.1, 0.02, 1))
    assert e.estimator == "crossover" and e.savings_pct is not None
    assert e.savings_ci95_pct is None and "fewer than 3 days" in e.ci_reason
    empty = estimate(TrialDays(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0)))
    assert empty.estimator is None and empty.savings_pct is None
    assert empty.ci_reason == "no comparable days yet"


def test_windows_make_days_and_odd_days_are_dropped_with_their_reason():
    day = np.repeat([10, 11, 12, 13], 6)
    energy = np.ones((24, 2))
    act = np.repeat([0, 1, 0, 1], 6)
    act[18] = 0  # day 13 ran both ways
    counted = np.ones(24, bool)
    counted[6:9] = False  # day 11 keeps 3 windows
    energy[12:18, 1] = 0.0  # coach 1 used nothing on day 12
    d = daily(day, energy, act, counted, min_windows=4)
    assert list(d.day) == [10]
    assert d.dropped == {"too_few_windows": 1, "no_energy": 1, "mixed_activation": 1}
    assert d.energy_kwh.tolist() == [[6.0, 6.0]] and list(d.windows) == [6]


def test_trains_pool_into_the_fleet():
    estimates = [estimate(_crossover(14, 0.06, r, 0.02, s)) for s, r in enumerate([1.1, 0.9, 1.0])]
    confounded = estimate(_crossover(10, 0.06, 1.12, 0.01, 2, plan="fixed"))
    fleet = pool([*estimates, confounded])
    assert fleet["trains_pooled"] == 3 and fleet["trains_confounded"] == 1
    low, high = fleet["savings_ci95_pct"]
    assert low < fleet["savings_pct"] < high
    assert fleet["savings_pct"] == pytest.approx(6.0, abs=0.5)
    # pooling narrows the interval below any train's
    assert high - low < min(e.savings_ci95_pct[1] - e.savings_ci95_pct[0] for e in estimates)
    assert pool([confounded])["savings_ci95_pct"] is None


def test_one_train_pooled_alone_keeps_its_interval():
    e = estimate(_crossover(8, 0.06, 1.1, 0.03, 5))
    fleet = pool([e])
    assert fleet["savings_pct"] == pytest.approx(e.savings_pct)
    assert fleet["savings_ci95_pct"][1] - fleet["savings_ci95_pct"][0] == pytest.approx(
        e.savings_ci95_pct[1] - e.savings_ci95_pct[0]
    )


@pytest.mark.parametrize("switch_hour", [0, 3, 23])
def test_service_days_are_the_dates_of_the_local_times_less_the_switch_hour(switch_hour):
    # both daylight-saving changes of 2024 (31 March, 27 October) and a winter new year
    times = pd.DatetimeIndex(
        np.concatenate(
            [
                pd.date_range(start, periods=4 * 24 * 3, freq="15min", tz="UTC")
                for start in ("2024-03-29 12:00", "2024-10-25 12:00", "2023-12-30 12:00")
            ]
        )
    )
    local = times.tz_convert("Europe/Zurich") - pd.Timedelta(hours=switch_hour)
    expected = [d.toordinal() for d in local.tz_localize(None).normalize().date]
    days = service_days(times, switch_hour)
    assert days.dtype == np.int64
    assert days.tolist() == expected
    assert days.tolist() == [service_day(t, switch_hour).toordinal() for t in times]


def _scipy_interval(samples, coef, n_resamples=4999, seed=0):
    """The 95 % and 68 % intervals of ln(1 − s) and its standard error as the bootstrap-t was
    computed with scipy.stats.bootstrap, one pair at a time."""
    a, b = samples
    theta = coef * (a.mean() - b.mean())
    se = abs(coef) * np.sqrt(np.var(a, ddof=1) / len(a) + np.var(b, ddof=1) / len(b))

    def pivot(a, b, axis=-1):
        t = coef * (np.mean(a, axis=axis) - np.mean(b, axis=axis))
        var = np.var(a, axis=axis, ddof=1) / a.shape[axis]
        s = abs(coef) * np.sqrt(var + np.var(b, axis=axis, ddof=1) / b.shape[axis])
        with np.errstate(divide="ignore", invalid="ignore"):
            return (t - theta) / s

    with np.errstate(all="ignore"):
        res = stats.bootstrap(
            samples,
            pivot,
            n_resamples=n_resamples,
            method="percentile",
            vectorized=True,
            rng=np.random.default_rng(seed),
        )
    q = np.quantile(np.nan_to_num(res.bootstrap_distribution, nan=0.0), [0.025, 0.16, 0.84, 0.975])
    bounds = 100.0 * (1.0 - np.exp(theta - q * se))  # the savings fall as ln(1 − s) rises
    return [bounds[0], bounds[3]], [bounds[1], bounds[2]], 100.0 * np.exp(theta) * se


def test_the_batched_bootstrap_is_scipys():
    # with 3 + 3 days, 1/81 of the resamples have no spread in either group (studentized to ±inf)
    rng = np.random.default_rng(11)
    sizes = [tuple(rng.integers(3, 21, 2)) for _ in range(24)] + [(7, 7)] * 4 + [(3, 3)] * 8
    pairs, expected = [], []
    for k, (n_a, n_b) in enumerate(sizes):
        crossover = k % 2 == 0
        # a saving of 2–10 % and a day-to-day spread down to 1e-9 of the log-ratios' level
        effect = np.log(1 - rng.uniform(0.02, 0.1)) * (0.5 if crossover else 1.0)
        spread = 10.0 ** rng.choice([-9, -6, -2, -1])
        level = np.log(rng.uniform(0.8, 1.25))
        if crossover:
            act = np.r_[np.zeros(n_a, int), np.ones(n_b, int)]
            x = level + np.where(act == 0, effect, -effect)
            coef = 0.5
        else:
            act = np.r_[np.full(n_a, k % 4 // 2), np.full(n_b, NEITHER)]
            sign = 1.0 if act[0] == 0 else -1.0
            x = level + np.where(act == NEITHER, 0.0, sign * effect)
            coef = sign
        x = x + rng.normal(0.0, spread, n_a + n_b)
        energy = np.c_[50.0 * np.exp(x), np.full(n_a + n_b, 50.0)]
        pairs.append(TrialDays(np.arange(n_a + n_b), energy, act, np.full(n_a + n_b, 40)))
        logs = np.log(energy[:, 0] / energy[:, 1])
        expected.append(_scipy_interval((logs[:n_a], logs[n_a:]), coef))
    got = estimate_many(pairs)
    for e, (ci95, ci68, se) in zip(got, expected, strict=True):
        assert e.savings_ci95_pct == pytest.approx(ci95, rel=1e-9)
        assert e.standard_error_pct == pytest.approx(se, rel=1e-9)
        assert e.meets_guideline_14 == ((ci68[1] - ci68[0]) / 2 < 0.5 * abs(e.savings_pct))
    assert {e.estimator for e in got} == {"crossover", "fixed_reference"}
    assert {e.meets_guideline_14 for e in got} == {True, False}


def test_estimating_many_pairs_at_once_is_estimating_each():
    fixed = _crossover(10, 0.06, 1.12, 0.01, 2, plan="fixed")
    fixed_reference = _fixed_with_reference()
    act = np.arange(8) % 2
    energy = np.c_[np.where(act == 0, 2.0, 1.0), np.ones(8)]  # log-ratios ln 2 and 0, exactly
    no_spread = TrialDays(np.arange(8), energy, act, np.full(8, 40))
    pairs = [
        _crossover(14, 0.06, 1.1, 0.03, 1),
        fixed_reference,
        fixed,
        TrialDays(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0)),
        _crossover(4, 0.06, 1.1, 0.02, 1),
        no_spread,
        _crossover(14, 0.06, 0.9, 0.05, 2),  # the first's sizes: one bootstrap for both
        _crossover(9, 0.03, 1.0, 0.02, 4),
        # more pairs of the first's sizes than a block of rows holds: two blocks
        *(_crossover(14, 0.05, 1.0 + k / 20, 0.02, 5 + k) for k in range(studentized.BLOCK_ROWS)),
    ]
    got = estimate_many(pairs, target_half_width_pct=1.0, n_resamples=999, seed=3)
    each = [estimate(d, target_half_width_pct=1.0, n_resamples=999, seed=3) for d in pairs]
    with ThreadPoolExecutor(2) as executor:  # the bootstraps on a caller's threads
        later = estimates_later(pairs, executor, target_half_width_pct=1.0, n_resamples=999, seed=3)
        assert later() == got
    assert [e.estimator for e in got] == [
        "crossover",
        "fixed_reference",
        "fixed_naive",
        None,
        "crossover",
        "crossover",
        "crossover",
        "crossover",
    ] + ["crossover"] * studentized.BLOCK_ROWS
    assert sum(e.savings_ci95_pct is not None for e in got) == 4 + studentized.BLOCK_ROWS
    assert [e.ci_reason for e in got[2:6]] == [
        "fixed plan: the saving is confounded with the coaches' own difference",
        "no comparable days yet",
        "fewer than 3 days in a group of the crossover estimate",
        "no day-to-day spread",
    ]
    for e, one in zip(got, each, strict=True):
        if one.savings_ci95_pct is None:
            assert e.savings_ci95_pct is None
        else:
            # exactly: a pair's interval does not depend on the pairs computed with it
            assert e.savings_ci95_pct == one.savings_ci95_pct
        assert e.standard_error_pct == one.standard_error_pct
        assert (e.estimator, e.savings_pct, e.ci_reason, e.naive_savings_pct, e.days) == (
            one.estimator,
            one.savings_pct,
            one.ci_reason,
            one.naive_savings_pct,
            one.days,
        )
        assert (e.days_to_target, e.meets_guideline_14) == (
            one.days_to_target,
            one.meets_guideline_14,
        )
    assert estimate_many([]) == []
    with pytest.raises(ValueError, match="at least one resample"):
        estimate_many(pairs, n_resamples=0)


def test_pairs_estimated_together_have_each_pairs_own_mean_and_variance_to_the_bit():
    """Pairs of the same group sizes are estimated together (one array per group); each pair's
    estimate and standard error are still numpy's mean and variance of its own days, exactly,
    as are its activated days' energies summed in their order (the naive figure)."""
    pairs = [
        _crossover(n, 0.05, 1.0 + n / 50, 0.03, seed) for n in (9, 9, 9, 12, 7) for seed in (1, 2)
    ]
    pairs += [_fixed_with_reference()]
    for days, e in zip(pairs, estimate_many(pairs, n_resamples=99), strict=True):
        x = np.log(days.energy_kwh[:, 0] / days.energy_kwh[:, 1])
        on = days.activated != NEITHER
        a, b = x[days.activated == 0], x[days.activated == 1]
        coef = 0.5
        if not len(a) or not len(b):
            a, b = (a, x[~on]) if len(a) else (b, x[~on])
            coef = 1.0 if e.days["coach_0"] else -1.0
        assert e.estimator == ("crossover" if coef == 0.5 else "fixed_reference")
        theta = coef * (np.mean(a) - np.mean(b))
        se = abs(coef) * np.sqrt(np.var(a, ddof=1) / len(a) + np.var(b, ddof=1) / len(b))
        assert e.savings_pct == float(100.0 * (1.0 - np.exp(theta)))
        assert e.standard_error_pct == float(100.0 * np.exp(theta) * se)
        act = days.energy_kwh[on, days.activated[on]].sum()
        deact = days.energy_kwh[on, 1 - days.activated[on]].sum()
        assert e.naive_savings_pct == float(100.0 * (1.0 - act / deact))
    with pytest.raises(ValueError, match="0, 1 or NEITHER"):
        estimate(TrialDays(np.arange(4), np.ones((4, 2)), np.array([0, 1, 2, 0]), np.full(4, 40)))


def test_an_interval_that_overflows_is_no_interval_not_an_error():
    """Energies exactly proportional in a crossover of 3 + 3 days: the log-ratios differ by
    rounding only, and resamples without spread put the largest floats among the studentized
    values; the interval's bounds overflow, so the estimate has none, with its reason."""
    e0 = np.array([24.378260918638002, 31.405935714716332, 38.20270042814721,
                   48.03202646762443, 17.789052368695614, 34.18462431859213])  # fmt: skip
    days = TrialDays(np.arange(6), np.c_[e0, 1.1 * e0], np.arange(6) % 2, np.full(6, 40))
    e = estimate(days)
    assert e.estimator == "crossover" and e.savings_pct == pytest.approx(0.0, abs=1e-9)
    assert e.savings_ci95_pct is None and e.ci_reason == "the bootstrap is degenerate"
    assert e.days_to_target is None and e.standard_error_pct is None


@pytest.mark.parametrize(
    ("n_a", "n_b", "distinct"), [(3, 3, True), (3, 5, True), (4, 4, True), (12, 14, False)]
)
def test_distinct_resamples_give_the_quantiles_of_all_resamples(n_a, n_b, distinct):
    """With few days each distinct resample is computed once and counted as often as drawn: the
    same order statistics, so the same quantiles as every resample computed (±inf included);
    with many days, where most resamples differ, they are computed as drawn."""
    counts_a, counts_b = studentized.resample_counts(n_a, n_b, 4999, 0)
    distinct_a, distinct_b, draws = studentized.distinct_resamples(n_a, n_b, 4999, 0)
    if not distinct:
        assert draws is None and distinct_a is counts_a and distinct_b is counts_b
        return
    assert draws.sum() == 4999 and len(draws) < 4999 / 2
    seen = {tuple(c) for c in np.concatenate([counts_a, counts_b]).T}
    assert {tuple(c) for c in np.concatenate([distinct_a, distinct_b]).T} == seen
    rng = np.random.default_rng(n_a * n_b)
    a = rng.normal(0.05, 0.02, (3, n_a))
    b = rng.normal(-0.05, 0.02, (3, n_b))
    a[2] = 0.1  # no spread in a: a resample of b's one day, repeated, studentizes to ±inf
    coef = np.array([0.5, -1.0, 0.5])
    full = studentized.pivot_quantiles(a, b, coef, counts_a, counts_b)
    got = studentized.pivot_quantiles(a, b, coef, distinct_a, distinct_b, draws)
    np.testing.assert_allclose(got, full, rtol=1e-12, atol=0)
    # 1/9 of the resamples of 3 days are ±inf, and pull the outer quantiles out of range
    assert (np.abs(full[2]) > 1e300).any() == (n_b == 3)
