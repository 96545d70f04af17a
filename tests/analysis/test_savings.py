"""The savings and comfort maths of a pair (analysis.savings.compare) on hand-computed series.

Every expected number is worked out by hand in the comments; floating-point sums of 30 samples
agree with them to ~1e-15 relative, so the tolerances are 1e-12.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from trainclimate.analysis.kpi import energy_kwh
from trainclimate.analysis.savings import CoachSeries, PairTotals, compare, savings_pct

T0 = pd.Timestamp("2024-11-28 06:00", tz="UTC")
RULE = 22.0


def approx(value):
    return pytest.approx(value, rel=1e-12, abs=1e-12)


def grid(minutes: float, step_s: float = 60.0) -> pd.DatetimeIndex:
    return pd.date_range(
        T0, periods=round(minutes * 60 / step_s), freq=pd.Timedelta(seconds=step_s)
    )


def per_window(values_kw, samples: int) -> np.ndarray:
    """A piecewise-constant series: each value held for ``samples`` samples."""
    return np.repeat(np.asarray(values_kw, dtype=float), samples)


def coach(time, power_kw, *, t_room=None, affected=None, in_band=None) -> CoachSeries:
    n = len(time)
    return CoachSeries(
        time=time,
        power_kw=power_kw,
        t_room_c=np.full((n, 3), RULE) if t_room is None else t_room,
        t_rule_c=np.full(n, RULE),
        affected=np.zeros(n, bool) if affected is None else affected,
        in_band=in_band,
    )


def minutes(time, *spans) -> np.ndarray:
    """A mask of the samples of a 1-min grid in the given [a, b) minute spans."""
    m = np.arange(len(time))
    out = np.zeros(len(time), bool)
    for a, b in spans:
        out |= (m >= a) & (m < b)
    return out


# --- energy and savings -------------------------------------------------------------------------
def test_energy_and_savings_per_window_on_piecewise_constant_power():
    time = grid(120)  # 1-min samples, four 30-min windows
    act = per_window([2.0, 0.0, 0.0, 4.0], 30)
    act[30:40], act[40:60] = 3.0, 1.0  # window 1: 3 kW for 10 min, then 1 kW for 20 min
    deact = per_window([4.0, 2.0, 0.0, 5.0], 30)  # window 2: neither coach used energy
    c = compare(coach(time, act), coach(time, deact))

    # E = P·t: 2 kW·0.5 h; 3·(1/6) + 1·(1/3); 0; 4·0.5 — and 4·0.5, 2·0.5, 0, 5·0.5
    np.testing.assert_allclose(c.energy_activated_kwh, [1.0, 5 / 6, 0.0, 2.0], rtol=1e-12)
    np.testing.assert_allclose(c.energy_deactivated_kwh, [2.0, 1.0, 0.0, 2.5], rtol=1e-12)
    # 100 (1 − E_act/E_deact): 50, 100/6, undefined (no energy in the deactivated coach), 20
    assert c.savings_30min_pct[0] == approx(50.0)
    assert c.savings_30min_pct[1] == approx(100 / 6)
    assert c.savings_30min_pct[2] is None
    assert c.savings_30min_pct[3] == approx(20.0)
    # overall from the sums over the counted windows: 1 − (23/6)/5.5 = 10/33
    assert c.energy_activated_total_kwh == approx(23 / 6)
    assert c.energy_deactivated_total_kwh == approx(5.5)
    assert c.savings_pct == approx(1000 / 33)
    assert list(c.window_start) == [T0 + pd.Timedelta(minutes=m) for m in (0, 30, 60, 90)]
    assert c.window_min == 30.0
    assert not c.excluded.any() and c.excluded_minutes == 0.0 and c.affected_minutes == 0.0
    assert c.counted_hours == approx(2.0)


def test_rectangle_rule_on_a_10_minute_grid():
    # each sample is the mean power over its 10-min step: E = Σ p · 1/6 h
    time = grid(120, step_s=600.0)
    act = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0])
    c = compare(coach(time, act), coach(time, 2 * act))
    np.testing.assert_allclose(c.energy_activated_kwh, [1.0, 2.5, 2.5, 1.0], rtol=1e-12)
    np.testing.assert_allclose(c.energy_deactivated_kwh, [2.0, 5.0, 5.0, 2.0], rtol=1e-12)
    assert c.savings_30min_pct == [approx(50.0)] * 4
    assert c.savings_pct == approx(50.0)
    assert c.energy_activated_total_kwh == approx(energy_kwh(act, 600.0)) == approx(7.0)


def test_a_window_without_deactivated_energy_is_undefined_but_the_overall_is_not():
    time = grid(60)
    # window 1: the deactivated coach's HVAC idle, the activated one's drawing 0.5 kW
    c = compare(coach(time, per_window([1.0, 0.5], 30)), coach(time, per_window([2.0, 0.0], 30)))
    assert c.savings_30min_pct == [approx(50.0), None]
    assert not c.excluded.any()  # nothing was missing: the window is counted, only undefined
    # the overall from the counted windows' sums: 1 − (0.5 + 0.25)/1.0
    assert c.savings_pct == approx(25.0)
    # no deactivated energy at all: no overall either
    none = compare(coach(time, np.ones(60)), coach(time, np.zeros(60)))
    assert none.savings_pct is None and none.savings_30min_pct == [None, None]


def test_savings_pct():
    assert savings_pct(3.0, 4.0) == 25.0
    assert savings_pct(5.0, 4.0) == -25.0  # the activated coach used more
    assert savings_pct(1.0, 0.0) is None and savings_pct(0.0, 0.0) is None
    assert savings_pct(1.0, float("nan")) is None


# --- excluded windows ---------------------------------------------------------------------------
def test_affected_samples_and_missing_power_exclude_their_windows():
    time = grid(180)  # six windows
    act = per_window([1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 30)
    deact = np.full(180, 8.0)
    act_affected = minutes(time, (40, 41))  # window 1: one minute of the activated coach
    deact_affected = minutes(time, (100, 105))  # window 3: five minutes of the deactivated coach
    act[130] = np.nan  # window 4: one minute of missing data
    a = coach(time, act, affected=act_affected)
    assert a.affected[130] and a.affected.sum() == 2  # missing power counts as affected
    c = compare(a, coach(time, deact, affected=deact_affected))

    assert c.excluded.tolist() == [False, True, False, True, True, False]
    assert c.savings_30min_pct == [approx(87.5), None, approx(62.5), None, None, approx(25.0)]
    assert c.excluded_minutes == 90.0  # three windows of 30 min
    assert c.affected_minutes == 7.0  # 1 + 5 + 1 samples of 1 min
    # the overall over windows 0, 2, 5 only: (0.5 + 1.5 + 3.0) / (3 · 4.0)
    assert c.energy_activated_total_kwh == approx(5.0)
    assert c.energy_deactivated_total_kwh == approx(12.0)
    assert c.savings_pct == approx(100 * (1 - 5.0 / 12.0))
    # an excluded window still reports its energy; the missing minute contributes none
    assert c.energy_activated_kwh[4] == approx(2.5 - 5.0 / 60)
    assert c.energy_activated_kwh[1] == approx(1.0)

    # the same events in 10-min windows: windows 4, 10 and 13 of 18
    ten = compare(a, coach(time, deact, affected=deact_affected), window_min=10.0)
    assert np.flatnonzero(ten.excluded).tolist() == [4, 10, 13]
    assert ten.excluded_minutes == 30.0 and ten.affected_minutes == 7.0
    assert len(ten.savings_30min_pct) == 18 and ten.window_min == 10.0


def test_everything_excluded_leaves_no_overall():
    time = grid(60)
    c = compare(
        coach(time, np.ones(60), affected=minutes(time, (10, 11), (50, 51))),
        coach(time, np.ones(60)),
    )
    assert c.excluded.all() and c.excluded_minutes == 60.0
    assert c.savings_pct is None and c.savings_30min_pct == [None, None]
    assert c.energy_activated_total_kwh == 0.0 == c.energy_deactivated_total_kwh


# --- the counted period: start and end ----------------------------------------------------------
def test_windows_count_from_start_and_drop_the_incomplete_last_one():
    time = grid(120)
    act = np.arange(120, dtype=float)  # minute m draws m kW
    deact = np.full(120, 60.0)
    affected = minutes(time, (10, 11), (110, 111))  # before start, and in the dropped tail
    t_room = np.full((120, 3), RULE)
    t_room[5, 0] = RULE + 3.0  # a violation before start: not counted
    start = T0 + pd.Timedelta(minutes=15)
    c = compare(coach(time, act, affected=affected, t_room=t_room), coach(time, deact), start=start)

    # windows [15, 45), [45, 75), [75, 105) min; [105, 120) is incomplete and dropped
    assert list(c.window_start) == [start + pd.Timedelta(minutes=m) for m in (0, 30, 60)]
    # Σ m over a window / 60: (15+44)·30/2/60, (45+74)·15/60, (75+104)·15/60
    np.testing.assert_allclose(c.energy_activated_kwh, [14.75, 29.75, 44.75], rtol=1e-12)
    np.testing.assert_allclose(c.energy_deactivated_kwh, [30.0] * 3, rtol=1e-12)
    assert c.savings_30min_pct == [approx(100 * (1 - e / 30)) for e in (14.75, 29.75, 44.75)]
    assert c.savings_30min_pct[2] < 0  # the activated coach used more: negative savings
    assert c.savings_pct == approx(100 * (1 - 89.25 / 90.0))
    assert not c.excluded.any() and c.excluded_minutes == 0.0 and c.affected_minutes == 0.0
    assert c.counted_hours == approx(1.5)
    assert c.avg_hourly_violation_k == 0.0


def test_end_ends_the_counted_period():
    time = grid(120)
    act, deact = np.arange(120, dtype=float), np.full(120, 60.0)
    t_room = np.full((120, 3), RULE)
    t_room[95:, 1] = RULE + 2.0  # after the counted period
    for end_min in (90, 100):  # three complete windows either way
        c = compare(
            coach(time, act, t_room=t_room),
            coach(time, deact),
            end=T0 + pd.Timedelta(minutes=end_min),
        )
        assert len(c.savings_30min_pct) == 3 and c.counted_hours == approx(1.5)
        # Σ m for m < 90, over 60
        assert c.energy_activated_kwh.sum() == approx(89 * 90 / 2 / 60)
        assert c.avg_hourly_violation_k == 0.0 and c.discomfort_kh == [0.0, 0.0, 0.0]
    empty = compare(coach(time, act), coach(time, deact), start=T0 + pd.Timedelta(minutes=100))
    assert empty.savings_30min_pct == [] and empty.savings_pct is None
    assert empty.counted_hours == 0.0 and empty.avg_hourly_violation_k == 0.0
    backwards = compare(coach(time, act), coach(time, deact), end=T0 - pd.Timedelta(minutes=5))
    assert backwards.savings_30min_pct == [] and len(backwards.window_start) == 0


def test_windows_outside_the_data_are_excluded_as_missing():
    # the counted period reaching past the series: its windows have no (or partial) data
    time = grid(60)
    act, deact = np.full(60, 1.0), np.full(60, 2.0)
    late = compare(coach(time, act), coach(time, deact), end=T0 + pd.Timedelta(minutes=105))
    assert late.excluded.tolist() == [False, False, True]  # [60, 90) min has no sample
    assert late.savings_30min_pct == [approx(50.0), approx(50.0), None]
    assert late.excluded_minutes == 30.0 and late.savings_pct == approx(50.0)
    early = compare(coach(time, act), coach(time, deact), start=T0 - pd.Timedelta(minutes=15))
    # [−15, 15) min holds 15 of its 30 minutes: not a window to compare
    assert early.excluded.tolist() == [True, False]
    assert early.excluded_minutes == 30.0 and early.savings_30min_pct[0] is None
    assert early.energy_activated_total_kwh == approx(0.5)


# --- comfort ------------------------------------------------------------------------------------
def test_average_hourly_violation_by_hand():
    time = grid(120)
    act_room = np.full((120, 3), RULE)
    act_room[30:60, 0] = RULE + 1.5  # deck up 1.5 K above T_rule for 30 min: 0.5 K over T_max
    deact_room = np.full((120, 3), RULE)
    deact_room[0:60, 2] = RULE - 1.2  # deck low 1.2 K below for 1 h: 0.2 K over T_max
    deact_room[60:90, 1] = RULE + 0.9  # inside the band: no violation
    power = np.ones(120)
    c = compare(coach(time, power, t_room=act_room), coach(time, power, t_room=deact_room))
    # 0.5 K · 0.5 h = 0.25 K·h on one deck; / 2 h / 3 decks
    assert c.discomfort_kh == [approx(0.25), 0.0, 0.0]
    assert c.avg_hourly_violation_k == approx(0.25 / 2 / 3)
    # 0.2 K · 1 h on one deck
    assert c.baseline_discomfort_kh == [0.0, 0.0, approx(0.2)]
    assert c.baseline_violation_k == approx(0.2 / 2 / 3)
    assert c.counted_hours == approx(2.0)
    # a tighter band, T_max = 0.5 K: 1.0 K · 0.5 h; 0.7 K · 1 h and 0.4 K · 0.5 h
    tight = compare(
        coach(time, power, t_room=act_room), coach(time, power, t_room=deact_room), t_max_k=0.5
    )
    assert tight.discomfort_kh == [approx(0.5), 0.0, 0.0]
    assert tight.baseline_discomfort_kh == [0.0, approx(0.2), approx(0.7)]
    assert tight.avg_hourly_violation_k == approx(0.5 / 2 / 3)


def test_violation_outside_the_band_or_while_affected_is_not_counted():
    time = grid(120)
    room = np.full((120, 3), RULE)
    room[30:60, 0] = RULE + 1.5  # 0.25 K·h as above
    room[90:120, 1] = RULE + 8.0  # in slumber (no comfort band): not counted
    room[60:70, 2] = RULE - 4.0  # while affected: not counted
    in_band = ~minutes(time, (90, 120))
    power = np.ones(120)
    affected = minutes(time, (60, 70))
    c = compare(
        coach(time, power, t_room=room, in_band=in_band), coach(time, power, affected=affected)
    )
    # counted: 120 − 30 (slumber) − 10 (affected) min
    assert c.counted_hours == approx(80 / 60)
    assert c.discomfort_kh == [approx(0.25), 0.0, 0.0]
    assert c.avg_hourly_violation_k == approx(0.25 / (80 / 60) / 3)
    # the deactivated coach is counted over the same samples: the mask is the pair's
    baseline = compare(
        coach(time, power, in_band=in_band), coach(time, power, t_room=room, affected=affected)
    )
    assert baseline.baseline_discomfort_kh == [approx(0.25), 0.0, 0.0]
    assert baseline.counted_hours == approx(80 / 60)
    # the band-less time is still counted for energy: no window was excluded by it
    assert np.flatnonzero(c.excluded).tolist() == [2]


def test_to_dict_is_json():
    time = grid(60)
    c = compare(coach(time, np.ones(60)), coach(time, np.full(60, 2.0)))
    data = json.loads(json.dumps(c.to_dict()))
    assert data["savings_pct"] == approx(50.0)
    assert data["savings_30min_pct"] == [approx(50.0), approx(50.0)]
    assert data["window_start"] == [T0.isoformat(), (T0 + pd.Timedelta(minutes=30)).isoformat()]
    assert data["excluded_windows"] == [False, False] and data["excluded_minutes"] == 0.0


# --- bad input ----------------------------------------------------------------------------------
def test_different_grids_are_refused():
    time = grid(60)
    a = coach(time, np.ones(60))
    with pytest.raises(ValueError, match="one time grid"):
        compare(a, coach(time + pd.Timedelta(seconds=30), np.ones(60)))
    with pytest.raises(ValueError, match="one time grid"):
        compare(a, coach(grid(61), np.ones(61)))


def test_a_non_uniform_grid_is_refused():
    time = grid(60).delete(30)  # one sample missing: a 2-min step
    with pytest.raises(ValueError, match="uniform"):
        compare(coach(time, np.ones(59)), coach(time, np.ones(59)))
    one = grid(1)
    with pytest.raises(ValueError, match="two samples"):
        compare(coach(one, [1.0]), coach(one, [1.0]))


def test_series_of_the_wrong_length_are_refused():
    time = grid(60)
    with pytest.raises(ValueError, match="length"):
        coach(time, np.ones(59))
    with pytest.raises(ValueError, match="length"):
        coach(time, np.ones(60), affected=np.zeros(61, bool))
    with pytest.raises(ValueError, match="length"):
        coach(time, np.ones(60), in_band=np.ones(30, bool))
    with pytest.raises(ValueError):
        coach(time, np.ones(60), t_room=np.full((59, 3), RULE))


def test_pooled_totals_are_the_sum_in_order_to_the_bit():
    # magnitudes over eight decades: a sum taken pairwise, or in another order, rounds otherwise
    rng = np.random.default_rng(1)

    def part() -> PairTotals:
        scale = 10.0 ** rng.integers(-4, 4, size=4)
        return PairTotals(
            *(rng.exponential(size=2) * scale[:2]),
            int(rng.integers(0, 100)),
            int(rng.integers(0, 10)),
            30.0,
            float(rng.exponential() * scale[2]),
            rng.exponential(size=3) * scale[3],
            rng.exponential(size=3),
        )

    for n in (0, 1, 2, 450, 3000):
        parts = [part() for _ in range(n)]
        added = PairTotals.empty(30.0)
        for p in parts:
            added = added + p
        pooled = PairTotals.pooled(parts, 30.0)
        for name in ("energy_activated_kwh", "energy_deactivated_kwh", "counted_hours"):
            assert getattr(pooled, name) == getattr(added, name)
        assert (pooled.windows, pooled.excluded_windows) == (added.windows, added.excluded_windows)
        assert np.array_equal(pooled.discomfort_kh, added.discomfort_kh)
        assert np.array_equal(pooled.baseline_discomfort_kh, added.baseline_discomfort_kh)
    with pytest.raises(ValueError, match="window lengths"):
        PairTotals.pooled([PairTotals.empty(15.0)], 30.0)
