"""Paired experiments like the paper's Section V: one train, two coaches, the layer on in one.

Both coaches of a pair stand (or run) in the same train: they share place, weather, operation and
occupancy exactly. Coach A has the DDPC layer activated, coach B follows T_rule (deactivated). A
third column simulates the band-edge reference (the ``edge`` controller) in coach A's place, so
every result also says what share of the achievable saving the layer got. The three are one
vectorised simulation (:class:`~trainclimate.sim.simulator.FleetSimulator`).

Each scenario has an :class:`ExperimentSetup` (:data:`EXPERIMENTS`): controller settings that
differ from the defaults (the conservative bound of Experiment 2, the energy-favouring weights of
Experiment 3), the field events of the paper's experiments — the connection lost to a coach, the
commands overwritten by a communication error — when the layer is switched on, and how long after
that the activated coach is taken to be in steady state (savings are counted from then, as the
paper counted from 14:00 after activating at 13:15). The comparison itself is
:func:`trainclimate.analysis.savings.compare`, the function the service's API calls.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from trainclimate.analysis.savings import CoachSeries, Comparison, compare
from trainclimate.control import OCPSettings
from trainclimate.control.closed_loop import ClosedLoop, build_controllers, tick_summary
from trainclimate.predict.base import MultistepPredictor
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, diversify
from trainclimate.sim.rule import MODE_REGULAR
from trainclimate.sim.simulator import FleetSimulator, SimulationResult

#: The columns of a pair simulation.
ACTIVATED, DEACTIVATED, EDGE = 0, 1, 2
EVENT_KINDS = ("connection_loss", "command_override")


@dataclass(frozen=True)
class Event:
    """A field event of a paired experiment, like those of the paper's Section V.

    Attributes
    ----------
    kind : str
        ``"connection_loss"`` or ``"command_override"`` (:data:`EVENT_KINDS`).
    coach : str
        ``"activated"`` or ``"deactivated"``.
    start : str
        Local clock time, ``"HH:MM"`` (``"+1"`` for the next day).
    minutes : float or None
        Duration (None: to the end of the run). [min]

    Raises
    ------
    ValueError
        For an unknown kind or coach.
    """

    kind: str
    coach: str
    start: str
    minutes: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise ValueError(f"unknown event kind {self.kind!r} (known: {', '.join(EVENT_KINDS)})")
        if self.coach not in ("activated", "deactivated"):
            raise ValueError("an event's coach is 'activated' or 'deactivated'")


@dataclass(frozen=True)
class ExperimentSetup:
    """How a scenario is run as a paired experiment (see the module docstring).

    Attributes
    ----------
    settings : dict
        :class:`~trainclimate.control.ocp.OCPSettings` fields that differ from the defaults.
    events : tuple of Event
        The field events.
    activate_at : str or None
        Local clock time the layer is switched on (None: as soon as its lead-in is complete).
    steady_after_min : float
        Delay from activation to the start of the counted period. [min]
    note : str
        What the setup reproduces.
    """

    settings: dict = field(default_factory=dict)
    events: tuple[Event, ...] = ()
    activate_at: str | None = None
    steady_after_min: float = 45.0
    note: str = ""

    def ocp_settings(self) -> OCPSettings:
        """The controller's settings.

        Returns
        -------
        OCPSettings
            The defaults with :attr:`settings` applied.
        """
        return dataclasses.replace(OCPSettings(), **self.settings)


EXPERIMENTS: dict[str, ExperimentSetup] = {
    "winter-day": ExperimentSetup(
        activate_at="05:15",
        steady_after_min=0.0,
        note="Section IV.B: activated at 05:15 after its 1-hour lead-in; savings over the day "
        "from activation",
    ),
    "parked-cooling-oct": ExperimentSetup(
        activate_at="13:15",
        events=(Event("connection_loss", "activated", "17:50"),),
        note="Experiment 1: activated at 13:15, counted from 14:00; the connection to the "
        "activated coach lost at 17:50",
    ),
    "parked-cooling-aug-conservative": ExperimentSetup(
        settings={"t_max": 0.6},
        note="Experiment 2: a tighter bound inside the controller (±0.6 K) than the ±1 K shown",
    ),
    "parked-cooling-aug-energy": ExperimentSetup(
        settings={"sigma": 10.0, "tau": 1.0, "gamma": 0.1},
        note="Experiment 3: weights favouring energy (σ = 10, τ = 1, γ = 0.1)",
    ),
    "parked-heating-nov": ExperimentSetup(
        events=(Event("command_override", "activated", "13:30", 30.0),),
        note="Experiment 4: the activated coach's commands overwritten for 30 min from 13:30",
    ),
}


def setup_for(name: str) -> ExperimentSetup:
    """The experiment setup of a scenario.

    Parameters
    ----------
    name : str
        Scenario name, a key of :data:`~trainclimate.sim.scenarios.SCENARIOS`.

    Returns
    -------
    ExperimentSetup
        From :data:`EXPERIMENTS`, or the default setup for a scenario without its own.
    """
    return EXPERIMENTS.get(name, ExperimentSetup())


@dataclass
class PairResult:
    """A paired experiment: the three-column simulation, its comparisons and the ticks.

    Attributes
    ----------
    scenario : Scenario
        The scenario run.
    setup : ExperimentSetup
        How it was run.
    result : SimulationResult
        Columns :data:`ACTIVATED`, :data:`DEACTIVATED` and :data:`EDGE`.
    comparison, edge_comparison : Comparison
        Activated and band-edge coach each against the deactivated one.
    activated_at : pandas.Timestamp or None
        When the layer first acted (UTC).
    counted_from : pandas.Timestamp
        Start of the counted period (UTC).
    ticks : dict
        :func:`~trainclimate.control.closed_loop.tick_summary` of the activated coach.
    affected : numpy.ndarray of bool, shape (steps, 3)
        Samples hit by a field event.
    controller_time_ratio : float
        Mean controller step time over the controller's period. [–]
    wall_s : float
        Wall-clock time of the run. [s]
    """

    scenario: scenarios.Scenario
    setup: ExperimentSetup
    result: SimulationResult
    comparison: Comparison
    edge_comparison: Comparison
    activated_at: pd.Timestamp | None
    counted_from: pd.Timestamp
    ticks: dict
    affected: np.ndarray  # (steps, 3)
    controller_time_ratio: float
    wall_s: float

    def to_dict(self) -> dict:
        """The JSON of ``trainclimate experiment run``, and the KPIs beside it.

        Returns
        -------
        dict
            JSON-ready: savings (%), violations (K), energies (kWh), discomfort (K·h per deck),
            minutes, hours, timestamps (ISO 8601), the band-edge reference's savings and the
            layer's share of them (%, None when the reference saves nothing), the controller
            settings and ticks.
        """
        c, e = self.comparison, self.edge_comparison
        # a share of a saving: meaningless when the reference itself saves nothing
        share = (
            100.0 * c.savings_pct / e.savings_pct
            if c.savings_pct is not None and e.savings_pct is not None and e.savings_pct > 0
            else None
        )
        return {
            "scenario": self.scenario.name,
            "savings_pct": c.savings_pct,
            "avg_hourly_violation_k": c.avg_hourly_violation_k,
            "baseline_violation_k": c.baseline_violation_k,
            "savings_30min_pct": c.savings_30min_pct,
            "excluded_minutes": c.excluded_minutes,
            "edge_savings_pct": e.savings_pct,
            "share_of_edge_pct": share,
            "edge_violation_k": e.avg_hourly_violation_k,
            "energy_activated_kwh": c.energy_activated_total_kwh,
            "energy_deactivated_kwh": c.energy_deactivated_total_kwh,
            "discomfort_kh": c.discomfort_kh,
            "baseline_discomfort_kh": c.baseline_discomfort_kh,
            "computational_time_ratio": self.controller_time_ratio,
            "affected_minutes": c.affected_minutes,
            "counted_hours": c.counted_hours,
            "counted_from": self.counted_from.isoformat(),
            "activated_at": None if self.activated_at is None else self.activated_at.isoformat(),
            "window_start": [t.isoformat() for t in c.window_start],
            "excluded_windows": c.excluded.tolist(),
            "controller_settings": dataclasses.asdict(self.setup.ocp_settings()),
            "controller_ticks": self.ticks,
            "note": self.setup.note,
            "wall_seconds": self.wall_s,
        }


def _event_masks(setup: ExperimentSetup, env: Environment) -> tuple[np.ndarray, np.ndarray]:
    """(disconnected, overridden), each (steps, 3), from the setup's events."""
    shape = (len(env.time), 3)
    masks = {kind: np.zeros(shape, bool) for kind in EVENT_KINDS}
    for ev in setup.events:
        a = scenarios.local_clock(env.time[0], ev.start)
        if ev.minutes is None:
            b = env.time[-1] + pd.Timedelta(seconds=env.dt_s)
        else:
            b = a + pd.Timedelta(minutes=ev.minutes)
        rows = (env.time >= a) & (env.time < b)
        cols = [ACTIVATED, EDGE] if ev.coach == "activated" else [DEACTIVATED]
        for c in cols:
            masks[ev.kind][rows, c] = True
    return masks["connection_loss"], masks["command_override"]


