"""Shared data of the paired-experiment tests: short pair runs of the small predictor.

The predictor is tests/conftest.py's ``small_predictor`` (a Transient Predictor at 5 min, ρ = 12,
T = 6, fitted in ≈ 1.5 s on a short simulation of re-seeded scenario days), never the default one.

Each pair run is done once per session (≈ 0.2 s per simulated hour) with the experiment module's
simulator and closed loop wrapped, so a test also sees the tick log and the coaches' parameters
that :class:`~trainclimate.analysis.experiment.PairResult` does not keep.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from trainclimate.analysis import experiment
from trainclimate.analysis.experiment import Event, ExperimentSetup, run_pair
from trainclimate.control.closed_loop import ClosedLoop
from trainclimate.sim.simulator import FleetSimulator


def recorded_pair(name: str, predictor, **kwargs) -> SimpleNamespace:
    """:func:`run_pair` with what it builds on the side: ``pair``; ``loop`` the ClosedLoop (its
    ``log`` has every tick); ``params`` the three coaches' CoachParams."""
    seen = SimpleNamespace(loops=[], params=[])

    class Loop(ClosedLoop):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            seen.loops.append(self)

    class Simulator(FleetSimulator):
        def __init__(self, params, *args, **kw):
            super().__init__(params, *args, **kw)
            seen.params.append(list(params))

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(experiment, "ClosedLoop", Loop)
        mp.setattr(experiment, "FleetSimulator", Simulator)
        pair = run_pair(name, predictor, **kwargs)
    assert len(seen.loops) == 1 and len(seen.params) == 1
    return SimpleNamespace(pair=pair, loop=seen.loops[0], params=seen.params[0])


@pytest.fixture(scope="session")
def heating_3h(small_predictor):
    """parked-heating-nov, 07:00–10:00 local: the layer on at 08:00 (after its 1-h lead-in),
    counted from 08:45, two windows; its override (13:30) lies outside."""
    return recorded_pair("parked-heating-nov", small_predictor, hours=3.0)


@pytest.fixture(scope="session")
def cooling_energy_3h(small_predictor):
    """parked-cooling-aug-energy, 09:00–12:00 local, the energy-favouring weights."""
    return recorded_pair("parked-cooling-aug-energy", small_predictor, hours=3.0)


@pytest.fixture(scope="session")
def heating_override(small_predictor):
    """parked-heating-nov, 07:00–15:00 local, with the scenario's own command override
    (activated coach, 13:30–14:00 local): counted from 08:45, twelve windows."""
    return recorded_pair("parked-heating-nov", small_predictor, hours=8.0)


#: A short run with a connection loss on each coach (local times; the run 07:00–10:30, the layer
#: on at 08:00, counted from 08:45: windows 08:45, 09:15, 09:45, the last incomplete one dropped).
LOSS_SETUP = ExperimentSetup(
    events=(
        Event("connection_loss", "activated", "09:00", 15.0),
        Event("connection_loss", "deactivated", "09:50", 10.0),
    ),
)


@pytest.fixture(scope="session")
def heating_loss(small_predictor):
    return recorded_pair("parked-heating-nov", small_predictor, hours=3.5, setup=LOSS_SETUP)


@pytest.fixture(scope="session")
def record_pair(small_predictor):
    """:func:`recorded_pair` with the session's predictor (conftest is not importable)."""
    return lambda name, **kwargs: recorded_pair(name, small_predictor, **kwargs)
