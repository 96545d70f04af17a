"""A scenario simulated under one controller: the simulator, the controllers and the closed loop
put together, as ``trainclimate simulate`` and the reports use them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from trainclimate.control.closed_loop import ClosedLoop, build_controllers, tick_summary
from trainclimate.control.ocp import DEFAULT_OBJECTIVE, OFFLINE_TIME_LIMIT_S, OCPSettings
from trainclimate.predict.base import MultistepPredictor
from trainclimate.sim import scenarios
from trainclimate.sim.params import CoachParams
from trainclimate.sim.simulator import FleetSimulator, SimulationResult
from trainclimate.sim.weather import Weather

#: The controllers a scenario can run under: today's rule-based setpoint, the DDPC layer, and the
#: band-edge reference (the comfort band's cheaper edge with a perfect forecast).
CONTROLLERS = ("rule", "ddpc", "edge")
#: Simulator steps between two progress reports.
PROGRESS_STEPS = 360


@dataclass
class SimulationRun:
    """What :func:`run_simulation` gives back.

    Attributes
    ----------
    scenario : trainclimate.sim.scenarios.Scenario
        The scenario that ran.
    result : trainclimate.sim.simulator.SimulationResult
        The simulated time series of every coach.
    ticks : dict or None
        The controller's tick summary (reasons, solve times; None under ``rule``).
    """

    scenario: scenarios.Scenario
    result: SimulationResult
    ticks: dict | None


def run_simulation(
    scenario: str,
    controller: str = "rule",
    *,
    coaches: int = 1,
    hours: float | None = None,
    weather: Weather | None = None,
    base_params: CoachParams | None = None,
    predictor: MultistepPredictor | None = None,
    forecast: str = "perfect",
    objective: str = DEFAULT_OBJECTIVE,
    record_flows: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> SimulationRun:
    """Simulate ``scenario`` with every coach under ``controller``.

    Parameters
    ----------
    scenario : str
        A scenario name (:data:`trainclimate.sim.scenarios.SCENARIOS`).
    controller : {"rule", "ddpc", "edge"}
        Today's rule-based setpoint, the DDPC layer (needs ``predictor``), or the band-edge
        reference.
    coaches : int
        Number of coaches, each with its own parameters.
    hours : float, optional
        Duration (default: the scenario's, or the weather file's span). [h]
    weather : trainclimate.sim.weather.Weather, optional
        Measured weather in place of the scenario's seeded weather.
    base_params : trainclimate.sim.params.CoachParams, optional
        The coach parameters the fleet's are drawn around (default: the documented ones).
    predictor : MultistepPredictor, optional
        The DDPC layer's prediction model.
    forecast : {"perfect", "persistence", "noisy"}
        The DDPC layer's disturbance forecast (the band edge always has a perfect one).
    objective : {"states", "paper", "margin"}
        The DDPC layer's objective (:data:`~trainclimate.control.ocp.OBJECTIVES`).
    record_flows : bool
        Keep every heat flow of the thermal model in the result.
    progress : callable, optional
        ``progress(done, total)``: simulator steps done so far and in all, called as it runs.

    Returns
    -------
    SimulationRun

    Raises
    ------
    trainclimate.sim.scenarios.ScenarioError
        For an unknown scenario.
    ValueError
        For an unknown controller, or ``ddpc`` without a predictor.
    """
    if controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {controller!r} (known: {', '.join(CONTROLLERS)})")
    spec = scenarios.get(scenario)
    env, params = scenarios.build(
        spec, n_coaches=coaches, hours=hours, weather=weather, base_params=base_params
    )
    settings = OCPSettings(objective=objective, time_limit_s=OFFLINE_TIME_LIMIT_S)
    controllers = build_controllers(controller, env.n_coaches, predictor, settings)
    sim = FleetSimulator(params, env, seed=spec.seed, record_flows=record_flows)
    loop = ClosedLoop(
        sim, controllers, forecast="perfect" if controller == "edge" else forecast, seed=spec.seed
    )
    while sim.k < sim.n_steps:
        sim.run(loop, steps=PROGRESS_STEPS)
        if progress:
            progress(sim.k, sim.n_steps)
    ticks = tick_summary(loop.log) if controller != "rule" else None
    return SimulationRun(spec, sim.result(), ticks)
