"""Running a fleet study's chunks on Dask distributed, resumably.

The chunks (:meth:`~trainclimate.study.plan.StudySpec.chunks`) are submitted as tasks to a Dask
scheduler: a :class:`distributed.LocalCluster` of worker processes on this machine by default, or
any running scheduler by its address (``tcp://HOST:PORT``: ``dask scheduler`` and ``dask worker``
started by hand, dask-jobqueue, Kubernetes). The weather and the prediction model are scattered to
the workers once. Dask retries a failing task (``retries``); a chunk that still fails is reported
with its coaches and days, and the study gives no totals.

``--out`` holds one study: ``study.json`` (what was asked, and its fingerprint) and
``chunks/<key>.parquet``, each written by the client as its chunk completes (to a temporary name,
then renamed, so a file is either whole or absent). Running the same study on the same ``--out``
submits only the chunks without a file; a killed run loses only the chunks in flight. Another
study there — any input different, the forecast too — is refused, so chunks never mix.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pandas as pd

from trainclimate.predict.base import MultistepPredictor
from trainclimate.sim.weather import Weather
from trainclimate.study.chunk import run_chunk
from trainclimate.study.plan import Chunk, StudyError, StudySpec

#: How long to wait for a scheduler given by address. [s]
CONNECT_TIMEOUT_S = 10.0
#: How many times Dask retries a failing chunk before it is reported.
RETRIES = 2


class ChunkError(StudyError):
    """Chunks failed after Dask's retries; their results are not in the totals."""


@dataclass
class StudyRun:
    """What :func:`run_study` did.

    Attributes
    ----------
    chunks : int
        Chunks in the study.
    chunks_skipped : int
        Chunks already in ``--out`` (not recomputed).
    chunks_run : int
        Chunks computed by this run.
    coach_days_run : int
        Their coach-days.
    seconds : float
        Wall time of the computed chunks. [s]
    workers : int
        Workers of the cluster (0 when nothing was computed).
    timings : dict
        Summed over the computed chunks: seconds per controller's runs, of which the DDPC
        controller's own steps, the DDPC ticks by reason, and each chunk's worker peak resident
        memory and its resident memory after the chunk (MB), in the order they completed.
    """

    chunks: int
    chunks_skipped: int
    chunks_run: int = 0
    coach_days_run: int = 0
    seconds: float = 0.0
    workers: int = 0
    timings: dict = field(default_factory=dict)


def chunk_dir(out: Path) -> Path:
    """Where a study's chunk files are."""
    return out / "chunks"


def _differences(theirs: dict, mine: dict) -> list[str]:
    """The fields two studies' specs differ in: ``name: theirs there, mine here`` for a short
    value, the name alone for the others (the coaches' parameters)."""
    out = []
    for name, value in mine.items():
        other = theirs.get(name)
        if other == value:
            continue
        short = all(isinstance(v, str | int | float | bool) for v in (other, value))
        out.append(f"{name}: {other} there, {value} here" if short else f"{name} differ")
    return out


def _claim_out(spec: StudySpec, out: Path) -> None:
    """Record the study in ``out/study.json``, or refuse an ``out`` that holds another one (any
    field of the spec different: the forecast, the seed, the coaches …), naming what differs."""
    path = out / "study.json"
    mine = {"fingerprint": spec.fingerprint(), "spec": asdict(spec)}
    if path.exists():
        try:
            theirs = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise StudyError(f"--out: {path} is unreadable ({exc}); use another --out") from None
        if theirs.get("fingerprint") != mine["fingerprint"]:
            plain = json.loads(json.dumps(mine["spec"], default=str))
            diff = _differences(theirs.get("spec") or {}, plain) or [
                f"{theirs.get('fingerprint')}, this one is {mine['fingerprint']}"
            ]
            raise StudyError(
                f"--out {out} holds a different study ({'; '.join(diff)}); "
                "use another --out to keep both"
            )
        return
    chunk_dir(out).mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(mine, indent=1, default=str) + "\n")
    os.replace(tmp, path)


def _write_chunk(out: Path, chunk: Chunk, frame: pd.DataFrame) -> None:
    path = chunk_dir(out) / f"{chunk.key}.parquet"
    tmp = path.with_name(path.name + ".tmp")
    frame.to_parquet(tmp)
    os.replace(tmp, path)


def done_chunks(spec: StudySpec, out: Path) -> set[str]:
    """The keys of the study's chunks that have a file in ``out``."""
    have = {p.stem for p in chunk_dir(out).glob("*.parquet")}
    return {c.key for c in spec.chunks() if c.key in have}


def read_chunks(spec: StudySpec, out: Path) -> pd.DataFrame:
    """Every chunk's rows, in the study's order (coach, day, situation).

    Raises
    ------
    StudyError
        If a chunk's file is missing.
    """
    frames = []
    for chunk in spec.chunks():
        path = chunk_dir(out) / f"{chunk.key}.parquet"
        if not path.exists():
            raise StudyError(f"chunk {chunk.key} has no result in {out}")
        frames.append(pd.read_parquet(path))
    frame = pd.concat(frames, ignore_index=True)
    return frame.sort_values(["coach_index", "day", "situation"], kind="stable", ignore_index=True)


