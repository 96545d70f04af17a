"""The DDPC layer (paper, Section III.C): the optimal control problem, T_opt, the state estimate,
the controller step with its fallbacks, forecasts, and the closed loop with the simulator."""

from trainclimate.control.controller import BandEdgeController, DDPCController, StepResult
from trainclimate.control.ocp import DDPCProblem, OCPSettings, ReferenceProblem, Solution

__all__ = [
    "BandEdgeController",
    "DDPCController",
    "DDPCProblem",
    "OCPSettings",
    "ReferenceProblem",
    "Solution",
    "StepResult",
]
