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
    from trainclimate.predict.default import default_predictor

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


# --- the service (PostgreSQL) ------------------------------------------------------------------
#: The server ``bench service`` creates its database on, unless ``$TRAINCLIMATE_TEST_PG_URL``
#: names another or ``--db`` gives a database.
PG_SERVER = "postgresql://postgres@127.0.0.1:5432/test"
_PG_EPOCH_S = 946_684_800  # 2000-01-01T00:00Z: PostgreSQL's binary timestamps count from here
_COPY_SIGNATURE = b"PGCOPY\n\xff\r\n\x00" + bytes(8)  # binary COPY header (no flags, no extension)
_RESET = (
    "TRUNCATE telemetry, setpoints, overrides, coaches, trains, fleet_clocks, audit_log "
    "RESTART IDENTITY CASCADE"
)


class ServiceBenchError(Exception):
    """No usable database for ``bench service`` (the CLI's exit code 2)."""


def _libpq_url(url: str) -> str:
    """``url`` for psycopg itself; a non-PostgreSQL URL is an error."""
    from trainclimate.service.db import normalise_url

    url = normalise_url(url)
    if not url.startswith("postgresql+psycopg://"):
        scheme = url.split(":", 1)[0]
        raise ServiceBenchError(f"the service benchmark needs PostgreSQL, not {scheme}")
    return "postgresql://" + url.split("://", 1)[1]


class _BenchDatabase:
    """A fresh database on the server (created here, dropped at the end), or the database ``url``
    names, which must be empty (the benchmark fills and truncates its tables)."""

    def __init__(self, url: str | None):
        import uuid

        self.given = url is not None
        if self.given:
            self.url = _libpq_url(url)
            self.name = None
        else:
            server = _libpq_url(os.environ.get("TRAINCLIMATE_TEST_PG_URL") or PG_SERVER)
            self.server = server
            self.name = f"tc_bench_{uuid.uuid4().hex[:10]}"
            self.url = f"{server.rsplit('/', 1)[0]}/{self.name}"

    def __enter__(self) -> str:
        import psycopg

        from trainclimate.service.db import migrate

        try:
            if self.given:
                psycopg.connect(self.url).close()
            else:
                with psycopg.connect(self.server, autocommit=True) as conn:
                    conn.execute(f'CREATE DATABASE "{self.name}"')
        except psycopg.OperationalError as exc:
            first = (str(exc).strip() or type(exc).__name__).splitlines()[0]
            raise ServiceBenchError(f"no PostgreSQL database to benchmark on: {first}") from None
        try:
            migrate(self.url)
            with psycopg.connect(self.url) as conn:
                used = conn.execute(
                    "SELECT (SELECT count(*) FROM coaches) + (SELECT count(*) FROM telemetry)"
                ).fetchone()[0]
            if used:
                raise ServiceBenchError(
                    "--db: the database must be empty (the benchmark fills and truncates it)"
                )
        except BaseException:
            self.__exit__()
            raise
        return self.url

    def __exit__(self, *exc) -> None:
        import psycopg

        if not self.given:
            with psycopg.connect(self.server, autocommit=True) as conn:
                conn.execute(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)')


def _sql(url: str, *statements: str, autocommit: bool = False) -> list:
    """Run ``statements``; the first row of each (None if it returns none)."""
    import psycopg

    out = []
    with psycopg.connect(url, autocommit=autocommit) as conn:
        for s in statements:
            cur = conn.execute(s)
            out.append(cur.fetchone() if cur.description else None)
    return out


def _postgres(url: str) -> dict:
    """The server's version and the settings that matter for these figures."""
    names = ("shared_buffers", "synchronous_commit", "fsync", "max_wal_size", "work_mem")
    rows = _sql(url, "SHOW server_version", *(f"SHOW {n}" for n in names))
    return {"version": rows[0][0], **{n: r[0] for n, r in zip(names, rows[1:], strict=True)}}


