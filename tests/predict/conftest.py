"""Shared data of the predictor tests: white-noise trajectories and a small fleet dataset.

(The suite-wide guard in tests/conftest.py keeps every test away from the default dataset.)
"""

from types import SimpleNamespace

import numpy as np
import pytest

from trainclimate.data import fleetlogs
from trainclimate.data.dataset import build_dataset
from trainclimate.predict.base import Z_SCALE

#: 2 days of the first 4 coaches of both campaigns: coach 0 (124A/124B) is often parked, the
#: others in service. Measured: ≈ 11.5 s to generate and build on one core; enough for ρ = T = 6
#: at 5 min (1335 Hankel columns from 30 training trajectories, 11 held-out ones of 66A and 66B).
SMALL_FLEET = {"max_days": 2, "max_coaches": 4}


def white_noise_trajectories(seed, lengths, sampling_min=None):
    """Trajectories of independent Gaussian signals, each of the size of its physical scale."""
    rng = np.random.default_rng(seed)
    out = []
    for n in lengths:
        z = rng.standard_normal((n, 9)) * Z_SCALE + np.array([21, 21, 21, 22, 5, 0, 0, 0, 0])
        traj = SimpleNamespace(y=z[:, :3], u=z[:, 3:4], d=z[:, 4:])
        if sampling_min is not None:
            traj.sampling_min = sampling_min
        out.append(traj)
    return out


@pytest.fixture(scope="session")
def noise_data():
    """``noise_data(seed, lengths, sampling_min=None)`` → white-noise trajectories
    (SimpleNamespace objects with ``y``, ``u``, ``d``)."""
    return white_noise_trajectories


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory):
    """A dataset directory built from the seeded fleet logs of :data:`SMALL_FLEET`."""
    root = tmp_path_factory.mktemp("small_fleet")
    fleetlogs.generate(root / "raw", **SMALL_FLEET)
    build_dataset(root / "raw", root / "data")
    return root / "data"
