"""Simulated trials (analysis.trial_sim, ``experiment trial``): the environment over days, the
windows a trial counts, the estimate beside the counterfactual truth, and the command.

The simulated trial (≈ 60 s of one core, the tests that use it marked slow) is six days of
parked-heating-nov with the session's small predictor, the alternate and the fixed plan side by
side against one counterfactual; the command's tests replace the simulation with made-up runs."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from trainclimate.analysis import trial_sim
from trainclimate.analysis.trial import TrialDays, estimate
from trainclimate.analysis.trial_environment import day_starts, trial_environment
from trainclimate.analysis.trial_plan import activated, day_start
from trainclimate.analysis.trial_runs import TrialRun, summarize
from trainclimate.analysis.trial_sim import _lead_in, _TrialFleet, simulate_trial
from trainclimate.cli import experiment as cli_experiment
from trainclimate.cli import main
from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment

DAYS = 6
KEYS = (
    "true_savings_pct",
    "savings_pct",
    "savings_ci95_pct",
    "savings_ci95_reason",
    "naive_savings_pct",
    "estimator",
    "days_to_target",
    "meets_guideline_14",
    "days",
    "plan",
    "scenario",
    "seed",
    "coach_spread",
    "forecast",
    "error_pct",
)


@pytest.fixture(scope="module")
def trial(small_predictor):
    """Six days of alternate and fixed side by side (≈ 60 s of one core)."""
    runs = simulate_trial(
        "parked-heating-nov",
        small_predictor,
        days=DAYS,
        plans=("alternate", "fixed"),
        coach_spread=0.1,
        seed=0,
    )
    return dict(zip(("alternate", "fixed"), runs, strict=True))


def test_the_days_run_from_the_switch_hour_with_their_own_weather():
    scenario = scenarios.get("parked-heating-nov")
    env = trial_environment(scenario, 3, seed=4)
    starts = day_starts(scenario, 3)
    assert env.time[0] == day_start(pd.Timestamp("2024-11-28").date()) == starts[0]
    assert env.time[-1] + pd.Timedelta(seconds=10) == starts[-1]
    assert len(env.time) == 3 * 8640 and env.n_coaches == 1
    assert np.all(env.mode == MODE_REGULAR) and np.all(env.heading_deg == 160.0)
    means = [env.t_amb_c[i * 8640 : (i + 1) * 8640].mean() for i in range(3)]
    assert np.ptp(means) > 0.3  # the generator's day-to-day anomaly, not one repeated day
    other = trial_environment(scenario, 3, seed=5)
    assert not np.allclose(other.t_amb_c, env.t_amb_c)


def test_an_in_service_train_runs_a_timetable_a_day():
    env = trial_environment(scenarios.get("winter-day"), 2, seed=0)
    regular = (env.mode[:, 0] == MODE_REGULAR).reshape(2, 8640)
    assert regular.any(axis=1).all() and not regular.all()  # in service by day, off at night
    assert not np.array_equal(regular[0], regular[1])  # each day its own timetable


def test_a_trials_sensor_noise_does_not_depend_on_the_trials_beside_it():
    env1, params = scenarios.build(scenarios.get("parked-heating-nov"), hours=0.5)
    pair = _TrialFleet(params * 2, Environment.side_by_side([env1] * 2), noise_seeds=[8], columns=2)
    batch = _TrialFleet(
        params * 4, Environment.side_by_side([env1] * 4), noise_seeds=[7, 8], columns=2
    )
    for _ in range(3):
        np.testing.assert_array_equal(batch.noise()[2:], pair.noise())


def test_the_lead_in_follows_each_switch_only():
    day = np.repeat([10, 11, 12], 4)
    since = np.tile([0.0, 30.0, 60.0, 90.0], 3)
    alternate = np.repeat([0, 1, 0], 4)
    fixed = np.zeros(12, int)
    assert _lead_in(alternate, day, since, 60.0).tolist() == [True, True, False, False] * 3
    assert _lead_in(fixed, day, since, 60.0).tolist() == [True, True] + [False] * 10
    assert not _lead_in(alternate, day, since, 0.0).any()


@pytest.mark.slow
def test_the_crossover_covers_the_truth(trial):
    run = trial["alternate"]
    e = run.estimate
    assert e.estimator == "crossover"
    assert e.days == {"coach_0": 3, "coach_1": 3, "reference": 0, "dropped": {}}
    low, high = e.savings_ci95_pct
    assert low <= run.true_savings_pct <= high and run.covered is True
    assert abs(run.error_pct) < 1.0
    assert 2.0 < run.true_savings_pct < 15.0  # the layer saves heating energy
    # the lead-in after the daily switches: 2 of each day's 48 windows
    assert run.counted_windows == DAYS * 46


@pytest.mark.slow
def test_a_fixed_plan_gives_the_naive_figure_without_an_interval(trial):
    run = trial["fixed"]
    e = run.estimate
    assert e.estimator == "fixed_naive"
    assert e.savings_ci95_pct is None and "confounded" in e.ci_reason
    assert e.savings_pct == e.naive_savings_pct
    assert run.error_pct == pytest.approx(e.naive_savings_pct - run.true_savings_pct)
    assert run.covered is None and e.days["coach_1"] == 0
    # one switch only, at the start: the other days count all their windows
    assert run.counted_windows == DAYS * 48 - 2
    # the truth is the same counterfactual's: the same coaches, over nearly the same windows
    assert run.true_savings_pct == pytest.approx(trial["alternate"].true_savings_pct, abs=0.3)


@pytest.mark.slow
def test_the_summary_counts_coverage_and_errors(trial):
    s = summarize(list(trial.values()))
    assert s["alternate"]["runs"] == 1 and s["alternate"]["coverage_pct"] == 100.0
    assert s["alternate"]["mae_pct"] == pytest.approx(abs(trial["alternate"].error_pct))
    assert s["fixed"]["coverage_pct"] is None and s["fixed"]["with_interval"] == 0
    assert s["fixed"]["naive_mae_pct"] == pytest.approx(abs(trial["fixed"].naive_error_pct))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scenario", "nowhere"], "unknown scenario"),
        (["--days", "0"], "--days must be at least 1"),
        (["--coach-spread", "1"], "--coach-spread must lie in [0, 1)"),
        (["--coach-spread", "-0.1"], "--coach-spread must lie in [0, 1)"),
        (["--plan", "weekly"], "unknown plan 'weekly'"),
        (["--plan", "alternate,reference"], "unknown plan 'reference'"),
        (["--seeds", "0"], "--seeds, --batch and --workers must be at least 1"),
        (["--batch", "0"], "--seeds, --batch and --workers must be at least 1"),
        (["--switch-hour", "24"], "--switch-hour must lie in 0–23"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(args, message, capsys):
    base = ["experiment", "trial", "--scenario", "parked-heating-nov", "--json"]
    assert main([*base, *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert message in captured.err and len(captured.err.strip().splitlines()) == 1


def _run(plan: str, seed: int = 0) -> TrialRun:
    """A run as :func:`simulate_trial` gives it, from made-up days (no simulation)."""
    act = np.array([activated(plan, d, seed) for d in range(10, 10 + DAYS)])
    energy = np.c_[np.where(act == 0, 94.0, 100.0), np.where(act == 1, 94.0, 100.0)]
    level = np.linspace(1.0, 1.2, DAYS) * (1 + 0.01 * np.sin(np.arange(DAYS)))
    energy = energy * level[:, None]
    days = TrialDays(np.arange(10, 10 + DAYS), energy, act, np.full(DAYS, 46))
    return TrialRun(
        "parked-heating-nov", plan, seed, 0.1, "perfect", 3, 60.0, DAYS,
        estimate(days, n_resamples=199), 6.0, [6.0, 6.0], DAYS * 46, 1.0,
    )  # fmt: skip


def _cli(monkeypatch, *args):
    """``experiment trial`` with the simulation replaced by :func:`_run` (no predictor)."""
    seen = {}

    def fake(name, predictor, seeds, *, batch, workers, progress, **kwargs):
        seen.update(kwargs, seeds=seeds, batch=batch, workers=workers)
        return [_run(p, s) for s in seeds for p in kwargs["plans"]]

    monkeypatch.setattr(trial_sim, "simulate_seeds", fake)
    monkeypatch.setattr(cli_experiment, "predictor_from", lambda args: None)
    code = main(["experiment", "trial", "--scenario", "parked-heating-nov", *args])
    return code, seen


def test_the_command_prints_one_json_object(monkeypatch, capsys):
    code, seen = _cli(monkeypatch, "--days", "6", "--json")
    assert code == 0
    assert seen["plans"] == ("alternate",) and seen["days"] == 6 and seen["coach_spread"] == 0.1
    assert seen["lead_in_min"] == 60.0 and seen["switch_hour"] == 3
    data = json.loads(capsys.readouterr().out)
    assert set(KEYS) <= set(data)
    assert data["error_pct"] == pytest.approx(data["savings_pct"] - data["true_savings_pct"])
    assert data["plan"] == "alternate" and data["estimator"] == "crossover"
    code, _ = _cli(monkeypatch, "--days", "6")
    text = capsys.readouterr().out
    assert code == 0 and "alternate plan" in text and "truth 6.00 %" in text


def test_several_seeds_and_plans_print_the_summary(monkeypatch, capsys):
    args = ("--plan", "alternate,fixed", "--seeds", "2", "--seed", "5", "--workers", "2")
    code, seen = _cli(monkeypatch, *args, "--json")
    assert code == 0 and seen["seeds"] == range(5, 7) and seen["workers"] == 2
    assert seen["batch"] == 4
    data = json.loads(capsys.readouterr().out)
    assert data["seeds"] == [5, 6] and data["plans"] == ["alternate", "fixed"]
    assert set(data["summary"]) == {"alternate", "fixed"} and len(data["runs"]) == 4
    assert data["summary"]["fixed"]["coverage_pct"] is None
    code, _ = _cli(monkeypatch, *args)
    text = capsys.readouterr().out
    assert "coverage" in text and text.count("\n") == 4  # heading, columns, two plans