def _copy_block(coach_ids: np.ndarray, time_s: np.ndarray, values: dict) -> bytes:
    """Telemetry rows in PostgreSQL's binary COPY format, built with numpy: coach_id, time, the
    values, mode (``regular``) and connected (true); every row the same size (coach ids of one
    length), so one structured array holds them."""
    from trainclimate.service.telemetry import VALUE_COLS

    ids = np.asarray(coach_ids, dtype="S")
    width = ids.dtype.itemsize
    if np.char.str_len(ids).min() != width:  # numpy would pad the shorter ones with NUL bytes
        raise ValueError("coach ids of one COPY block must have the same length")
    fields = [("n", ">i2"), ("id_len", ">i4"), ("coach_id", f"S{width}")]
    fields += [("time_len", ">i4"), ("time", ">i8")]
    for c in VALUE_COLS:
        fields += [(f"{c}_len", ">i4"), (c, ">f8")]
    fields += [("mode_len", ">i4"), ("mode", "S7"), ("connected_len", ">i4"), ("connected", "u1")]
    a = np.empty(len(time_s), np.dtype(fields))
    a["n"] = 3 + len(VALUE_COLS) + 1
    a["id_len"], a["coach_id"] = width, ids
    a["time_len"] = 8
    a["time"] = np.round((np.asarray(time_s, float) - _PG_EPOCH_S) * 1e6).astype(np.int64)
    for c in VALUE_COLS:
        a[f"{c}_len"], a[c] = 8, values[c]
    a["mode_len"], a["mode"] = 7, b"regular"
    a["connected_len"], a["connected"] = 1, 1
    return a.tobytes()


def _copy_telemetry(url: str, blocks) -> tuple[int, float]:
    """COPY the binary ``blocks`` (from :func:`_copy_block`) into telemetry in one transaction:
    (bytes sent, seconds including the commit)."""
    import psycopg

    from trainclimate.service.telemetry import VALUE_COLS

    cols = ", ".join(("coach_id", "time", *VALUE_COLS, "mode", "connected"))
    sent, t0 = 0, time.perf_counter()
    sql = f"COPY telemetry ({cols}) FROM STDIN (FORMAT BINARY)"
    with psycopg.connect(url) as conn, conn.cursor() as cur, cur.copy(sql) as copy:
        copy.write(_COPY_SIGNATURE)
        for block in blocks:
            copy.write(block)
            sent += len(block)
        copy.write(b"\xff\xff")
    return sent, time.perf_counter() - t0


def _synthetic(rng, train: np.ndarray, active: np.ndarray, minute: np.ndarray) -> dict:
    """Plausible 1-minute telemetry of coaches in regular mode (numpy, no simulation): a daily
    cycle of T_amb around 4 °C and of the sun, rooms at 21–22 °C with sensor noise, T_rule 22 °C
    and an activated coach's T_ref below it, HVAC power 5–10 kW (≈ 10 % less when activated).
    ``minute`` counts minutes since midnight UTC of the first day; arrays of one length."""
    from trainclimate.service.telemetry import VALUE_COLS

    n = len(minute)
    hour = (minute % 1440) / 60.0
    t_amb = 4.0 + 4.0 * np.sin(2 * np.pi * (hour - 9.0) / 24.0) + 0.3 * (train % 7)
    t_amb += rng.normal(0.0, 0.3, n)
    sun = np.clip(np.sin(np.pi * (hour - 7.0) / 10.0), 0.0, None) * (hour > 7.0) * (hour < 17.0)
    ghi = 450.0 * sun * rng.uniform(0.5, 1.0, n)
    mid = 21.6 - 0.3 * active + rng.normal(0.0, 0.2, n)
    power = 7.5 + 1.0 * np.sin(2 * np.pi * (hour - 3.0) / 24.0) - 0.15 * (t_amb - 4.0)
    power = np.clip(power + rng.normal(0.0, 0.8, n), 5.0, 10.0) * np.where(active, 0.9, 1.0)
    values = {
        "t_room_up_c": mid + 0.3 + rng.normal(0.0, 0.1, n),
        "t_room_mid_c": mid,
        "t_room_low_c": mid - 0.3 + rng.normal(0.0, 0.1, n),
        "t_ref_c": 22.0 - 0.8 * active,
        "t_rule_c": np.full(n, 22.0),
        "t_amb_c": t_amb,
        "q_gt_w_m2": 0.45 * ghi,
        "q_gs_w_m2": 0.25 * ghi,
        "occupancy_pct": np.clip(rng.normal(25.0, 15.0, n), 0.0, 150.0),
        "speed_kmh": rng.uniform(0.0, 120.0, n),
        "ghi_w_m2": ghi,
        "power_kw": power,
    }
    return {c: np.broadcast_to(np.asarray(values[c], float), (n,)) for c in VALUE_COLS}


