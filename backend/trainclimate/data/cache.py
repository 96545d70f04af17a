"""The default fleet dataset, built once per machine and reused (predictors, controller, studies).

It lives under ``$TRAINCLIMATE_HOME`` (default ``~/.cache/trainclimate``) in a directory named
for :data:`DATASET_VERSION`, which changes whenever the generator or the pipeline would produce
different data. The first call generates the raw logs of both campaigns and runs the pipeline
(≈ 2.5 min on 2 cores); later calls return at once. The build happens in a temporary directory
renamed into place at the end, so an interrupted build leaves nothing half-made.
"""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Callable
from pathlib import Path

log = logging.getLogger(__name__)

#: Bump when generated data or the pipeline's output would change.
DATASET_VERSION = "fleet-1"


def home() -> Path:
    """Where trainclimate keeps built data and models: ``$TRAINCLIMATE_HOME`` or
    ``~/.cache/trainclimate``."""
    return Path(os.environ.get("TRAINCLIMATE_HOME", Path.home() / ".cache" / "trainclimate"))


def default_dataset(progress: Callable[[str, int, int], None] | None = None) -> Path:
    """The directory of the default dataset (``trajectories_<S>min.parquet``, ``dataset.json``),
    built first if missing. ``progress(stage, done, total)`` is called while building."""
    from trainclimate.data import fleetlogs, pipeline

    target = home() / DATASET_VERSION
    if (target / "dataset.json").exists():
        return target
    log.warning("building the default fleet dataset in %s (once; about 2.5 minutes)", target)
    tmp = target.with_name(target.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    total = sum(len(c.days) * len(c.coaches) for c in fleetlogs.CAMPAIGNS.values())
    done = [0]

    def step(stage: str) -> Callable[[int], None]:
        def advance(n: int) -> None:
            done[0] += n
            if progress:
                progress(stage, done[0], total)

        return advance

    fleetlogs.generate(tmp / "raw", progress=step("generate"))
    done[0] = 0
    pipeline.build_dataset(tmp / "raw", tmp, progress=step("pipeline"))
    shutil.rmtree(tmp / "raw")  # the trajectories are what is reused; raw logs are 0.3 GB
    shutil.rmtree(target, ignore_errors=True)
    tmp.rename(target)
    return target