def check_scheduler(scheduler: str) -> None:
    """Raise :class:`StudyError` unless ``scheduler`` is ``local`` or a Dask address."""
    if scheduler != "local" and not scheduler.startswith(("tcp://", "tls://", "ws://", "wss://")):
        raise StudyError(f"--scheduler {scheduler!r}: 'local' or an address like tcp://HOST:8786")


def _client(scheduler: str, workers: int | None):
    """A Dask client: a LocalCluster of ``workers`` processes (one thread each), or the running
    scheduler at ``scheduler``."""
    from distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler == "local":
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            silence_logs=logging.WARNING,
        )
        client = Client(cluster)
        client.run(_stdout_to_stderr)
        return client, cluster
    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s"), None
    except (OSError, TimeoutError) as exc:
        raise StudyError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None


def _stdout_to_stderr() -> None:
    """Point a local worker's standard output (the file descriptor, so C libraries' too) at its
    standard error: OSQP now and then prints a line from C, which must not mix with the
    command's JSON on the terminal both share."""
    sys.stdout.flush()
    os.dup2(2, 1)


def _describe(spec: StudySpec, chunk: Chunk) -> str:
    first, last = spec.coach_ids[chunk.coach_lo], spec.coach_ids[chunk.coach_hi - 1]
    days = spec.dates[chunk.day_lo : chunk.day_hi]
    return f"coaches {first}…{last}, days {days[0]}…{days[-1]}"


def run_study(
    spec: StudySpec,
    out: Path,
    *,
    weather: Weather,
    predictor: MultistepPredictor | None,
    scheduler: str = "local",
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> StudyRun:
    """Compute the study's missing chunks on Dask and write each to ``out`` as it completes.

    Parameters
    ----------
    spec : StudySpec
        The study.
    out : pathlib.Path
        Its directory (see the module docstring).
    weather : Weather
        The study's weather.
    predictor : MultistepPredictor or None
        The DDPC layer's model.
    scheduler : str, default "local"
        ``"local"`` (a LocalCluster) or a scheduler's address.
    workers : int, optional
        The LocalCluster's worker processes (default: the CPUs); ignored with an address.
    progress : callable, optional
        ``progress(chunks, coach_days)`` after each completed chunk: how many it added.

    Returns
    -------
    StudyRun

    Raises
    ------
    StudyError
        If ``out`` holds another study or the scheduler cannot be reached.
    ChunkError
        If chunks still failed after Dask's retries (the others are kept in ``out``).
    """
    from distributed import as_completed

    check_scheduler(scheduler)
    _claim_out(spec, out)
    chunks = spec.chunks()
    have = done_chunks(spec, out)
    todo = [c for c in chunks if c.key not in have]
    run = StudyRun(chunks=len(chunks), chunks_skipped=len(chunks) - len(todo))
    if not todo:
        return run
    client, cluster = _client(scheduler, workers)
    try:
        run.workers = len(client.scheduler_info(n_workers=-1)["workers"])
        weather_f, predictor_f = client.scatter([weather, predictor], broadcast=True)
        t0 = time.perf_counter()
        futures = {
            client.submit(
                run_chunk,
                spec,
                chunk,
                weather_f,
                predictor_f,
                key=f"study-{spec.fingerprint()}-{chunk.key}",
                retries=RETRIES,
                pure=False,
            ): chunk
            for chunk in todo
        }
        failed = []
        timings: dict = {
            "seconds": {},
            "ddpc_controller_s": 0.0,
            "ddpc_ticks": {},
            "worker_peak_rss_mb": [],
            "worker_rss_mb": [],
        }
        for future in as_completed(futures):
            chunk = futures[future]
            if future.status != "finished":
                failed.append((chunk, future.exception()))
                continue
            frame = future.result()
            _write_chunk(out, chunk, frame)
            _add_timings(timings, frame.attrs)
            run.chunks_run += 1
            run.coach_days_run += chunk.coach_days
            future.release()
            if progress:
                progress(1, chunk.coach_days)
        run.seconds = time.perf_counter() - t0
        run.timings = timings
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    if failed:
        chunk, exc = failed[0]
        raise ChunkError(
            f"{len(failed)} chunk(s) failed after {RETRIES} retries, first "
            f"{_describe(spec, chunk)}: {type(exc).__name__}: {exc}; the "
            f"{run.chunks_skipped + run.chunks_run} finished are kept, run again to retry the rest"
        )
    return run


def _add_timings(total: dict, attrs: dict) -> None:
    for kind, s in attrs.get("seconds", {}).items():
        total["seconds"][kind] = total["seconds"].get(kind, 0.0) + s
    total["ddpc_controller_s"] += attrs.get("ddpc_controller_s", 0.0)
    for reason, n in attrs.get("ddpc_ticks", {}).items():
        total["ddpc_ticks"][reason] = total["ddpc_ticks"].get(reason, 0) + n
    total["worker_peak_rss_mb"].append(attrs.get("worker_peak_rss_mb"))
    total["worker_rss_mb"].append(attrs.get("worker_rss_mb"))
