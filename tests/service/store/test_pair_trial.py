"""The pair trial's window analysis, all pairs at once: each pair exactly as alone, and the
vectorized lead-in and service days as the loops they replace."""

from __future__ import annotations

import numpy as np
import pandas as pd

from trainclimate.analysis import trial, trial_plan
from trainclimate.service.store import pair_labels, pair_trial
from trainclimate.service.store.pair_labels import COUNTS, SUMS, SUMS_INDEX, UNLABELLED


def _lead_in_loop(label: np.ndarray, n: int) -> np.ndarray:
    """The lead-in as a loop over the windows: a change between labelled windows marks it and
    the n − 1 after it."""
    out = np.zeros(len(label), bool)
    previous = None
    for w, x in enumerate(label):
        if x == UNLABELLED:
            continue
        if previous is not None and x != previous:
            out[w : w + n] = True
        previous = x
    return out


def test_the_lead_in_marks_the_windows_after_each_change_of_roles():
    rng = np.random.default_rng(3)
    choices = np.array([0, 1, trial_plan.NEITHER, UNLABELLED])
    labels = choices[rng.choice(4, size=(200, 40), p=[0.4, 0.3, 0.1, 0.2])]
    for lead_in_min, n in ((60.0, 2), (30.0, 1), (100.0, 4), (3000.0, 100)):
        got = pair_labels.lead_in(labels, 30.0, lead_in_min)
        for row, marked in zip(labels, got, strict=True):
            np.testing.assert_array_equal(marked, _lead_in_loop(row, n))
    # by hand: 0 0 – 1 1 1 0: the change to 1 marks two windows, the one back to 0 one (the end)
    label = np.array([0, 0, UNLABELLED, 1, 1, 1, 0])
    assert pair_labels.lead_in(label, 30.0).tolist() == [0, 0, 0, 1, 1, 0, 1]
    assert pair_labels.lead_in(label[:0], 30.0).shape == (0,)


def test_the_lead_in_taken_in_parts_is_the_lead_in_taken_whole():
    rng = np.random.default_rng(5)
    choices = np.array([0, 1, trial_plan.NEITHER, UNLABELLED])
    labels = choices[rng.choice(4, size=(300, 30), p=[0.3, 0.3, 0.1, 0.3])]
    for lead_in_min in (60.0, 30.0, 100.0):
        whole = pair_labels.lead_in(labels, 30.0, lead_in_min)
        # every pair cut at its own point: the first part from nothing before it, the second
        # from the state the first one leaves
        for cut in (0, 1, 2, 7, 29, 30):
            state = pair_labels.lead_state(labels[:, :cut])
            second = pair_labels.lead_in(labels[:, cut:], 30.0, lead_in_min, state)
            first = pair_labels.lead_in(labels[:, :cut], 30.0, lead_in_min)
            np.testing.assert_array_equal(np.concatenate([first, second], axis=1), whole)
    # by hand: a change in the last window of the first part runs into the second
    state = pair_labels.lead_state(np.array([0, 0, 1]))
    assert (int(state[0]), int(state[1])) == (1, 1)
    assert pair_labels.lead_in(np.array([1, 1, 1]), 30.0, entering=state).tolist() == [1, 0, 0]
    # and nothing labelled in a part carries the state before it through
    state = pair_labels.lead_state(np.array([UNLABELLED] * 3), state)
    assert (int(state[0]), int(state[1])) == (1, 4)
    assert pair_labels.lead_in(np.array([0, 0]), 30.0, entering=state).tolist() == [1, 1]


