"""Benchmarks (``trainclimate bench …``): speed figures measured against a baseline in one run."""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from trainclimate.sim import scenarios
from trainclimate.sim.simulator import FleetSimulator


def machine() -> dict:
    """What the figures were measured on."""
    return {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def bench_simulator(coaches: int = 100, days: float = 1.0, loop_coaches: int = 5) -> dict:
    """Simulated coach-days per second for a vectorised fleet, against a per-coach loop.

    The fleet runs ``coaches`` half coaches of the ``winter-day`` scenario (in service, all
    blocks active) for ``days`` at the simulator's own 10 s step; the baseline simulates
    ``loop_coaches`` of the same coaches one at a time (one simulator per coach, the plain
    Python loop over coaches) and is scaled per coach-day. Environment construction (weather,
    routes) is not timed.
    """
    scenario = scenarios.get("winter-day")
    env, params = scenarios.build(scenario, n_coaches=coaches, hours=24.0 * days)
    t0 = time.perf_counter()
    sim = FleetSimulator(params, env)
    sim.run()
    fleet_s = time.perf_counter() - t0

    n_loop = min(loop_coaches, coaches)
    t0 = time.perf_counter()
    for i in range(n_loop):
        single = FleetSimulator([params[i]], env.coaches([i]))
        single.run()
    loop_s = time.perf_counter() - t0

    fleet_rate = coaches * days / fleet_s
    loop_rate = n_loop * days / loop_s
    return {
        "coach_days_per_s": fleet_rate,
        "coaches": coaches,
        "days": days,
        "dt_s": env.dt_s,
        "steps": len(env.time),
        "fleet_seconds": fleet_s,
        "loop_coach_days_per_s": loop_rate,
        "loop_coaches": n_loop,
        "speedup_vs_loop": fleet_rate / loop_rate,
        "machine": machine(),
    }


def _replicate(src: Path, dst: Path, copies: int, campaign: str = "") -> int:
    """Link every raw file of ``src`` (of ``campaign``, if given) ``copies`` times under ``dst``
    with new coach names, so the pipeline sees ``copies`` × as many coach-days (they are
    processed independently)."""
    from trainclimate.data.formats import parse_log_name

    n = 0
    for path in sorted(src.rglob(f"{campaign}*/*/*.csv")):
        train, coach, day = parse_log_name(path)
        rel = path.parent.relative_to(src)
        for c in range(copies):
            target = dst / rel / f"{train}_{coach}x{c}_{day}.csv"
            target.parent.mkdir(parents=True, exist_ok=True)
            os.link(path, target)
            n += 1
    return n


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_pipeline(raw: str, out: str) -> dict:
    """(In a child process) the pipeline on ``raw``: time, rows, peak memory."""
    from trainclimate.data.pipeline import build_dataset

    t0 = time.perf_counter()
    summary = build_dataset(raw, out)
    return {
        "seconds": time.perf_counter() - t0,
        "raw_rows": summary.raw_rows,
        "coach_days": summary.coach_days,
        "peak_rss_mb": _peak_rss_mb(),
    }


def run_parse_only(raw: str) -> dict:
    """(In a child process) the baseline: only parse every CSV file under ``raw`` with pandas."""
    import pandas as pd

    t0 = time.perf_counter()
    rows = 0
    for path in sorted(Path(raw).rglob("*.csv")):
        sep = ";" if b";" in path.read_bytes()[:200] else ","
        try:
            rows += len(pd.read_csv(path, sep=sep, dtype=str, on_bad_lines="skip"))
        except (ValueError, UnicodeDecodeError):
            continue  # the unreadable files the pipeline also skips
    return {"seconds": time.perf_counter() - t0, "rows": rows}


def run_fit(path: str, mode: str, scale: str, rho: str, horizon: str) -> dict:
    """(In a child process) a Transient Predictor fit on the trajectories of ``path`` repeated
    ``scale`` times (``streaming``), or the baseline ``one_shot``: the whole transposed Hankel
    matrix materialised and factored in one QR."""
    import itertools

    import scipy.linalg as sla

    from trainclimate.data.trajectory import read_trajectories
    from trainclimate.predict import TransientPredictor
    from trainclimate.predict.base import Z_SCALE
    from trainclimate.predict.hankel import column_chunks

    scale, rho, horizon = int(scale), int(rho), int(horizon)
    trajs = read_trajectories(path)
    before = _peak_rss_mb()
    t0 = time.perf_counter()
    if mode == "streaming":
        repeated = itertools.chain.from_iterable(itertools.repeat(trajs, scale))
        columns = TransientPredictor(rho, horizon).fit(repeated).n_columns
    else:
        zt = np.concatenate(list(column_chunks(trajs, rho + horizon)))
        zt /= np.tile(Z_SCALE, rho + horizon)
        columns = len(zt)
        sla.qr(zt, mode="r", overwrite_a=True)
    return {
        "mode": mode,
        "scale": scale,
        "columns": columns,
        "seconds": time.perf_counter() - t0,
        "peak_rss_mb": _peak_rss_mb(),
        "rss_before_fit_mb": before,
    }


def _child(name: str, *args: str) -> dict:
    """Run ``name(*args)`` of this module in a fresh Python process; its JSON result."""
    out = subprocess.run(
        [sys.executable, "-m", "trainclimate.bench", name, *args],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_pipeline(days: int = 4, copies: tuple[int, int] = (2, 20)) -> dict:
    """Pipeline throughput (raw rows/s) and peak memory at two dataset sizes.

    Generates ``days`` days of one winter (1-min HVAC) and one summer (2-s HVAC) coach, then
    links those files under new coach names ``copies[0]`` and ``copies[1]`` times and runs
    :func:`~trainclimate.data.pipeline.build_dataset` on each in a fresh process, reading its
    peak resident memory. The baseline, in the same run, only parses the same CSV files with
    pandas (no cleaning, fusion, resampling or output): the pipeline's cost over bare I/O.
    Equal peak memory at both sizes is the bounded-memory property: the pipeline holds one
    coach-day at a time, so a fleet-year (900 coaches × 365 days) needs no more. The fleet-year
    time is extrapolated from the large run (half 2-s, half 1-min logs) and from a run of 1-min
    winter logs alone.
    """
    import tempfile

    from trainclimate.data import fleetlogs

    with tempfile.TemporaryDirectory(prefix="tc-bench-") as tmp:
        tmp = Path(tmp)
        fleetlogs.generate(tmp / "seed", max_days=days, max_coaches=1)
        runs = []
        for n in copies:
            raw = tmp / f"raw{n}"
            _replicate(tmp / "seed", raw, n)
            run = _child("run_pipeline", str(raw), str(tmp / f"out{n}"))
            base = _child("run_parse_only", str(raw))
            run["rows_per_s"] = run["raw_rows"] / run["seconds"]
            run["parse_only_rows_per_s"] = base["rows"] / base["seconds"]
            run["ratio_to_parse_only"] = run["rows_per_s"] / run["parse_only_rows_per_s"]
            runs.append(run)
        # a fleet-year of 1-min logs, as the issue sizes it: the winter campaign's format alone
        raw = tmp / "winter"
        _replicate(tmp / "seed", raw, copies[1], campaign="winter-spring")
        winter = _child("run_pipeline", str(raw), str(tmp / "out-winter"))
    small, large = runs
    return {
        "rows_per_s": large["rows_per_s"],
        "peak_rss_mb": large["peak_rss_mb"],
        "runs": runs,
        "memory_growth": large["peak_rss_mb"] / small["peak_rss_mb"],
        "size_ratio": large["raw_rows"] / small["raw_rows"],
        "fleet_year_hours_estimate": 900 * 365 * large["seconds"] / large["coach_days"] / 3600,
        "fleet_year_1min_hours_estimate": 900
        * 365
        * winter["seconds"]
        / winter["coach_days"]
        / 3600,
        "winter_1min_run": winter,
        "machine": machine(),
    }


def bench_predictor(
    scales: tuple[int, ...] = (1, 10, 100),
    data_dir: str | Path | None = None,
    rho: int = 60,
    horizon: int = 30,
    progress=None,
) -> dict:
    """Transient Predictor fit time and peak memory at 1-min sampling, ρ = 60, T = 30.

    The streaming fit runs on the full 1-min dataset (every trajectory of both campaigns) and on
    the same trajectories repeated 10× and 100× (as many more Hankel columns); the baseline, at
    1×, materialises the whole transposed Hankel matrix and factors it in one QR. Each run is a
    fresh process reporting its own peak resident memory (which includes the loaded
    trajectories and libraries, ``rss_before_fit_mb``).
    """
    from trainclimate.data.cache import default_dataset

    path = Path(data_dir or default_dataset()) / "trajectories_1min.parquet"
    runs = []
    for mode, scale in [("one_shot", 1), *(("streaming", s) for s in scales)]:
        runs.append(_child("run_fit", str(path), mode, str(scale), str(rho), str(horizon)))
        if progress:
            progress(1)
    one_shot = runs[0]
    streaming = {r["scale"]: r for r in runs[1:]}
    first = streaming[scales[0]]
    return {
        "rho": rho,
        "horizon": horizon,
        "rows": 9 * (rho + horizon),
        "fit_seconds": first["seconds"],
        "columns": first["columns"],
        "runs": runs,
        "streaming_vs_one_shot_time": first["seconds"] / one_shot["seconds"],
        "one_shot_extra_mb": one_shot["peak_rss_mb"] - one_shot["rss_before_fit_mb"],
        "streaming_extra_mb": {
            s: r["peak_rss_mb"] - r["rss_before_fit_mb"] for s, r in streaming.items()
        },
        "seconds_per_million_columns": {
            s: r["seconds"] / r["columns"] * 1e6 for s, r in streaming.items()
        },
        "machine": machine(),
    }


if __name__ == "__main__":  # child processes of the benchmarks: python -m trainclimate.bench NAME …
    _children = {"run_pipeline": run_pipeline, "run_parse_only": run_parse_only, "run_fit": run_fit}
    print(json.dumps(_children[sys.argv[1]](*sys.argv[2:])))