def _pair_ids(prefix: str, trains: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Coach ids ``{prefix}{train:03d}-A`` (activated) and ``-B`` of ``trains`` trains: (ids,
    train index, activated) per coach, A and B of each train next to each other."""
    ids = [f"{prefix}{t:03d}-{s}" for t in range(trains) for s in "AB"]
    train = np.repeat(np.arange(trains), 2)
    active = np.tile([True, False], trains)
    return ids, train, active


def _register(url: str, ids: list[str], fleet: str) -> None:
    """Trains and coaches (``{train}-A`` activated), straight into the tables."""
    import psycopg

    trains = sorted({c.rsplit("-", 1)[0] for c in ids})
    with psycopg.connect(url) as conn, conn.cursor() as cur:
        cur.executemany(
            "INSERT INTO trains (id, name, created_at) VALUES (%s, %s, now())",
            [(t, t) for t in trains],
        )
        cur.executemany(
            "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at) "
            "VALUES (%s, %s, %s, %s, now())",
            [(c, c.rsplit("-", 1)[0], fleet, c.endswith("-A")) for c in ids],
        )


def _tokens(url: str, *roles: str) -> list[dict]:
    """Authorization headers of new users with ``roles``."""
    from trainclimate.service.db import Database
    from trainclimate.service.security import create_token

    db = Database(url)
    headers = []
    with db.transaction() as session:
        for role in roles:
            token, _ = create_token(session, role, f"bench-{role}")
            headers.append({"Authorization": f"Bearer {token}"})
    db.dispose()
    return headers


def _bench_model(directory: Path) -> tuple[Path, str]:
    """The model file the app registers: the cached default model if it exists (never built
    here), else a Transient Predictor at the same setting (5 min, ρ = 12, T = 6) fitted in about
    2 s on white-noise inputs through first-order room dynamics: valid, which is all the tick
    needs."""
    from types import SimpleNamespace

    from trainclimate.predict import TransientPredictor
    from trainclimate.predict.artifact import save_predictor
    from trainclimate.predict.default import default_model_path

    path = default_model_path()
    if path.exists():
        return path, "default (cached)"
    rng = np.random.default_rng(0)
    trajectories = []
    for _ in range(20):
        n = 200
        u = 22.0 + rng.uniform(-2.0, 2.0, n)
        d = np.column_stack(
            [
                rng.normal(5.0, 5.0, n),
                rng.uniform(0.0, 300.0, n),
                rng.uniform(0.0, 200.0, n),
                rng.uniform(0.0, 100.0, n),
                rng.uniform(0.0, 120.0, n),
            ]
        )
        y = np.empty((n, 3))
        y[0] = 21.5
        gain = d[:, 1] * 2e-3 + d[:, 2] * 1e-3 + d[:, 3] * 1e-2
        for k in range(n - 1):
            drive = 0.25 * (u[k] - y[k]) + 0.03 * (d[k, 0] - y[k]) + gain[k]
            y[k + 1] = y[k] + drive + np.array([0.05, 0.0, -0.05]) + rng.normal(0.0, 0.05, 3)
        trajectories.append(SimpleNamespace(y=y, u=u[:, None], d=d, sampling_min=5))
    predictor = TransientPredictor(12, 6).fit(trajectories)
    return save_predictor(predictor, directory / "bench-model.npz"), "small (fitted here)"


def _app(url: str, model: Path):
    """The service in-process (migrations, model registration); its live loop only runs once at
    start, so nothing else writes while a benchmark runs."""
    from trainclimate.service.app import create_app
    from trainclimate.service.settings import Settings

    settings = Settings(database_url=url, predictor_path=model, scheduler_interval_s=3600.0)
    return create_app(settings)


def _latency_ms(seconds: list[float]) -> dict:
    a = np.asarray(seconds) * 1e3
    return {
        "median_ms": float(np.median(a)),
        "p95_ms": float(np.percentile(a, 95)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "requests": len(a),
    }


def _bench_ingest(url: str, model: Path, coaches: int, batches: int, rows_per_batch: int) -> dict:
    """Telemetry ingest rows/s three ways on the same batches: the HTTP API, ``commands.ingest``
    (one transaction per batch, no HTTP) and the baseline, a plain executemany INSERT per batch;
    interleaved batch by batch (each way writes its own coaches into one table), so a machine
    that slows down meanwhile slows all three alike. Then all rows once more in one executemany
    and one transaction."""
    import pandas as pd
    from fastapi.testclient import TestClient
    from sqlalchemy import text

    from trainclimate.service import commands
    from trainclimate.service.db import Database
    from trainclimate.service.models import Telemetry
    from trainclimate.service.telemetry import to_wire

    rng = np.random.default_rng(1)
    pairs = coaches // 2
    ids, train, active = _pair_ids("H", pairs)
    start = pd.Timestamp("2024-11-01T00:00Z")
    batch_rows: list[tuple[int, list[dict]]] = []
    for b in range(batches):  # hourly batches, every coach's in turn (as gateways send them)
        minute = b * rows_per_batch + np.arange(1, rows_per_batch + 1)
        stamps = [t.to_pydatetime() for t in start + pd.to_timedelta(minute, unit="min")]
        for i in range(len(ids)):
            n = len(minute)
            v = _synthetic(rng, np.full(n, train[i]), np.full(n, active[i]), minute)
            values = {c: a.tolist() for c, a in v.items()}
            rows = [
                {
                    "time": t,
                    **{c: values[c][k] for c in values},
                    "mode": "regular",
                    "connected": True,
                }
                for k, t in enumerate(stamps)
            ]
            batch_rows.append((i, rows))
    n_rows = sum(len(r) for _, r in batch_rows)
    way_ids = {
        way: _pair_ids(prefix, pairs)[0]
        for way, prefix in zip(("http", "direct", "plain", "one"), "HDPO", strict=True)
    }
    for way in way_ids.values():
        _register(url, way, "live")
    bodies = [
        json.dumps(
            {
                "coach_id": way_ids["http"][i],
                "rows": [to_wire(r) for r in rows],
            }
        ).encode()
        for i, rows in batch_rows
    ]
    (operator,) = _tokens(url, "operator")
    headers = {**operator, "Content-Type": "application/json"}
    db = Database(url)
    table = Telemetry.__table__
    plain_s = direct_s = http_s = 0.0
    latencies = []
    with TestClient(_app(url, model)) as client:
        for (i, rows), body in zip(batch_rows, bodies, strict=True):
            plain_rows = [{**r, "coach_id": way_ids["plain"][i]} for r in rows]
            t0 = time.perf_counter()  # the baseline: a plain INSERT of the batch
            with db.engine.begin() as conn:
                conn.execute(table.insert(), plain_rows)
            t1 = time.perf_counter()  # the command the API runs, without HTTP
            with db.transaction() as session:
                commands.ingest(session, way_ids["direct"][i], rows)
            t2 = time.perf_counter()  # through the HTTP API
            reply = client.post("/api/v1/telemetry", content=body, headers=headers)
            t3 = time.perf_counter()
            if reply.status_code != 200 or reply.json()["stored"] != len(rows):
                raise RuntimeError(f"ingest failed: {reply.status_code} {reply.text[:200]}")
            plain_s += t1 - t0
            direct_s += t2 - t1
            http_s += t3 - t2
            latencies.append(t3 - t2)
    every = [{**r, "coach_id": way_ids["one"][i]} for i, rows in batch_rows for r in rows]
    t0 = time.perf_counter()
    with db.engine.begin() as conn:
        conn.execute(table.insert(), every)
    one_s = time.perf_counter() - t0
    stored = _sql(url, "SELECT count(*) FROM telemetry")[0][0]
    if stored != 4 * n_rows:
        raise RuntimeError(f"{stored} rows stored of {4 * n_rows}")
    with db.engine.begin() as conn:
        conn.execute(text(_RESET))
    db.dispose()
    plain = n_rows / plain_s
    return {
        "rows": n_rows,
        "coaches": len(ids),
        "batches": len(batch_rows),
        "rows_per_batch": rows_per_batch,
        "http_rows_per_s": n_rows / http_s,
        "http_batch_latency": _latency_ms(latencies),
        "direct_rows_per_s": n_rows / direct_s,
        "plain_insert_rows_per_s": plain,
        "plain_insert_one_transaction_rows_per_s": n_rows / one_s,
        "http_vs_plain": n_rows / http_s / plain,
        "direct_vs_plain": n_rows / direct_s / plain,
    }


def _comparison_rows(trains: int, days: int, seed: int):
    """Blocks for :func:`_copy_telemetry`: ``trains`` pairs × ``days`` of 1-minute rows, one
    block per day, in the order a live feed stores them (hour by hour, coach after coach)."""
    import pandas as pd

    ids, train, active = _pair_ids("C", trains)
    start_s = pd.Timestamp("2024-11-01T00:00Z").timestamp()
    rng = np.random.default_rng(seed)
    hour, coach, minute = np.meshgrid(
        np.arange(24), np.arange(len(ids)), np.arange(1, 61), indexing="ij"
    )
    coach, day_minute = coach.ravel(), (hour * 60 + minute).ravel()
    id_array = np.asarray(ids, dtype="S")[coach]
    for day in range(days):
        m = day * 1440 + day_minute
        v = _synthetic(rng, train[coach], active[coach], m)
        yield _copy_block(id_array, start_s + 60.0 * m, v)


def _in_schema(url: str, schema: str) -> str:
    """``url`` with ``schema`` first on the search path (a second set of tables)."""
    return f"{url}{'&' if '?' in url else '?'}options=-csearch_path%3D{schema}"


def _time_comparisons(model: Path, databases: dict, n: int, seed: int) -> dict:
    """``n`` GET /trains/{id}/comparison on each of ``databases`` (name → (URL, trains, days)),
    taking turns request by request, each of a random train over a random 24-h window (after a
    few untimed ones): latency per database."""
    import contextlib

    import pandas as pd
    from fastapi.testclient import TestClient

    rng = np.random.default_rng(seed)
    start = pd.Timestamp("2024-11-01T00:00Z")
    latencies: dict[str, list[float]] = {name: [] for name in databases}
    windows: dict[str, int] = {}
    with contextlib.ExitStack() as stack:
        clients = {
            name: (stack.enter_context(TestClient(_app(url, model))), _tokens(url, "viewer")[0])
            for name, (url, _, _) in databases.items()
        }
        for i in range(n + 5):
            for name, (_, trains, days) in databases.items():
                client, viewer = clients[name]
                train = f"C{int(rng.integers(trains)):03d}"
                first = start + pd.Timedelta(minutes=int(rng.integers(0, (days - 1) * 1440 + 1)))
                params = {
                    "start": first.isoformat(),
                    "end": (first + pd.Timedelta(hours=24)).isoformat(),
                }
                path = f"/api/v1/trains/{train}/comparison"
                t0 = time.perf_counter()
                reply = client.get(path, params=params, headers=viewer)
                elapsed = time.perf_counter() - t0
                if reply.status_code != 200:
                    raise RuntimeError(f"comparison failed: {reply.status_code} {reply.text[:200]}")
                if i >= 5:
                    latencies[name].append(elapsed)
                    windows[name] = len(reply.json()["windows"])
    return {
        name: {**_latency_ms(latencies[name]), "windows_per_reply": windows[name]}
        for name in databases
    }


def _table_size(url: str) -> dict:
    total, heap, index = _sql(
        url,
        "SELECT pg_total_relation_size('telemetry'), pg_relation_size('telemetry'), "
        "pg_indexes_size('telemetry')",
    )[0]
    return {"total_mb": total / 2**20, "heap_mb": heap / 2**20, "indexes_mb": index / 2**20}


def _bench_comparison(
    url: str, model: Path, trains: int, days: int, requests: int, progress
) -> dict:
    """p95 latency of a 24-h pair comparison with ``trains`` pairs × ``days`` stored, against
    the same with 1 pair × 1 day stored (its own tables, in schema ``bench_small`` of the same
    database), requests taking turns; the COPY load rate of the large data set."""
    from trainclimate.service.db import migrate

    small_url = _in_schema(url, "bench_small")
    _sql(url, "CREATE SCHEMA bench_small")
    try:
        migrate(small_url)
        _register(small_url, _pair_ids("C", 1)[0], "archive")
        _copy_telemetry(small_url, _comparison_rows(1, 1, seed=2))
        _sql(small_url, "VACUUM ANALYZE telemetry", autocommit=True)

        ids = _pair_ids("C", trains)[0]
        _register(url, ids, "archive")  # not the live fleet: the tick later leaves them alone
        n_rows = len(ids) * days * 1440
        sent, copy_s = _copy_telemetry(url, _comparison_rows(trains, days, seed=2))
        t0 = time.perf_counter()
        _sql(url, "VACUUM ANALYZE telemetry", autocommit=True)
        vacuum_s = time.perf_counter() - t0
        if progress:
            progress(1)
        timed = _time_comparisons(
            model, {"large": (url, trains, days), "small": (small_url, 1, 1)}, requests, seed=3
        )
        large, small = timed["large"], timed["small"]
        large["rows_stored"], large["table"] = n_rows, _table_size(url)
        small["rows_stored"], small["table"] = 2 * 1440, _table_size(small_url)
        if progress:
            progress(1)
    finally:
        _sql(url, "DROP SCHEMA IF EXISTS bench_small CASCADE")
    return {
        "coaches": len(ids),
        "days": days,
        "window_hours": 24,
        "large": large,
        "small": small,
        "p95_large_vs_small": large["p95_ms"] / small["p95_ms"],
        "median_large_vs_small": large["median_ms"] / small["median_ms"],
        "copy": {
            "rows": n_rows,
            "seconds": copy_s,
            "rows_per_s": n_rows / copy_s,
            "mb_sent": sent / 2**20,
            "vacuum_analyze_s": vacuum_s,
        },
    }


def _fleet_block(coaches: int, minutes: int):
    """``coaches`` coaches of ``parked-heating-nov`` (HVAC in regular mode) simulated for
    ``minutes``, as 1-minute telemetry rows minute by minute (every coach's row of a minute
    together, as a live feed stores them): (ids, the first row's minute start, COPY block)."""
    from trainclimate.sim.rule import MODE_REGULAR

    ids = _pair_ids("L", coaches // 2)[0]
    env, params = scenarios.build(
        scenarios.get("parked-heating-nov"), n_coaches=len(ids), hours=minutes / 60.0
    )
    sim = FleetSimulator(params, env)
    sim.run()
    r = sim.result()
    per_min = round(60.0 / env.dt_s)
    steps = minutes * per_min
    if not np.all(np.asarray(env.mode[:steps]) == MODE_REGULAR):
        raise RuntimeError("the fleet tick's scenario left regular mode")

    def means(a) -> np.ndarray:
        a = np.asarray(a)[:steps]
        return a.reshape(minutes, per_min, *a.shape[1:]).mean(axis=1)

    room = means(r.t_room_meas_c)
    values = {
        "t_room_up_c": room[..., 0],
        "t_room_mid_c": room[..., 1],
        "t_room_low_c": room[..., 2],
        "t_ref_c": means(r.t_ref_c),
        "t_rule_c": means(r.t_rule_c),
        "t_amb_c": means(env.t_amb_c),
        "ghi_w_m2": means(env.ghi_w_m2),
        "q_gt_w_m2": means(env.q_roof_w_m2),
        "q_gs_w_m2": means(env.q_side_w_m2),
        "occupancy_pct": means(env.occupancy_pct),
        "speed_kmh": means(env.speed_kmh),
        "power_kw": means(r.total_power_w) / 1e3,
    }
    start = env.time[0]
    time_s = start.timestamp() + 60.0 * np.repeat(np.arange(1, minutes + 1), len(ids))
    id_array = np.tile(np.asarray(ids, dtype="S"), minutes)
    block = _copy_block(id_array, time_s, {c: v.ravel() for c, v in values.items()})
    return ids, start, block


def _bench_tick(url: str, model: Path, coaches: int, lead_ticks: int, repeats: int) -> dict:
    """The live fleet's tick for ``coaches`` coaches (half activated) with its database work,
    against the same decisions in memory (:meth:`Scheduler.decide`: the controller steps alone)."""
    from datetime import timedelta

    from sqlalchemy import select

    from trainclimate.predict.artifact import load_predictor
    from trainclimate.service.app import register_model_file
    from trainclimate.service.db import Database
    from trainclimate.service.loop import Scheduler
    from trainclimate.service.models import Coach
    from trainclimate.service.settings import Settings
    from trainclimate.service.telemetry import controller_samples, load_rows

    settings = Settings(database_url=url, predictor_path=model)
    period = timedelta(minutes=settings.sampling_min)
    minutes = round((lead_ticks + repeats) * period / timedelta(minutes=1))
    ids, start, block = _fleet_block(coaches, minutes)
    _register(url, ids, "live")
    _copy_telemetry(url, [block])
    _sql(url, "VACUUM ANALYZE telemetry", autocommit=True)
    db = Database(url)
    with db.transaction() as session:
        register_model_file(session, settings)
    warm = start.to_pydatetime() + lead_ticks * period
    ticks = [warm + j * period for j in range(1, repeats + 1)]

    scheduler = Scheduler(db, settings)
    if scheduler.tick_fleet("live", warm) != len(ids):  # warm-up: controllers, caches, pool
        raise RuntimeError("the warm-up tick did not reach every coach")
    tick_s, written = [], []
    for tick in ticks:
        t0 = time.perf_counter()
        written.append(scheduler.tick_fleet("live", tick))
        tick_s.append(time.perf_counter() - t0)
    reasons = dict(
        _sql_all(
            url,
            "SELECT reason, count(*) FROM setpoints WHERE tick = %s GROUP BY reason ORDER BY 1",
            (ticks[0],),
        )
    )

    # the same work without the database: the decisions alone, on the same samples
    rho = load_predictor(model).rho
    window = (rho + 2) * period + timedelta(minutes=1)
    with db.sessions() as session:
        fleet = session.scalars(select(Coach).where(Coach.fleet == "live").order_by(Coach.id)).all()
    read_s, samples_s, steps_s = [], [], []
    baseline = Scheduler(db, settings)
    with db.transaction() as session:
        baseline.refresh_model(session)
    baseline_reasons: dict[str, int] = {}
    for j, tick in enumerate([warm, *ticks]):
        t0 = time.perf_counter()
        telemetry = {}
        for b in range(0, len(ids), 250):  # the tick's reads, batch by batch
            with db.transaction() as session:
                telemetry |= load_rows(session, ids[b : b + 250], tick - window, tick)
        t1 = time.perf_counter()
        at = tick.timestamp()
        samples = {c: controller_samples(telemetry[c], at, scheduler.period_s) for c in ids}
        t2 = time.perf_counter()
        decisions = [baseline.decide(c, samples[c.id], None, tick) for c in fleet]
        t3 = time.perf_counter()
        if j:  # the first is the baseline's own warm-up tick
            read_s.append(t1 - t0)
            samples_s.append(t2 - t1)
            steps_s.append(t3 - t2)
        if j == 1:
            for d in decisions:
                baseline_reasons[d.reason] = baseline_reasons.get(d.reason, 0) + 1
    rows_stored = _sql(url, "SELECT count(*) FROM telemetry")[0][0]

    # the tick's claim and writes: a tick with no telemetry in its window (every coach stale, so
    # no samples and no controller step) is the claim, the reads (empty, still one DataFrame per
    # coach), the overrides, the insert of every setpoint, the last_tick updates and the commits
    empty = ticks[-1] + timedelta(days=1)
    t0 = time.perf_counter()
    stale_written = scheduler.tick_fleet("live", empty)
    claim_write_s = time.perf_counter() - t0
    stale = dict(
        _sql_all(url, "SELECT reason, count(*) FROM setpoints WHERE tick = %s GROUP BY 1", (empty,))
    )
    if stale_written != len(ids) or stale != {"stale": len(ids)}:
        raise RuntimeError(f"the tick without telemetry gave {stale}")
    db.dispose()
    tick_med, steps_med = float(np.median(tick_s)), float(np.median(steps_s))
    read_med, samples_med = float(np.median(read_s)), float(np.median(samples_s))
    return {
        "coaches": len(ids),
        "activated": len(ids) // 2,
        "lead_in_ticks": lead_ticks,
        "tick_s": tick_med,
        "tick_runs_s": tick_s,
        "setpoints_written": written,
        "reasons": reasons,
        "controller_steps_s": steps_med,
        "controller_steps_runs_s": steps_s,
        "baseline_reasons": baseline_reasons,
        "tick_vs_steps": tick_med / steps_med,
        "parts_s": {  # each measured on its own (their sum is the tick's, up to the noise)
            "telemetry_read": read_med,
            "controller_samples": samples_med,
            "decisions": steps_med,
            "tick_without_telemetry": claim_write_s,
        },
        "target_s": 2.0,
        "telemetry_rows_stored": rows_stored,
    }


def _sql_all(url: str, statement: str, params: tuple = ()) -> list:
    import psycopg

    with psycopg.connect(url) as conn:
        return conn.execute(statement, params).fetchall()


def bench_service(
    db_url: str | None = None,
    *,
    ingest_coaches: int = 50,
    ingest_batches: int = 12,
    trains: int = 50,
    days: int = 30,
    requests: int = 200,
    fleet: int = 1000,
    repeats: int = 1,
    progress=None,
) -> dict:
    """The service on PostgreSQL: telemetry ingest rows/s, the 24-h pair comparison's latency
    with a month of fleet data stored, and the live fleet's tick with its database writes.

    Runs on a fresh database created on the server ``$TRAINCLIMATE_TEST_PG_URL`` (default
    :data:`PG_SERVER`) and dropped at the end, or on the empty database ``db_url``, migrated with
    :func:`~trainclimate.service.db.migrate`; the app runs in-process (FastAPI's TestClient) with
    the cached default model, or a small one fitted here if there is none.

    1. Ingest: ``ingest_coaches`` coaches × ``ingest_batches`` hourly batches of 60 rows through
       ``POST /api/v1/telemetry`` and through ``commands.ingest`` (one transaction per batch);
       baseline a plain SQLAlchemy executemany INSERT of the same batches. The three take turns
       batch by batch, each writing its own coaches.
    2. Comparison: ``trains`` × 2 coaches × ``days`` of 1-min rows loaded with binary COPY (the
       load rate is reported), then ``requests`` ``GET /api/v1/trains/{id}/comparison`` of random
       trains over random 24-h windows; baseline the same with 1 pair × 1 day stored (its own
       tables, in a schema of the same database), requests taking turns with the large one.
    3. Fleet tick: ``fleet`` live coaches (half activated), simulated minute by minute for a
       lead-in of 14 ticks; after a warm-up tick, ``repeats`` ticks of
       :meth:`~trainclimate.service.loop.Scheduler.tick_fleet` are timed; baseline the same
       decisions in memory on the same samples (the controller steps alone). The tick's parts
       are timed on their own as well: its telemetry reads, the samples' extraction, and a tick
       with no telemetry in its window (every coach stale: the claim and the writes).
    """
    import tempfile

    step = progress or (lambda n: None)
    with tempfile.TemporaryDirectory(prefix="tc-bench-") as tmp, _BenchDatabase(db_url) as url:
        model, model_kind = _bench_model(Path(tmp))
        postgres = _postgres(url)
        ingest = _bench_ingest(url, model, ingest_coaches, ingest_batches, 60)
        step(1)
        comparison = _bench_comparison(url, model, trains, days, requests, step)
        tick = _bench_tick(url, model, fleet, 14, repeats)
        step(1)
        if db_url is not None:
            _sql(url, _RESET)  # leave the given database as empty as it came
    return {
        "ingest": ingest,
        "comparison": comparison,
        "fleet_tick": tick,
        "model": model_kind,
        "database": {"created": db_url is None, **postgres},
        "machine": machine(),
    }
