"""Shared data of the controller tests: a variant of the small predictor (tests/conftest.py fits
it) and a sampler.

(The suite-wide guard in tests/conftest.py keeps every test away from the default dataset.)
"""

from __future__ import annotations

import copy

import pytest

from helpers.training import tick_samples


@pytest.fixture(scope="session")
def predictor_10min(small_predictor):
    """The same Ĥ, declared for 10-min samples (incompatible with a 5-min controller)."""
    other = copy.copy(small_predictor)
    other.sampling_min = 10.0
    return other


@pytest.fixture(scope="session")
def sampler():
    """:func:`tick_samples` for the tests (conftest modules are not importable by name)."""
    return tick_samples
