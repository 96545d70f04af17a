"""Shared data of the controller tests: a Transient Predictor fitted on simulated coaches
(:mod:`support` says how), its variants and a sampler.

(The suite-wide guard in tests/conftest.py keeps every test away from the default dataset.)
"""

from __future__ import annotations

import copy

import pytest

from support import HORIZON, RHO, tick_samples, training_trajectories
from trainclimate.predict import TransientPredictor
from trainclimate.predict.artifact import save_predictor


@pytest.fixture(scope="session")
def trajectories():
    return training_trajectories()


@pytest.fixture(scope="session")
def predictor(trajectories):
    """The Transient Predictor at the controller's setting (5 min, ρ = 12, T = 6)."""
    return TransientPredictor(RHO, HORIZON).fit(trajectories)


@pytest.fixture(scope="session")
def predictor_10min(predictor):
    """The same Ĥ, declared for 10-min samples (incompatible with a 5-min controller)."""
    other = copy.copy(predictor)
    other.sampling_min = 10.0
    return other


@pytest.fixture(scope="session")
def predictor_file(predictor, tmp_path_factory):
    return save_predictor(predictor, tmp_path_factory.mktemp("model") / "transient.npz")


@pytest.fixture(scope="session")
def sampler():
    """:func:`tick_samples` for the tests (conftest modules are not importable by name)."""
    return tick_samples
