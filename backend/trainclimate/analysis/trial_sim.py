"""Trials on a simulated pair of coaches: what a real trial measures, beside the truth.

A real trial (:mod:`trainclimate.analysis.trial`) sees each coach under one condition a day and
has to estimate the saving. Only a simulator can also run each coach under both conditions over
the same days, and so say what the saving was. :func:`simulate_trials` runs, for each seed, a
train's two coaches — each with parameters of its own, drawn ±``coach_spread`` around the
scenario's coach by :func:`~trainclimate.sim.params.diversify`, as ``experiment run
--coach-spread`` draws its deactivated coach — continuously over N service days, a batch of
seeds in one vectorised fleet:

- the pair under each trial plan asked for, the layer on for the day's coach and switched at the
  switch hour (:func:`~trainclimate.analysis.trial_plan.activated`): what a trial measures;
- each coach with the layer always on, and always off: the counterfactual, shared by the plans.

**The days** are :mod:`.trial_environment`'s: the scenario's place, first date and kind of
operation, the seeded generator's weather. The scenario's controller settings and HVAC options
apply (:func:`~trainclimate.analysis.experiment.setup_for`), its one-off field events do not, and
the solver's real-time budget lifted as in every offline simulation
(:data:`~trainclimate.control.ocp.OFFLINE_TIME_LIMIT_S`).

**Counting**, per plan: 30-min windows from the trial's start. A window counts where the
activated coach ran under the layer throughout (regular mode, past the controller's warm-up) and
lies beyond ``lead_in_min`` after a switch of the layer — the trial's start and each service day
whose activated coach differs from the day before's — since right after a switch both coaches
still carry the other condition's thermal state. The simulator's data are always clean. The
windows make service days (:func:`~trainclimate.analysis.trial.daily`), the days the estimate
(:func:`~trainclimate.analysis.trial.estimate`). The truth is 100 (1 − ΣE_on / ΣE_off) of the
counterfactual runs, both coaches together, over the same counted windows of the days the
estimate used; energy is the HVAC meter's (the headline meter of ``experiment run``). The runs
and their summary over seeds are :mod:`.trial_runs`'.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np

from trainclimate.analysis.experiment import setup_for
from trainclimate.analysis.trial import daily, estimate
from trainclimate.analysis.trial_environment import (
    FORECAST_STREAM,
    NOISE_STREAM,
    PARAMS_STREAM,
    SIM_DT_S,
    day_starts,
    trial_environment,
)
from trainclimate.analysis.trial_plan import DEFAULT_SWITCH_HOUR, activated, service_days
from trainclimate.analysis.trial_runs import TrialRun
from trainclimate.coach.meters import HEADLINE_METER
from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.control.closed_loop import ClosedLoop, TickLog, build_controllers
from trainclimate.predict.base import MultistepPredictor
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, diversify
from trainclimate.sim.seeding import seed_of
from trainclimate.sim.simulator import FleetSimulator

#: The plans a simulated trial runs (``reference`` alone measures no saving).
TRIAL_PLANS = ("fixed", "alternate", "randomized")
#: Excluded from counting after each switch of the layer. [min]
LEAD_IN_MIN = 60.0
#: Savings window. [min]
WINDOW_MIN = 30.0
_STEPS_PER_WINDOW = round(WINDOW_MIN * 60.0 / SIM_DT_S)
#: Simulator steps between two progress reports (a simulated hour).
PROGRESS_STEPS = 360


def pair_params(base: CoachParams, coach_spread: float, seed: int) -> list[CoachParams]:
    """The trial's two coaches.

    Parameters
    ----------
    base : CoachParams
        The scenario's coach.
    coach_spread : float
        Each parameter of each coach drawn within ±this around ``base``
        (:func:`~trainclimate.sim.params.diversify`); 0 makes them twins. [–]
    seed : int
        Seed of the draw.

    Returns
    -------
    list of CoachParams
        Coach 0 and coach 1.
    """
    if not coach_spread:
        return [base, base]
    return diversify(base, 2, seed=seed, spread=coach_spread)


@dataclass
class _Trial:
    """One seed's trial as a batch simulates it: its train, its coaches and its plans' days."""

    seed: int
    env: Environment  # one column
    coaches: list[CoachParams]
    day: np.ndarray  # (W,) each window's service day (ordinal)
    acts: list[np.ndarray]  # per plan, (W,) the activated coach of each window
    since_min: np.ndarray  # (W,) from the start of the window's day [min]

    def active(self, n_columns: int) -> np.ndarray:
        """Where the layer is on, (W, columns): each plan's coach 0 and 1, then always."""
        out = np.ones((len(self.day), n_columns), bool)
        for i, act in enumerate(self.acts):
            out[:, 2 * i] = act == 0
            out[:, 2 * i + 1] = act == 1
        return out