def _pair(rng, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A pair's windows: clean 30-minute sums with some gaps and lost links, and setpoint
    counts whose roles swap every 48 windows, with fallbacks and missing ticks."""
    grid = np.zeros((n, len(SUMS)))
    grid[:, SUMS_INDEX["minutes"]] = 30
    grid[:, SUMS_INDEX["counted_minutes"]] = 30
    for c in ("energy_0_kwh", "energy_1_kwh"):
        grid[:, SUMS_INDEX[c]] = rng.uniform(2.0, 4.0, n)
    for c in ("energy_0_hvac_kwh", "energy_1_hvac_kwh"):
        grid[:, SUMS_INDEX[c]] = 0.8 * grid[:, SUMS_INDEX[c.replace("_hvac", "")]]
    for c in SUMS:
        if c.startswith("discomfort"):
            grid[:, SUMS_INDEX[c]] = rng.exponential(0.01, n) * (rng.random(n) < 0.2)
    grid[rng.random(n) < 0.05, SUMS_INDEX["minutes"]] = 25
    grid[rng.random(n) < 0.03, SUMS_INDEX["disconnected_minutes"]] = 3
    if rng.random() < 0.5:
        grid[rng.random(n) < 0.05, SUMS_INDEX["unsplit_minutes"]] = 30
    counts = np.zeros((n, 2, len(COUNTS)))
    counts[..., COUNTS.index("ticks")] = 6
    first = rng.integers(2)
    for w in range(n):
        on = (first + w // 48) % 2
        counts[w, on, COUNTS.index("ddpc")] = 6
        counts[w, 1 - on, COUNTS.index("inactive")] = 6
    counts[rng.random(n) < 0.03, 0, COUNTS.index("fallback")] = 1
    counts[rng.random(n) < 0.02, :, COUNTS.index("ticks")] = 0
    return grid, counts


def test_pairs_analysed_together_are_each_as_alone():
    rng = np.random.default_rng(7)
    n = 48 * 9
    first = pd.Timestamp("2025-03-20T00:00Z")  # over the change to summer time
    pairs = [_pair(rng, n) for _ in range(12)]
    hours = [3, 3, 0, 23, 3, 5, 3, 3, 0, 3, 3, 3]
    w0 = round(first.timestamp()) // 1800
    together = pair_trial.pair_results(
        np.arange(w0, w0 + n),
        np.stack([g for g, _ in pairs]),
        np.stack([c for _, c in pairs]),
        30.0,
        hours,
    )
    estimators = set()
    for (grid, counts), hour, batched in zip(pairs, hours, together, strict=True):
        alone = pair_trial.pair_result(grid, counts, first, 30.0, hour)
        assert pair_trial.figures(batched, 30.0) == pair_trial.figures(alone, 30.0)
        np.testing.assert_array_equal(batched["label"], alone["label"])
        np.testing.assert_array_equal(batched["code"], alone["code"])
        estimators.add(batched["estimate"].estimator)
        # the counted windows are those labelled 0 or 1 without a reason
        counted = np.array([r is None for r in pair_trial.reasons(alone)]) & (alone["label"] >= 0)
        np.testing.assert_array_equal(alone["counted"], counted)
    assert "crossover" in estimators


def _daily_loop(day, energy, act, keep, min_windows):
    """:func:`trial.daily` as a loop over the days (how it was first written)."""
    out_days, e, a, w, dropped = [], [], [], [], {}
    for d in np.unique(day[keep]):
        sel = keep & (day == d)
        labels = np.unique(act[sel])
        total = energy[sel].sum(axis=0)
        reason = None
        if sel.sum() < min_windows:
            reason = "too_few_windows"
        elif len(labels) > 1:
            reason = "mixed_activation"
        elif not np.all(total > 0):
            reason = "no_energy"
        if reason:
            dropped[reason] = dropped.get(reason, 0) + 1
            continue
        out_days.append(d)
        e.append(total)
        a.append(labels[0])
        w.append(int(sel.sum()))
    return out_days, e, a, w, dropped


def test_days_of_many_pairs_are_each_pairs_days():
    rng = np.random.default_rng(11)
    n = 48 * 6
    day = np.repeat(np.arange(738000, 738006), 48)
    energy = rng.uniform(1.0, 3.0, (30, n, 2))
    energy[rng.random((30, n)) < 0.02] = 0.0
    act = rng.choice([0, 1, trial_plan.NEITHER], size=(30, n), p=[0.45, 0.45, 0.1])
    act[:, :96] = 0  # whole days of one label
    keep = rng.random((30, n)) < 0.7
    keep[:5, 48:94] = False  # days with two windows
    found = trial.daily_many(day, energy, act, keep, min_windows=4)
    for p, got in enumerate(found):
        days, e, a, w, dropped = _daily_loop(day, energy[p], act[p], keep[p], 4)
        np.testing.assert_array_equal(got.day, days)
        np.testing.assert_allclose(got.energy_kwh, np.reshape(e, (-1, 2)), rtol=1e-12)
        np.testing.assert_array_equal(got.activated, a)
        np.testing.assert_array_equal(got.windows, w)
        assert got.dropped == dropped
    assert any(d.dropped.get("mixed_activation") for d in found)
    assert any(d.dropped.get("too_few_windows") for d in found)
