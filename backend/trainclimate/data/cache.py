"""The generated fleet datasets, built once per machine and reused (predictors, controller).

They live under ``$TRAINCLIMATE_HOME`` (default ``~/.cache/trainclimate``, created when first
needed) in directories named for :data:`DATASET_VERSION`, which changes whenever the generator or
the pipeline would produce different data:

- the *default* dataset (:func:`default_dataset`): both measurement campaigns in full, 384
  coach-days (≈ 2.5 min on 2 cores);
- the *quick* dataset (:func:`quick_dataset`): the first :data:`QUICK_DAYS` days of each campaign,
  every coach (≈ 20 s), from which the service fits the model it starts with on a new machine.

A build happens in a temporary directory renamed into place at the end, under a lock file (a
second process waits for the first), so an interrupted build
leaves nothing half-made. The files the generator corrupts on purpose are counted in one line,
not warned about one by one.
"""

from __future__ import annotations

import fcntl
import logging
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from trainclimate.paths import home, writable_dir

log = logging.getLogger(__name__)

#: Bump when generated data or the pipeline's output would change.
DATASET_VERSION = "fleet-3"
#: Days of each campaign in the quick dataset.
QUICK_DAYS = 4

Progress = Callable[[str, int, int], None]


def default_dataset(progress: Progress | None = None) -> Path:
    """The default dataset, built first if missing.

    Parameters
    ----------
    progress : callable, optional
        ``progress(stage, done, total)``, called while building (stage ``"generate"`` or
        ``"pipeline"``, counts in coach-days).

    Returns
    -------
    pathlib.Path
        Its directory (``trajectories_<S>min.parquet``, ``dataset.json``).
    """
    return _dataset(DATASET_VERSION, None, progress)


def quick_dataset(progress: Progress | None = None) -> Path:
    """The quick dataset (the first :data:`QUICK_DAYS` days of each campaign), built first if
    missing; the arguments and the result as for :func:`default_dataset`."""
    return _dataset(f"{DATASET_VERSION}-quick{QUICK_DAYS}d", QUICK_DAYS, progress)


@contextmanager
def exclusive(target: Path) -> Iterator[None]:
    """Hold ``<target>.lock`` (an advisory ``flock``) while a cached artifact is checked and
    built: a second process wanting it waits for the first instead of building it alongside
    (two builds sharing a directory corrupt it)."""
    with open(target.with_name(target.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _dataset(name: str, max_days: int | None, progress: Progress | None) -> Path:
    target = writable_dir(home(), "trainclimate's home") / name
    if (target / "dataset.json").exists():
        return target
    with exclusive(target):
        if not (target / "dataset.json").exists():  # not built while this one waited
            _build(target, max_days, progress)
    return target


def _build(target: Path, max_days: int | None, progress: Progress | None) -> None:
    from trainclimate.data import dataset, fleetlogs

    name = target.name
    coach_days = sum(
        len(c.days[:max_days] if max_days else c.days) * len(c.coaches)
        for c in fleetlogs.CAMPAIGNS.values()
    )
    log.info("building the %s dataset in %s (%d coach-days, once)", name, target, coach_days)
    tmp = target.with_name(target.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    done = [0]

    def step(stage: str) -> Callable[[int], None]:
        def advance(n: int) -> None:
            done[0] += n
            if progress:
                progress(stage, done[0], coach_days)

        return advance

    step("generate")(0)
    generated = fleetlogs.generate(tmp / "raw", max_days=max_days, progress=step("generate"))
    done[0] = 0
    dataset.build_dataset(
        tmp / "raw", tmp, progress=step("pipeline"), expected_unreadable=generated.corrupted
    )
    shutil.rmtree(tmp / "raw")  # the trajectories are what is reused; raw logs are 0.3 GB
    shutil.rmtree(target, ignore_errors=True)
    tmp.rename(target)