def _trial(
    scenario: scenarios.Scenario,
    base: CoachParams,
    seed: int,
    *,
    days: int,
    plans: tuple[str, ...],
    coach_spread: float,
    switch_hour: int,
) -> _Trial:
    """Seed ``seed``'s train, coaches and plans (the arguments as :func:`simulate_trials`')."""
    env = trial_environment(scenario, days, seed, switch_hour)
    w_time = env.time[::_STEPS_PER_WINDOW]
    day = service_days(w_time, switch_hour)
    starts = day_starts(scenario, days, switch_hour)
    return _Trial(
        seed=seed,
        env=env,
        coaches=pair_params(base, coach_spread, seed_of(scenario.seed, seed, PARAMS_STREAM)),
        day=day,
        acts=[np.array([activated(p, d, seed) for d in day]) for p in plans],
        since_min=((w_time - starts[day - day[0]]).total_seconds() / 60.0).to_numpy(),
    )


class _TrialFleet(FleetSimulator):
    """The fleet of a batch of trials, each trial's sensor noise drawn from its own seed, so a
    trial's numbers do not depend on the trials beside it."""

    def __init__(
        self, params: list[CoachParams], env: Environment, *, noise_seeds: list[int], columns: int
    ):
        super().__init__(params, env)
        self.generators = [np.random.default_rng(s) for s in noise_seeds]
        self.columns = columns

    def noise(self) -> np.ndarray:
        """One standard normal draw per deck sensor, each trial's from its own generator, (N, 3)."""
        return np.concatenate([g.normal(size=(self.columns, 3)) for g in self.generators])