def _series(result: SimulationResult, coach: int, affected: np.ndarray, lost: np.ndarray):
    power = result.total_power_w[:, coach] / 1e3
    power = np.where(lost[: len(power), coach], np.nan, power)  # no logger data while cut off
    return CoachSeries(
        time=result.time,
        power_kw=power,
        t_room_c=result.t_room_c[:, coach],
        t_rule_c=result.t_rule_c[:, coach],
        affected=affected[: len(power), coach],
        in_band=result.env.mode[: len(power), coach] == MODE_REGULAR,
    )


def run_pair(
    name: str,
    predictor: MultistepPredictor,
    *,
    hours: float | None = None,
    forecast: str = "perfect",
    coach_spread: float = 0.0,
    setup: ExperimentSetup | None = None,
    window_min: float = 30.0,
    base_params: CoachParams | None = None,
) -> PairResult:
    """Run a scenario as a paired experiment (see the module docstring).

    Parameters
    ----------
    name : str
        Scenario name (:data:`~trainclimate.sim.scenarios.SCENARIOS`).
    predictor : MultistepPredictor
        The DDPC layer's prediction model.
    hours : float, optional
        Duration (default: the scenario's). [h]
    forecast : str, default "perfect"
        The activated coach's forecast: ``"perfect"``, ``"persistence"`` or ``"noisy"``.
    coach_spread : float, default 0.0
        > 0 gives the deactivated coach parameters of its own (seeded ±spread around the
        activated coach's, as two real coaches differ); 0 makes them twins, so the comparison
        measures the controller alone. [–]
    setup : ExperimentSetup, optional
        Overrides the scenario's (:func:`setup_for`).
    window_min : float, default 30.0
        Savings window. [min]
    base_params : CoachParams, optional
        The coaches' parameters (e.g. a calibrated twin's); default the scenario's.

    Returns
    -------
    PairResult

    Raises
    ------
    ScenarioError
        For an unknown scenario or invalid duration.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section V.
    """
    t_start = time.perf_counter()
    scenario = scenarios.get(name)
    setup = setup or setup_for(name)
    env1, params = scenarios.build(scenario, n_coaches=1, hours=hours)
    env = Environment.side_by_side([env1] * 3)
    base = params[0] if base_params is None else base_params
    other = diversify(base, 1, seed=scenario.seed, spread=coach_spread)[0] if coach_spread else base
    sim = FleetSimulator([base, other, base], env, seed=scenario.seed)
    settings = setup.ocp_settings()
    ddpc = build_controllers("ddpc", 1, predictor, settings)[0]
    edge = build_controllers("edge", 1, predictor, settings)[0]
    disconnected, overridden = _event_masks(setup, env)
    active_from = np.zeros(3, int)
    activated_at = None
    if setup.activate_at is not None:
        activated_at = scenarios.local_clock(env.time[0], setup.activate_at)
        active_from[:] = int(np.searchsorted(env.time, activated_at))
    loop = ClosedLoop(
        sim,
        [ddpc, None, edge],
        forecast=[forecast, "perfect", "perfect"],  # the reference knows the true future
        seed=scenario.seed,
        disconnected=disconnected,
        overridden=overridden,
        active_from=active_from,
    )
    sim.run(loop)
    result = sim.result()
    log = loop.log.of_coach(ACTIVATED)
    if activated_at is None:
        first = next(
            (k for k, r in zip(log.step, log.results, strict=True) if r.source == "ddpc"), None
        )
        activated_at = None if first is None else env.time[first]
    counted_from = (activated_at or env.time[0]) + pd.Timedelta(minutes=setup.steady_after_min)
    affected = disconnected | overridden
    series = [_series(result, c, affected, disconnected) for c in range(3)]
    kw = {"start": counted_from, "window_min": window_min}
    comparison = compare(series[ACTIVATED], series[DEACTIVATED], **kw)
    edge_comparison = compare(series[EDGE], series[DEACTIVATED], **kw)
    steps = [r.step_time_s for r in log.results]
    return PairResult(
        scenario=scenario,
        setup=setup,
        result=result,
        comparison=comparison,
        edge_comparison=edge_comparison,
        activated_at=activated_at,
        counted_from=counted_from,
        ticks=tick_summary(log),
        affected=affected,
        controller_time_ratio=float(np.mean(steps) / loop.tick_s) if steps else 0.0,
        wall_s=time.perf_counter() - t_start,
    )
