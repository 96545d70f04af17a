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


def _controller_instances(predictor, n: int, seed: int = 0):
    """``n`` realistic controller inputs: windows of the default dataset's 5-min trajectories
    (measured y, u, d and the true future d), T_rule from the rule curve."""
    from trainclimate.data.cache import default_dataset
    from trainclimate.data.trajectory import iter_trajectories
    from trainclimate.sim.rule import RuleCurve

    rho, T = predictor.rho, predictor.horizon
    path = Path(default_dataset()) / "trajectories_5min.parquet"
    trajs = [t for t, _ in zip(iter_trajectories(path), range(400), strict=False)]
    trajs = [t for t in trajs if len(t) >= rho + T]
    rng = np.random.default_rng(seed)
    rule = RuleCurve()
    out = []
    for _ in range(n):
        t = trajs[rng.integers(len(trajs))]
        k = int(rng.integers(0, len(t) - rho - T + 1))
        d_all = t.d[k : k + rho + T]
        out.append(
            {
                "now_s": float(t.time[k + rho - 1].timestamp()),
                "sample_times_s": np.array([x.timestamp() for x in t.time[k : k + rho]]),
                "y": t.y[k : k + rho],
                "u": t.u[k : k + rho - 1, 0],
                "d": d_all[:rho],
                "d_future": d_all[rho:],
                "t_rule": rule(d_all[rho - 1 :, 0]),
                "u_prev": float(t.u[k + rho - 2, 0]),
            }
        )
    return out


def _percentiles_ms(seconds: list[float]) -> tuple[float, float]:
    a = np.asarray(seconds) * 1e3
    return float(np.median(a)), float(np.percentile(a, 99))


def bench_controller(n_steps: int = 1000, n_naive: int = 60, fleet: int = 1000) -> dict:
    """Controller speed at ρ = 12, T = 6 (the default model) on realistic inputs.

    One OCP solve three ways — the fast path (OSQP, matrices built once, warm-started), the
    cached cvxpy path (DPP, compiled once) and the naive cvxpy path (rebuilt every step) — each
    timed around ``solve`` on the same instances; the whole controller step (checks, state
    estimate, T_opt, solve) on the fast path; and one fleet tick: ``fleet`` coaches, each with its
    own controller, one step each after a first tick has warmed them (setup not timed).
    """
    from trainclimate.control import DDPCController, DDPCProblem, ReferenceProblem
    from trainclimate.control.coach_model import CoachModel
    from trainclimate.control.controller import t_opt
    from trainclimate.control.estimator import StateEstimator
    from trainclimate.control.models import default_predictor

    predictor = default_predictor()
    cases = _controller_instances(predictor, n_steps)
    model = CoachModel()
    est = StateEstimator(model)
    args = []
    for c in cases:  # the OCP's data, as the controller builds it
        est.run(c["y"], c["d"])
        x0 = est.temperatures
        x0[:3] = c["y"][-1]
        opt = t_opt(model, x0, c["d"][-1], c["d_future"], c["t_rule"], 1.0)
        args.append((c["y"], c["u"], c["d"], c["d_future"], c["t_rule"], opt, c["u_prev"]))

    def timed(solve, items) -> list[float]:
        out = []
        for a in items:
            t0 = time.perf_counter()
            solve(*a)
            out.append(time.perf_counter() - t0)
        return out

    fast = timed(DDPCProblem(predictor).solve, args)
    dpp = timed(ReferenceProblem(predictor).solve, args[:200])
    naive = timed(ReferenceProblem(predictor, rebuild=True).solve, args[:n_naive])
    ctl = DDPCController(predictor, model=model)
    step = []
    for c in cases:
        t0 = time.perf_counter()
        ctl.step(**c)
        step.append(time.perf_counter() - t0)

    controllers = [DDPCController(predictor, model=model) for _ in range(fleet)]
    fleet_cases = [cases[i % len(cases)] for i in range(fleet)]
    for ctl, c in zip(controllers, fleet_cases, strict=True):
        ctl.step(**c)  # first tick: warm-up of the estimate and the solver
    t0 = time.perf_counter()
    reasons: dict[str, int] = {}
    for ctl, c in zip(controllers, fleet_cases, strict=True):
        r = ctl.step(**c)
        reasons[r.reason] = reasons.get(r.reason, 0) + 1
    fleet_s = time.perf_counter() - t0

    fast_med, fast_p99 = _percentiles_ms(fast)
    dpp_med, dpp_p99 = _percentiles_ms(dpp)
    naive_med, naive_p99 = _percentiles_ms(naive)
    step_med, step_p99 = _percentiles_ms(step)
    return {
        "fast_median_ms": fast_med,
        "fast_p99_ms": fast_p99,
        "cvxpy_dpp_median_ms": dpp_med,
        "cvxpy_dpp_p99_ms": dpp_p99,
        "cvxpy_naive_median_ms": naive_med,
        "cvxpy_naive_p99_ms": naive_p99,
        "naive_over_fast": naive_med / fast_med,
        "dpp_over_fast": dpp_med / fast_med,
        "controller_step_median_ms": step_med,
        "controller_step_p99_ms": step_p99,
        "fleet_1000_tick_s": fleet_s * 1000 / fleet,
        "fleet_coaches": fleet,
        "fleet_tick_reasons": reasons,
        "rho": predictor.rho,
        "horizon": predictor.horizon,
        "instances": len(cases),
        "machine": machine(),
    }
