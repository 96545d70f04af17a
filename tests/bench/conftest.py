"""Shared data of the benchmark tests: the raw logs ``bench pipeline`` generates at ``days=2``
(2 days of the first coach of both campaigns: 4 coach-days simulated once per session, ≈ 20 s,
≈ 40 s on a busy 2-core machine) and the fleet dataset built from them, which stands in for the
default dataset of ``bench predictor`` and ``bench controller``.

(The suite-wide guard in tests/conftest.py keeps every test away from the default dataset.)
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from trainclimate.data import fleetlogs
from trainclimate.data.dataset import build_dataset

#: The days of ``bench pipeline``'s generation here (at 1 day the first coaches are never long
#: enough in regular mode: the pipeline finds no trajectory).
DAYS = 2


@pytest.fixture(scope="session")
def raw_logs(tmp_path_factory) -> Path:
    """The raw logs ``fleetlogs.generate(..., max_days=DAYS, max_coaches=1)`` writes."""
    raw = tmp_path_factory.mktemp("bench") / "raw"
    fleetlogs.generate(raw, max_days=DAYS, max_coaches=1)
    return raw


@pytest.fixture
def pregenerated(raw_logs, monkeypatch) -> int:
    """``fleetlogs.generate`` replaced by hard links to :func:`raw_logs` (the same files, without
    simulating them again), which accepts ``bench pipeline``'s arguments at ``days=DAYS`` only;
    returns ``DAYS``."""

    def link(out, *, max_days=None, max_coaches=None, **kwargs):
        assert (max_days, max_coaches, kwargs) == (DAYS, 1, {})
        for path in raw_logs.rglob("*"):
            if path.is_file():
                target = Path(out) / path.relative_to(raw_logs)
                target.parent.mkdir(parents=True, exist_ok=True)
                os.link(path, target)

    monkeypatch.setattr(fleetlogs, "generate", link)
    return DAYS


@pytest.fixture(scope="session")
def dataset(raw_logs, tmp_path_factory) -> Path:
    """The fleet dataset of :func:`raw_logs` (6 trajectories at 1 min, ≈ 1 800 points)."""
    out = tmp_path_factory.mktemp("bench") / "dataset"
    build_dataset(raw_logs, out)
    return out
