"""Benchmarks (``trainclimate bench …``): speed figures measured against a baseline in one run."""

from __future__ import annotations

import json
import os
import platform
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


_PIPELINE_CHILD = """
import json, resource, sys, time
from trainclimate.data.pipeline import build_dataset
t0 = time.perf_counter()
s = build_dataset(sys.argv[1], sys.argv[2])
dt = time.perf_counter() - t0
print(json.dumps({"seconds": dt, "raw_rows": s.raw_rows, "coach_days": s.coach_days,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

_PARSE_CHILD = """
import json, sys, time
from pathlib import Path
import pandas as pd
from trainclimate.data.formats import FORMATS
t0 = time.perf_counter()
rows = 0
for path in sorted(Path(sys.argv[1]).rglob("*.csv")):
    head = path.read_bytes()[:200]
    sep = ";" if b";" in head else ","
    try:
        rows += len(pd.read_csv(path, sep=sep, dtype=str, on_bad_lines="skip"))
    except Exception:
        pass
print(json.dumps({"seconds": time.perf_counter() - t0, "rows": rows}))
"""


def _child(code: str, *args: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", code, *args], check=True, capture_output=True, text=True
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
            run = _child(_PIPELINE_CHILD, str(raw), str(tmp / f"out{n}"))
            base = _child(_PARSE_CHILD, str(raw))
            run["rows_per_s"] = run["raw_rows"] / run["seconds"]
            run["parse_only_rows_per_s"] = base["rows"] / base["seconds"]
            run["ratio_to_parse_only"] = run["rows_per_s"] / run["parse_only_rows_per_s"]
            runs.append(run)
        # a fleet-year of 1-min logs, as the issue sizes it: the winter campaign's format alone
        raw = tmp / "winter"
        _replicate(tmp / "seed", raw, copies[1], campaign="winter-spring")
        winter = _child(_PIPELINE_CHILD, str(raw), str(tmp / "out-winter"))
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