def _acting(log: TickLog, n_windows: int, n_columns: int, steps_per_window: int) -> np.ndarray:
    """Ticks per window and column at which the layer decided (past its warm-up), (W, columns)."""
    out = np.zeros((n_windows, n_columns), int)
    for k, c, r in zip(log.step, log.coach, log.results, strict=True):
        if r.reason != "warmup":
            out[k // steps_per_window, c] += 1
    return out


def _lead_in(
    act: np.ndarray, day: np.ndarray, since_day_start_min: np.ndarray, lead_in_min: float
) -> np.ndarray:
    """Windows (W,) within ``lead_in_min`` of a switch: the trial's start and each day whose
    activated coach differs from the day before's (windows in time order)."""
    first = np.searchsorted(day, day)  # each window's day's first window
    switched = (first == 0) | (act != act[np.maximum(first - 1, 0)])
    return switched & (since_day_start_min < lead_in_min)


def simulate_trials(
    name: str,
    predictor: MultistepPredictor,
    seeds: list[int] | range,
    *,
    days: int,
    plans: tuple[str, ...] = ("alternate",),
    coach_spread: float = 0.0,
    forecast: str = "perfect",
    switch_hour: int = DEFAULT_SWITCH_HOUR,
    lead_in_min: float = LEAD_IN_MIN,
    base_params: CoachParams | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[TrialRun]:
    """Simulate trials of ``days`` service days under each plan, with their counterfactual: one
    trial per seed, all in one vectorised fleet (see the module docstring).

    A seed's numbers are the same whatever seeds run beside it. The fleet holds 2 columns per
    plan and 4 for the counterfactual per seed, ≈ 2.5 MB of records per column and simulated
    day; its simulator steps cost about as much for a few seeds as for one.

    Parameters
    ----------
    name : str
        Scenario name (:data:`~trainclimate.sim.scenarios.SCENARIOS`).
    predictor : MultistepPredictor
        The layer's prediction model.
    seeds : list of int or range
        The trials' seeds (weather, operation, coaches, sensor noise, the randomized plan, the
        bootstrap).
    days : int
        Service days N, at least 1.
    plans : tuple of str, default ("alternate",)
        Plans of :data:`TRIAL_PLANS`, simulated side by side against one counterfactual; the
        ``fixed`` plan activates coach 0.
    coach_spread : float, default 0.0
        The coaches' parameter spread (:func:`pair_params`). [–]
    forecast : str, default "perfect"
        The layer's disturbance forecast: ``"perfect"``, ``"persistence"`` or ``"noisy"``.
    switch_hour : int, default 3
        Local hour a service day starts and the plan switches, 0–23. [h]
    lead_in_min : float, default 60.0
        Excluded from counting after each switch. [min]
    base_params : CoachParams, optional
        The coach the pairs are drawn around (default: the scenario's).
    progress : callable, optional
        ``progress(done, total)``: simulator steps done and in all, as it runs.

    Returns
    -------
    list of TrialRun
        Seed by seed, each seed's plans in order.

    Raises
    ------
    ScenarioError
        For an unknown scenario.
    ValueError
        As :func:`check_trial`.
    """
    t_start = time.perf_counter()
    scenario = scenarios.get(name)
    check_trial(days, plans, coach_spread, switch_hour, lead_in_min)
    setup = setup_for(name)
    base = dataclasses.replace(base_params or CoachParams(), **setup.hvac_options)
    kw = {"days": days, "plans": plans, "coach_spread": coach_spread, "switch_hour": switch_hour}
    trials = [_trial(scenario, base, seed, **kw) for seed in seeds]
    n_cols = 2 * len(plans) + 4
    sim, loop = _fleet(scenario, predictor, trials, n_cols, forecast)
    while sim.k < sim.n_steps:
        sim.run(loop, steps=PROGRESS_STEPS)
        if progress:
            progress(sim.k, sim.n_steps)
    energy, under = _windows(sim, loop)
    meta = {
        "scenario": name,
        "coach_spread": coach_spread,
        "forecast": forecast,
        "switch_hour": switch_hour,
        "lead_in_min": lead_in_min,
        "days_simulated": days,
        "wall_s": time.perf_counter() - t_start,
    }
    runs = []
    for i, t in enumerate(trials):
        cols = slice(i * n_cols, (i + 1) * n_cols)
        runs += _plan_runs(t, plans, energy[:, cols], under[:, cols], seed=t.seed, **meta)
    return runs


def _fleet(
    scenario: scenarios.Scenario,
    predictor: MultistepPredictor,
    trials: list[_Trial],
    n_cols: int,
    forecast: str,
) -> tuple[FleetSimulator, ClosedLoop]:
    """The batch's simulator and closed loop: per trial, each plan's coach 0 and 1 under the
    plan, then coach 0 and 1 always on, then always off (``n_cols`` columns)."""
    settings = setup_for(scenario.name).ocp_settings()
    env = Environment.side_by_side([t.env for t in trials for _ in range(n_cols)])
    sim = _TrialFleet(
        [p for t in trials for p in t.coaches * (n_cols // 2)],
        env,
        noise_seeds=[seed_of(scenario.seed, t.seed, NOISE_STREAM) for t in trials],
        columns=n_cols,
    )
    controllers = []
    for _ in trials:  # each trial its own: a controller keeps its coach's state
        controllers += [*build_controllers("ddpc", n_cols - 2, predictor, settings), None, None]
    loop = ClosedLoop(
        sim,
        controllers,
        forecast=([forecast] * (n_cols - 2) + ["perfect"] * 2) * len(trials),
        seed=[
            seed_of(scenario.seed, t.seed, FORECAST_STREAM) + c
            for t in trials
            for c in range(n_cols)
        ],
        active=np.repeat(np.hstack([t.active(n_cols) for t in trials]), _STEPS_PER_WINDOW, axis=0),
    )
    return sim, loop


def _windows(sim: FleetSimulator, loop: ClosedLoop) -> tuple[np.ndarray, np.ndarray]:
    """Per window and column: the energy on the HVAC meter (kWh), and whether the layer acted
    throughout (regular mode, every tick past the warm-up); each (W, columns)."""
    spw = _STEPS_PER_WINDOW
    n_windows = sim.n_steps // spw
    power = sim.result().meter_w(HEADLINE_METER).reshape(n_windows, spw, -1)
    energy = power.sum(axis=1) * SIM_DT_S / 3.6e6  # W·step → kWh
    regular = (sim.env.mode.reshape(n_windows, spw, -1) == MODE_REGULAR).all(axis=1)
    acting = _acting(loop.log, n_windows, sim.env.n_coaches, spw)
    return energy, regular & (acting == spw // loop.steps_per_tick)


def _plan_runs(
    t: _Trial, plans: tuple[str, ...], energy: np.ndarray, under: np.ndarray, **meta
) -> list[TrialRun]:
    """Each plan's estimate and truth from one trial's columns: ``energy`` (W, columns) in kWh,
    ``under`` (W, columns) where the layer acted throughout; ``meta`` the other fields of
    :class:`TrialRun`."""
    on, off = energy[:, -4:-2], energy[:, -2:]
    runs = []
    for i, (plan, act) in enumerate(zip(plans, t.acts, strict=True)):
        cols = [2 * i, 2 * i + 1]
        counted = under[np.arange(len(act)), np.take(cols, act)]
        counted &= ~_lead_in(act, t.day, t.since_min, meta["lead_in_min"])
        trial_days = daily(t.day, energy[:, cols], act, counted)
        kept = counted & np.isin(t.day, trial_days.day)
        runs.append(
            TrialRun(
                plan=plan,
                estimate=estimate(trial_days, seed=t.seed),
                true_savings_pct=_savings(on[kept].sum(), off[kept].sum()),
                true_savings_by_coach_pct=[
                    _savings(on[kept, c].sum(), off[kept, c].sum()) for c in (0, 1)
                ],
                counted_windows=int(kept.sum()),
                **meta,
            )
        )
    return runs


def simulate_trial(name: str, predictor: MultistepPredictor, *, seed: int = 0, **kwargs):
    """One seed's :func:`simulate_trials`.

    Parameters
    ----------
    name : str
        Scenario name.
    predictor : MultistepPredictor
        The layer's prediction model.
    seed : int, default 0
        The trial's seed.
    **kwargs
        The other arguments of :func:`simulate_trials` (``days`` among them).

    Returns
    -------
    list of TrialRun
        One per plan, in order.
    """
    return simulate_trials(name, predictor, [seed], **kwargs)


def _savings(e_on_kwh: float, e_off_kwh: float) -> float | None:
    """100 (1 − E_on / E_off) [%]; None when E_off is not positive."""
    return float(100.0 * (1.0 - e_on_kwh / e_off_kwh)) if e_off_kwh > 0 else None


def check_trial(
    days: int, plans: tuple[str, ...], coach_spread: float, switch_hour: int, lead_in_min: float
) -> None:
    """Raise ValueError for inputs :func:`simulate_trial` cannot run (one line each)."""
    if days < 1:
        raise ValueError("--days must be at least 1")
    for plan in plans or ("",):
        if plan not in TRIAL_PLANS:
            raise ValueError(f"unknown plan {plan!r}: expected one of {', '.join(TRIAL_PLANS)}")
    if not 0.0 <= coach_spread < 1.0:
        raise ValueError("--coach-spread must lie in [0, 1)")
    if not 0 <= switch_hour <= 23:
        raise ValueError("--switch-hour must lie in 0–23")
    if not 0.0 <= lead_in_min < 1440.0:
        raise ValueError("--lead-in-min must lie in [0, 1440)")


def simulate_seeds(
    name: str,
    predictor: MultistepPredictor,
    seeds: range,
    *,
    batch: int = 4,
    workers: int = 1,
    progress: Callable[[float], None] | None = None,
    **kwargs,
) -> list[TrialRun]:
    """:func:`simulate_trials` for many seeds, ``batch`` seeds to a fleet, one fleet after
    another or in worker processes.

    Parameters
    ----------
    name : str
        Scenario name.
    predictor : MultistepPredictor
        The layer's prediction model.
    seeds : range
        The trials' seeds.
    batch : int, default 4
        Seeds simulated in one fleet (its simulator steps cost about as much as one seed's; its
        memory grows with it).
    workers : int, default 1
        Processes running fleets at once (1: this one).
    progress : callable, optional
        ``progress(days)``: simulated trial-days done so far, over all seeds (with workers, as
        each fleet finishes).
    **kwargs
        The other arguments of :func:`simulate_trials` (``days`` among them).

    Returns
    -------
    list of TrialRun
        Seed by seed, each seed's plans in order.
    """
    days = kwargs["days"]
    groups = [seeds[i : i + batch] for i in range(0, len(seeds), batch)]
    if workers == 1:
        runs, before = [], 0
        for group in groups:

            def step(done: int, total: int, before: int = before, n: int = len(group)) -> None:
                if progress:
                    progress(days * (before + n * done / total))

            runs += simulate_trials(name, predictor, group, progress=step, **kwargs)
            before += len(group)
        return runs
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        futures = {pool.submit(simulate_trials, name, predictor, g, **kwargs): g for g in groups}
        done = 0
        for future in as_completed(futures):
            done += len(futures[future])
            if progress:
                progress(days * done)
        return [run for f in futures for run in f.result()]
