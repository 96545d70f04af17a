"""The ``trainclimate`` command line (see CONTRACT.md for the commands and their JSON).

Every command takes ``--json`` and then prints exactly one JSON object on stdout; logs and
progress go to stderr. Bad arguments, an unknown scenario or a malformed input file end with exit
code 2 and a one-line message on stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from trainclimate.data.pipeline import PipelineError
from trainclimate.paths import StorageError, writable_dir, writable_file
from trainclimate.predict import METHODS, PredictorDataError
from trainclimate.predict.artifact import ArtifactError
from trainclimate.sim.params import CoachParams, ParamsError, load_params
from trainclimate.sim.scenarios import SCENARIOS, ScenarioError
from trainclimate.sim.weather import WeatherError

CONTROLLERS = ("rule", "ddpc", "edge")
OUT_HINT = "choose another path"


class UsageError(Exception):
    """Bad input from the user: exit code 2 with a one-line message."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        raise UsageError(message)


def _emit(args: argparse.Namespace, data: dict, human: Callable[[dict], str]) -> None:
    if args.json:
        print(json.dumps(data, default=_json_default))
    else:
        print(human(data))


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _progress(total: int, desc: str, unit: str = "step"):
    """A tqdm progress bar on stderr when it is a terminal, else a no-op."""
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        leave=False,
        disable=not sys.stderr.isatty(),
        mininterval=0.5,
    )


def _out_file(path: str | None, what: str) -> Path | None:
    """An output file named on the command line, its directory created (None if not given);
    :class:`StorageError` (exit 2) when it cannot be written — before any work is done."""
    return writable_file(path, what, hint=OUT_HINT) if path else None


def _out_dir(path: str | None, what: str) -> Path | None:
    """An output directory named on the command line, created with its parents (None if not
    given); :class:`StorageError` (exit 2) when it cannot be."""
    return writable_dir(path, what, hint=OUT_HINT) if path else None


# --- commands -------------------------------------------------------------------------------
def cmd_scenarios(args: argparse.Namespace) -> None:
    data = {
        "scenarios": [{"name": s.name, "description": s.description} for s in SCENARIOS.values()]
    }
    _emit(
        args,
        data,
        lambda d: "\n".join(f"{s['name']:<34} {s['description']}" for s in d["scenarios"]),
    )


def cmd_coach_params(args: argparse.Namespace) -> None:
    params = load_params(args.file) if args.file else CoachParams()
    data = params.to_dict()

    def human(d: dict) -> str:
        return "\n".join(f"{k:<32} {v}" for k, v in d.items())

    _emit(args, data, human)


def run_simulation(args: argparse.Namespace, record_flows: bool = False):
    """Build and run the simulation an argparse namespace asks for: (scenario, result, tick
    summary or None)."""
    from trainclimate.control.closed_loop import ClosedLoop, build_controllers, tick_summary
    from trainclimate.sim import scenarios
    from trainclimate.sim.simulator import FleetSimulator
    from trainclimate.sim.weather import load_weather_csv

    scenario = scenarios.get(args.scenario)
    weather = load_weather_csv(args.weather_csv) if args.weather_csv else None
    base = load_params(args.coach_params) if args.coach_params else None
    env, params = scenarios.build(
        scenario, n_coaches=args.coaches, hours=args.hours, weather=weather, base_params=base
    )
    predictor = _predictor(args) if args.controller == "ddpc" else None
    controllers = build_controllers(args.controller, env.n_coaches, predictor)
    sim = FleetSimulator(
        params, env, seed=scenario.seed, record_flows=record_flows or args.out is not None
    )
    forecast = "perfect" if args.controller == "edge" else args.forecast
    loop = ClosedLoop(sim, controllers, forecast=forecast, seed=scenario.seed)
    with _progress(sim.n_steps, f"simulate {scenario.name} ({args.controller})") as bar:
        while sim.k < sim.n_steps:
            before = sim.k
            sim.run(loop, steps=360)
            bar.update(sim.k - before)
    ticks = tick_summary(loop.log) if args.controller != "rule" else None
    return scenario, sim.result(), ticks


def _predictor(args: argparse.Namespace):
    """``--predictor FILE`` or the cached default model (fitted once on the default dataset)."""
    from trainclimate.predict.artifact import load_predictor

    if getattr(args, "predictor", None):
        return load_predictor(args.predictor)
    from trainclimate.predict.default import default_predictor

    return default_predictor()


def cmd_simulate(args: argparse.Namespace) -> None:
    from trainclimate.analysis.summary import fleet_kpis

    if args.coaches < 1:
        raise UsageError("--coaches must be at least 1")
    if args.hours is not None and not (np.isfinite(args.hours) and args.hours > 0):
        raise UsageError("--hours must be positive")
    out = _out_file(args.out, "the simulation's Parquet file")
    scenario, result, ticks = run_simulation(args)
    data = {"scenario": scenario.name, "controller": args.controller, **fleet_kpis(result)}
    if ticks is not None:
        data["controller_ticks"] = ticks
    if out is not None:
        frames = []
        for c in range(len(data["coaches"])):
            frame = result.frame(c)
            frame.insert(0, "coach", c)
            frames.append(frame)
        pd.concat(frames).to_parquet(out)
        data["out"] = str(out)

    def human(d: dict) -> str:
        return (
            f"{d['scenario']} ({d['controller']}, {len(d['coaches'])} coach(es), "
            f"{d['hours']:.1f} h): {d['energy_kwh']:.1f} kWh per coach, "
            f"mean {d['mean_power_kw']:.2f} kW, avg hourly violation "
            f"{d['avg_hourly_violation_k']:.4f} K, discomfort {d['discomfort_kh']:.3f} K·h"
            + (f"\ntime series: {d['out']}" if "out" in d else "")
        )

    _emit(args, data, human)


def _bench_simulator_text(d: dict) -> str:
    return (
        f"simulator: {d['coach_days_per_s']:.1f} coach-days/s for {d['coaches']} coaches × "
        f"{d['days']:g} day(s) at dt = {d['dt_s']:g} s; per-coach loop "
        f"{d['loop_coach_days_per_s']:.2f} coach-days/s; speed-up {d['speedup_vs_loop']:.0f}×"
    )


def _bench_pipeline_text(d: dict) -> str:
    return (
        f"pipeline: {d['rows_per_s']:,.0f} raw rows/s "
        f"({d['runs'][-1]['ratio_to_parse_only']:.2f}× plain CSV parsing); peak memory "
        f"{d['runs'][0]['peak_rss_mb']:.0f} MB → {d['peak_rss_mb']:.0f} MB for "
        f"{d['size_ratio']:.0f}× the data; "
        f"fleet-year at 1 min ≈ {d['fleet_year_1min_hours_estimate']:.1f} h"
    )


def _bench_predictor_text(d: dict) -> str:
    return "\n".join(
        f"{r['mode']:>9} ×{r['scale']:<4} {r['columns']:>10,} columns "
        f"{r['seconds']:8.1f} s  peak {r['peak_rss_mb']:7.0f} MB "
        f"(+{r['peak_rss_mb'] - r['rss_before_fit_mb']:.0f} MB for the fit)"
        for r in d["runs"]
    )


def _bench_controller_text(d: dict) -> str:
    return (
        f"OCP solve (ρ = {d['rho']}, T = {d['horizon']}), median: fast "
        f"{d['fast_median_ms']:.3f} ms (p99 {d['fast_p99_ms']:.3f}), cvxpy DPP "
        f"{d['cvxpy_dpp_median_ms']:.1f} ms, cvxpy rebuilt {d['cvxpy_naive_median_ms']:.1f} ms "
        f"({d['naive_over_fast']:.0f}× the fast path)\n"
        f"whole controller step {d['controller_step_median_ms']:.3f} ms median; "
        f"fleet tick of 1000 coaches {d['fleet_1000_tick_s']:.2f} s"
    )


def _bench_service_text(d: dict) -> str:
    i, c, t = d["ingest"], d["comparison"], d["fleet_tick"]
    large, small = c["large"], c["small"]
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(t["reasons"].items()))
    return (
        f"ingest into PostgreSQL: HTTP API {i['http_rows_per_s']:,.0f} rows/s "
        f"({i['http_vs_plain']:.2f}× a plain INSERT), commands.ingest "
        f"{i['direct_rows_per_s']:,.0f} rows/s ({i['direct_vs_plain']:.2f}×), plain INSERT "
        f"{i['plain_insert_rows_per_s']:,.0f} rows/s; COPY {c['copy']['rows_per_s']:,.0f} rows/s\n"
        f"24-h comparison with {large['rows_stored'] / 1e6:.2f} M rows stored "
        f"({large['table']['total_mb']:,.0f} MB): median {large['median_ms']:.1f} ms, "
        f"p95 {large['p95_ms']:.1f} ms, p99 {large['p99_ms']:.1f} ms; with 1 pair × 1 day: "
        f"median {small['median_ms']:.1f} ms, p95 {small['p95_ms']:.1f} ms "
        f"(p95 ratio {c['p95_large_vs_small']:.2f}×)\n"
        f"fleet tick of {t['coaches']} coaches with the database: {t['tick_s']:.2f} s "
        f"(target {t['target_s']:g} s); the decisions alone {t['controller_steps_s']:.2f} s "
        f"({t['tick_vs_steps']:.0f}×); reasons: {reasons}"
    )


def cmd_bench(args: argparse.Namespace) -> None:
    from trainclimate import bench

    if args.target == "simulator":
        if args.coaches < 1 or args.days <= 0:
            raise UsageError("--coaches must be ≥ 1 and --days positive")
        data = bench.bench_simulator(args.coaches, args.days, args.loop_coaches)
        _emit(args, data, _bench_simulator_text)
    elif args.target == "pipeline":
        _emit(args, bench.bench_pipeline(), _bench_pipeline_text)
    elif args.target == "predictor":
        try:
            scales = tuple(int(x) for x in args.scales.split(","))
        except ValueError:
            raise UsageError("--scales takes integers separated by commas, e.g. 1,10,100") from None
        with _progress(len(scales) + 1, "predictor fits", "fit") as bar:
            data = bench.bench_predictor(scales, args.data, progress=bar.update)
        _emit(args, data, _bench_predictor_text)
    elif args.target == "service":
        with _progress(4, "service benchmark", "stage") as bar:
            try:
                data = bench.bench_service(args.db, progress=bar.update)
            except bench.ServiceBenchError as exc:
                raise UsageError(str(exc)) from None
        _emit(args, data, _bench_service_text)
    else:
        _emit(args, bench.bench_controller(), _bench_controller_text)


def cmd_dataset_build(args: argparse.Namespace) -> None:
    from trainclimate.data import fleetlogs, pipeline

    if (args.days is not None and args.days < 1) or (args.coaches is not None and args.coaches < 1):
        raise UsageError("--days and --coaches must be at least 1")
    out = _out_dir(args.out, "the dataset")
    generated = None
    if args.raw:
        raw = Path(args.raw)
        if not raw.is_dir():
            raise UsageError(f"--raw: no such directory: {raw}")
    else:
        raw = out / "raw"
        campaigns = tuple(fleetlogs.CAMPAIGNS[c] for c in args.campaign or fleetlogs.CAMPAIGNS)
        total = sum(
            len(c.days[: args.days] if args.days else c.days)
            * min(len(c.coaches), args.coaches or len(c.coaches))
            for c in campaigns
        )
        with _progress(total, "generate raw logs", "coach-day") as bar:
            generated = fleetlogs.generate(
                raw,
                campaigns=campaigns,
                max_days=args.days,
                max_coaches=args.coaches,
                progress=bar.update,
            )
    groups, _ = pipeline.discover(raw)
    with _progress(len(groups), "pipeline", "coach-day") as bar:
        summary = pipeline.build_dataset(
            raw,
            out,
            progress=bar.update,
            expected_unreadable=generated.corrupted if generated else (),
        )
    data = {**summary.to_dict(), "raw": str(raw), "out": str(out)}
    if generated is not None:
        data["generated"] = {
            "files": generated.files,
            "rows": generated.rows,
            "coach_days": generated.coach_days,
        }

    def human(d: dict) -> str:
        lines = [f"{'campaign':<15}{'sampling':>9}{'#T':>7}{'#D':>8}"]
        lines += [
            f"{r['campaign']:<15}{r['sampling_min']:>6} min{r['trajectories']:>7}"
            f"{r['mean_points']:>8.0f}"
            for r in d["table"]
        ]
        lines.append("dropped: " + ", ".join(f"{k} {v}" for k, v in d["dropped_rows"].items()))
        lines.append("repaired: " + ", ".join(f"{k} {v}" for k, v in d["repaired_rows"].items()))
        others = len(d["unreadable_files"]) - d["unreadable_as_generated"]
        if d["unreadable_as_generated"]:
            lines.append(f"corrupted files skipped, as generated: {d['unreadable_as_generated']}")
        if others:
            lines.append(f"unreadable files: {others} (see warnings)")
        lines.append(f"trajectories written under {d['out']}")
        return "\n".join(lines)

    _emit(args, data, human)


def _given_dataset(value: str, flag: str) -> Path:
    """A dataset directory named on the command line (usage error if it holds none)."""
    path = Path(value)
    if not (path / "dataset.json").exists() and not any(path.glob("trajectories_*min.parquet")):
        raise UsageError(f"{flag}: {path} holds no dataset (run `trainclimate dataset build`)")
    return path


def _dataset_dir(args: argparse.Namespace) -> Path:
    """``--data DIR`` or the default dataset (built once, with a progress bar)."""
    if args.data:
        return _given_dataset(args.data, "--data")
    from trainclimate.data.cache import default_dataset

    bars: dict[str, object] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in bars:
            for bar in bars.values():
                bar.close()
            bars[stage] = _progress(total, f"default dataset: {stage}", "coach-day")
        bar = bars[stage]
        bar.update(done - bar.n)

    try:
        return default_dataset(progress)
    finally:
        for bar in bars.values():
            bar.close()


def _check_predictor_args(args: argparse.Namespace) -> None:
    if args.rho < 1 or args.horizon < 1:
        raise UsageError("--rho and --horizon must be at least 1")
    if args.sampling_min not in (1, 5, 10):
        raise UsageError("--sampling-min must be 1, 5 or 10 (the dataset's sampling times)")


def _mae_human(d: dict) -> str:
    steps = " ".join(f"{m:.3f}" for m in d["mae_per_step_c"])
    return (
        f"{d['method']} predictor, {d['sampling_min']} min, ρ = {d['rho']}, T = {d['horizon']}: "
        f"MAE per step (K, mean over decks) {steps}; mean {d['mae_mean_c']:.4f} K on "
        f"{', '.join(d['validation_coaches'])} ({d['validation_windows']} windows)"
    )


def cmd_predictor_evaluate(args: argparse.Namespace) -> None:
    from trainclimate.predict.evaluate import evaluate, load_split

    _check_predictor_args(args)
    split = None
    if args.train_data:  # fitted on another dataset's training coaches, measured on this one's
        train, _ = load_split(_given_dataset(args.train_data, "--train-data"), args.sampling_min)
        _, validation = load_split(_dataset_dir(args), args.sampling_min)
        split = (train, validation)
    _, data = evaluate(
        args.method, args.sampling_min, args.rho, args.horizon, _dataset_dir(args), split
    )
    _emit(args, data, _mae_human)


def cmd_predictor_fit(args: argparse.Namespace) -> None:
    from trainclimate.predict.artifact import save_predictor
    from trainclimate.predict.evaluate import evaluate

    _check_predictor_args(args)
    _out_file(args.out, "the model file")
    predictor, result = evaluate(
        args.method, args.sampling_min, args.rho, args.horizon, _dataset_dir(args)
    )
    path = save_predictor(predictor, args.out, validation=result)
    data = {**result, "out": str(path)}
    _emit(args, data, lambda d: _mae_human(d) + f"\nmodel written: {d['out']}")


def cmd_predictor_default(args: argparse.Namespace) -> None:
    from trainclimate.predict import default as models

    path = models.quick_model_path() if args.quick else models.default_model_path()
    built = not path.exists()
    bars: dict[str, object] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in bars:
            bars[stage] = _progress(total, f"{stage} ({'quick' if args.quick else 'default'})")
        bars[stage].update(done - bars[stage].n)

    predictor = (models.quick_predictor if args.quick else models.default_predictor)(
        progress=progress
    )
    for bar in bars.values():
        bar.close()
    data = {
        "model": "quick" if args.quick else "default",
        "path": str(path),
        "built": built,
        "trajectories": predictor.n_trajectories,
        "hankel_columns": predictor.n_columns,
    }
    _emit(args, data, lambda d: f"{d['model']} model {'built' if built else 'cached'}: {d['path']}")


def cmd_predictor_study(args: argparse.Namespace) -> None:
    from trainclimate.predict import study

    _out_file(args.html, "the HTML report")
    data_dir = _dataset_dir(args)
    with _progress(study.n_runs(), "sensitivity studies", "fit") as bar:
        results = study.run_studies(data_dir, progress=bar.update)
    data = {"studies": results, "summary": study.summary_rows(results)}
    if args.html:
        data["html"] = str(study.write_report(results, args.html).resolve())

    def human(d: dict) -> str:
        lines = [f"{'study':<9}{'S':>4}{'ρ':>4}{'T':>4}" + "".join(f"{m:>17}" for m in METHODS)]
        for r in d["summary"]:
            lines.append(
                f"{r['study']:<9}{r['sampling_min']:>4}{r['rho']:>4}{r['horizon']:>4}"
                + "".join(f"{r[f'{m}_mean_mae_c']:>17.4f}" for m in METHODS)
                + f"  best: {r['best']}"
            )
        if "html" in d:
            lines.append(f"report written: {d['html']}")
        return "\n".join(lines)

    _emit(args, data, human)


def _experiment_text(d: dict) -> str:
    def pct(v):
        return "–" if v is None else f"{v:.2f} %"

    return (
        f"{d['scenario']}: savings {pct(d['savings_pct'])} (band-edge reference "
        f"{pct(d['edge_savings_pct'])}), average hourly violation "
        f"{d['avg_hourly_violation_k']:.4f} K (deactivated coach {d['baseline_violation_k']:.4f} K)"
        f", {d['excluded_minutes']:.0f} min excluded, counted from {d['counted_from']}"
        + (f"\nreport written: {d['html']}" if "html" in d else "")
    )


def cmd_experiment_run(args: argparse.Namespace) -> None:
    from trainclimate.analysis.experiment import run_pair
    from trainclimate.analysis.report import write_experiment_report
    from trainclimate.sim import scenarios

    scenarios.get(args.scenario)  # an unknown name is a usage error before any work
    if args.hours is not None and not (np.isfinite(args.hours) and args.hours > 0):
        raise UsageError("--hours must be positive")
    if not 0 <= args.coach_spread < 1:
        raise UsageError("--coach-spread must lie in [0, 1)")
    _out_file(args.html, "the HTML report")
    pair = run_pair(
        args.scenario,
        _predictor(args),
        hours=args.hours,
        forecast=args.forecast,
        coach_spread=args.coach_spread,
    )
    data = pair.to_dict()
    if args.html:
        data["html"] = str(write_experiment_report(pair, args.html).resolve())
    _emit(args, data, _experiment_text)


def cmd_experiment_summary(args: argparse.Namespace) -> None:
    from trainclimate.analysis.experiment import EXPERIMENTS, run_pair
    from trainclimate.analysis.report import write_experiment_report, write_summary

    out = _out_dir(args.out, "the experiment reports")
    predictor = _predictor(args)
    rows = []
    with _progress(len(EXPERIMENTS), "paired experiments", "experiment") as bar:
        for name in EXPERIMENTS:
            pair = run_pair(name, predictor, forecast=args.forecast)
            row = pair.to_dict()
            row["html"] = str(write_experiment_report(pair, out / f"{name}.html"))
            rows.append(row)
            bar.update(1)
    files = write_summary(rows, out)
    data = {"experiments": rows, **{k: str(v) for k, v in files.items()}}

    def human(d: dict) -> str:
        return "\n".join(_experiment_text(r).splitlines()[0] for r in d["experiments"]) + (
            f"\nsummary written: {d['markdown']} and {d['html']}"
        )

    _emit(args, data, human)


def _db_url(args: argparse.Namespace) -> str:
    from trainclimate.service.settings import default_database_url

    return args.db or os.environ.get("TRAINCLIMATE_DATABASE_URL") or default_database_url()


def cmd_serve(args: argparse.Namespace) -> None:
    import uvicorn
    from sqlalchemy.exc import OperationalError

    from trainclimate.service.app import create_app
    from trainclimate.service.db import migrate
    from trainclimate.service.settings import Settings

    if not (np.isfinite(args.speedup) and args.speedup > 0):
        raise UsageError("--speedup must be positive")
    settings = Settings(
        database_url=_db_url(args),
        fleet=args.fleet,
        speedup=args.speedup,
        predictor_path=args.predictor,
    )
    url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '::') else args.host}:{args.port}/"
    try:  # a database that cannot be reached is a one-line error, not a traceback
        migrate(settings.database_url)
    except OperationalError as exc:
        first = str(exc.orig).strip().splitlines()[0] if exc.orig else type(exc).__name__
        raise UsageError(f"cannot use the database: {first}") from None
    lines = [f"trainclimate: serving on {url} (database {settings.database_url.split('://')[0]})"]
    out = []
    if args.new_token:
        token = _create_token(settings.database_url, args.new_token, f"demo-{args.new_token}")
        out = [f"dashboard: {url}", f"{args.new_token} token: {token['token']}"]
    app = create_app(settings)
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level=args.log_level)
    server = uvicorn.Server(config)
    threading.Thread(
        target=_announce, args=(server, lines, out), name="announce", daemon=True
    ).start()
    server.run()


def _announce(server, stderr_lines: list[str], stdout_lines: list[str]) -> None:
    """Print the URL (and token) once the server accepts connections."""
    while not server.started:
        if server.should_exit:
            return
        time.sleep(0.05)
    print("\n".join(stderr_lines), file=sys.stderr, flush=True)
    if stdout_lines:
        print("\n".join(stdout_lines), flush=True)


def _create_token(url: str, role: str, name: str | None) -> dict:
    """A new token in the migrated database ``url``: {token, name, role}."""
    from trainclimate.service.db import Database
    from trainclimate.service.security import create_token

    db = Database(url)
    try:
        with db.transaction() as session:
            token, user = create_token(session, role, name)
            return {"token": token, "name": user.name, "role": user.role}
    finally:
        db.dispose()


def cmd_token_create(args: argparse.Namespace) -> None:
    from trainclimate.service.db import migrate

    url = _db_url(args)
    migrate(url)
    data = _create_token(url, args.role, args.name)
    out = _out_file(args.out, "the token file")
    if out is not None:  # for another process to read (the compose demo's gateways): owner-only
        out.touch(mode=0o600)
        out.write_text(data["token"] + "\n")
        data = {**data, "token": None, "file": str(out)}
        _emit(args, data, lambda d: f"token written to {d['file']}")
        return
    _emit(args, data, lambda d: d["token"])


def cmd_gateway(args: argparse.Namespace) -> None:
    import httpx

    from trainclimate.service.gateway import Gateway
    from trainclimate.sim import scenarios

    scenarios.get(args.scenario)
    coaches = [c for c in args.coaches.split(",") if c]
    if not coaches:
        raise UsageError("--coaches needs at least one coach id")
    active = [c for c in (args.active or coaches[0]).split(",") if c]
    if not set(active) <= set(coaches):
        raise UsageError("--active must name coaches of --coaches")
    token = args.token or os.environ.get("TRAINCLIMATE_TOKEN")
    if args.token_file:
        try:
            token = Path(args.token_file).read_text().strip()
        except OSError as exc:
            raise UsageError(f"--token-file: {exc.strerror}: {args.token_file}") from None
    if not token:
        raise UsageError(
            "--token, --token-file or TRAINCLIMATE_TOKEN is required: an operator token"
        )
    gateway = Gateway(
        args.server,
        token,
        coaches,
        train_id=args.train or coaches[0].split("-")[0],
        active=active,
        scenario=args.scenario,
        speedup=args.speedup,
        hours=args.hours,
    )
    try:
        stats = gateway.run()
    except httpx.HTTPStatusError as exc:  # a refusal: a bad token, a coach of another train
        reply = exc.response
        try:
            detail = reply.json()["detail"]
        except (ValueError, KeyError, TypeError):
            detail = reply.reason_phrase
        raise UsageError(f"the server refused the gateway: {reply.status_code} {detail}") from None
    _emit(args, dataclasses.asdict(stats), lambda d: json.dumps(d))


def cmd_demo(args: argparse.Namespace) -> None:
    from trainclimate.analysis.report import write_simulation_report
    from trainclimate.analysis.summary import fleet_kpis

    out = _out_dir(args.out, "the demo report")
    results = {}
    for controller in CONTROLLERS:
        ns = argparse.Namespace(
            scenario="winter-day",
            controller=controller,
            coaches=args.coaches,
            hours=None,
            weather_csv=None,
            coach_params=None,
            out=None,
            predictor=None,
            forecast="perfect",
        )
        scenario, results[controller], _ = run_simulation(ns, record_flows=True)
    path = write_simulation_report(results, scenario, out / "winter-day.html")
    data = {
        "report": str(path.resolve()),
        "scenario": scenario.name,
        "controllers": {
            c: {k: v for k, v in fleet_kpis(r).items() if k != "coaches"}
            for c, r in results.items()
        },
    }
    _emit(args, data, lambda d: f"report written: {d['report']}")


# --- parser ----------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="trainclimate", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    def add(name: str, func, help_: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_, description=help_)
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
        p.set_defaults(func=func)
        return p

    add("scenarios", cmd_scenarios, "list the named scenarios")

    p = add("simulate", cmd_simulate, "simulate a scenario and print its KPIs")
    p.add_argument("--scenario", required=True, help="scenario name (see `scenarios`)")
    p.add_argument("--controller", choices=CONTROLLERS, default="rule")
    p.add_argument("--hours", type=float, default=None, help="duration (default: scenario's)")
    p.add_argument("--coaches", type=int, default=1, help="number of coaches (default 1)")
    p.add_argument("--weather-csv", default=None, help="measured weather (time,t_amb_c,ghi_w_m2)")
    p.add_argument("--coach-params", default=None, help="coach parameter JSON file")
    p.add_argument("--out", default=None, help="write the full time series (Parquet)")
    p.add_argument("--predictor", default=None, help="ddpc: model file (default: cached model)")
    p.add_argument(
        "--forecast",
        choices=("perfect", "persistence", "noisy"),
        default="perfect",
        help="ddpc: disturbance forecast (default perfect)",
    )

    p = add("coach-params", cmd_coach_params, "print coach parameters (the file format)")
    p.add_argument("--default", action="store_true", help="the default parameters")
    p.add_argument("--file", default=None, help="validate and print a parameter file")

    p = add("bench", cmd_bench, "run a benchmark")
    p.add_argument(
        "target", choices=("simulator", "pipeline", "predictor", "controller", "service")
    )
    p.add_argument("--scales", default="1,10,100", help="predictor: column multiples to fit")
    p.add_argument("--data", default=None, help="predictor: dataset directory")
    p.add_argument(
        "--db",
        default=None,
        help="service: an empty PostgreSQL database (default: a new one on the server "
        "$TRAINCLIMATE_TEST_PG_URL names, else 127.0.0.1:5432, dropped at the end)",
    )
    p.add_argument("--coaches", type=int, default=100)
    p.add_argument("--days", type=float, default=1.0)
    p.add_argument(
        "--loop-coaches", type=int, default=5, help="coaches simulated one by one for the baseline"
    )

    dataset = sub.add_parser("dataset", help="fleet logs and the data pipeline")
    dsub = dataset.add_subparsers(dest="dataset_command", required=True, parser_class=_Parser)
    p = dsub.add_parser(
        "build",
        help="generate raw fleet logs (or read --raw) and run the pipeline",
        description="generate raw fleet logs (or read --raw) and run the pipeline",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=cmd_dataset_build)
    p.add_argument("--out", required=True, help="output directory (trajectories, dataset.json)")
    p.add_argument("--raw", default=None, help="read raw logs from here instead of generating")
    p.add_argument("--days", type=int, default=None, help="only the first N days per campaign")
    p.add_argument("--coaches", type=int, default=None, help="only the first N coaches")
    p.add_argument(
        "--campaign", action="append", choices=("winter-spring", "summer"), help="repeatable"
    )

    predictor = sub.add_parser("predictor", help="fit and evaluate the prediction models")
    psub = predictor.add_subparsers(dest="predictor_command", required=True, parser_class=_Parser)

    def add_predictor(name: str, func, help_: str, setting: bool = True) -> argparse.ArgumentParser:
        p = psub.add_parser(name, help=help_, description=help_)
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
        p.add_argument("--data", default=None, help="dataset directory (default: built once)")
        p.set_defaults(func=func)
        if setting:
            p.add_argument(
                "--method", choices=("transient", "subspace", "arx"), default="transient"
            )
            p.add_argument("--sampling-min", type=int, default=5, help="1, 5 or 10 (default 5)")
            p.add_argument("--rho", type=int, default=12, help="lead-in samples (default 12)")
            p.add_argument("--horizon", type=int, default=12, help="prediction steps (default 12)")
        return p

    p = add_predictor("evaluate", cmd_predictor_evaluate, "MAE per step on the held-out coaches")
    p.add_argument(
        "--train-data",
        default=None,
        help="fit on the training coaches of this dataset instead (measured on --data's "
        "held-out coaches), e.g. the quick dataset the service starts with",
    )
    p = add_predictor("fit", cmd_predictor_fit, "fit on the training coaches and save the model")
    p.add_argument("--out", required=True, help="model file to write (.npz)")
    p = add_predictor(
        "default",
        cmd_predictor_default,
        "build (once) and cache the model the controller and the service use by default",
        setting=False,
    )
    p.add_argument(
        "--quick", action="store_true", help="the quick model (a 4-day campaign, ≈ 1 min)"
    )
    p = add_predictor(
        "study", cmd_predictor_study, "the paper's three sensitivity studies", setting=False
    )
    p.add_argument("--html", default=None, help="write the report with Plotly figures here")

    experiment = sub.add_parser("experiment", help="paired experiments (activated vs deactivated)")
    esub = experiment.add_subparsers(dest="experiment_command", required=True, parser_class=_Parser)
    for name, func, help_ in (
        ("run", cmd_experiment_run, "run one scenario as a paired experiment"),
        ("summary", cmd_experiment_summary, "run every paired experiment and write the table"),
    ):
        p = esub.add_parser(name, help=help_, description=help_)
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
        p.set_defaults(func=func)
        p.add_argument("--predictor", default=None, help="model file (default: cached model)")
        p.add_argument(
            "--forecast",
            choices=("perfect", "persistence", "noisy"),
            default="perfect",
            help="disturbance forecast (default perfect)",
        )
        if name == "run":
            p.add_argument("--scenario", required=True, help="scenario name (see `scenarios`)")
            p.add_argument("--html", default=None, help="write the report (HTML, Plotly)")
            p.add_argument("--hours", type=float, default=None, help="duration (default: all)")
            p.add_argument(
                "--coach-spread",
                type=float,
                default=0.0,
                help="parameter spread of the deactivated coach (0: twins; e.g. 0.1)",
            )
        else:
            p.add_argument("--out", default="out/experiments", help="output directory")

    p = add("serve", cmd_serve, "run the service (API, dashboard, control loop)")
    p.add_argument(
        "--db",
        default=None,
        help="database URL (default: $TRAINCLIMATE_DATABASE_URL, then a SQLite file)",
    )
    p.add_argument("--fleet", choices=("demo",), default=None, help="add the simulated demo fleet")
    p.add_argument("--speedup", type=float, default=1.0, help="demo clock × real time")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--predictor", default=None, help="model file (default: the cached model)")
    p.add_argument("--log-level", default="warning")
    p.add_argument(
        "--new-token",
        choices=("viewer", "operator", "admin"),
        default=None,
        help="create a token with this role at start and print it with the dashboard's URL",
    )

    token = sub.add_parser("token", help="API tokens")
    tsub = token.add_subparsers(dest="token_command", required=True, parser_class=_Parser)
    p = tsub.add_parser("create", help="create a token (shown once)", description="create a token")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--role", required=True, choices=("viewer", "operator", "admin"))
    p.add_argument("--name", default=None, help="user name (default: generated)")
    p.add_argument("--db", default=None, help="database URL")
    p.add_argument("--out", default=None, help="write the token to this file (mode 600)")
    p.set_defaults(func=cmd_token_create)

    p = add("gateway", cmd_gateway, "an onboard gateway emulator speaking the HTTP live feed")
    p.add_argument("--server", required=True, help="the service's URL, e.g. http://127.0.0.1:8000")
    p.add_argument("--coaches", required=True, help="coach ids, comma-separated (one train)")
    p.add_argument("--active", default=None, help="coaches with the layer on (default: the first)")
    p.add_argument("--train", default=None, help="train id (default: the first coach's prefix)")
    p.add_argument("--token", default=None, help="an operator token (or $TRAINCLIMATE_TOKEN)")
    p.add_argument("--token-file", default=None, help="a file holding the operator token")
    p.add_argument("--scenario", default="parked-heating-nov", help="weather and operation")
    p.add_argument("--speedup", type=float, default=60.0, help="clock × real time")
    p.add_argument("--hours", type=float, default=None, help="how long (default: the scenario's)")

    p = add("demo", cmd_demo, "simulate winter-day and write an HTML report")
    p.add_argument("--out", default="out/demo", help="output directory")
    p.add_argument("--coaches", type=int, default=3)
    return parser


class _LogFormat(logging.Formatter):
    """``trainclimate: warning: …`` for warnings and errors, ``trainclimate: …`` for news."""

    def format(self, record: logging.LogRecord) -> str:
        warning = record.levelno >= logging.WARNING
        return ("trainclimate: warning: " if warning else "trainclimate: ") + super().format(record)


def main(argv: list[str] | None = None) -> int:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LogFormat())
    logging.basicConfig(level=logging.WARNING, handlers=[handler], force=True)
    logging.getLogger("trainclimate").setLevel(logging.INFO)
    try:
        args = build_parser().parse_args(argv)
        if args.command == "coach-params" and not (args.default or args.file):
            raise UsageError("coach-params needs --default or --file FILE")
        args.func(args)
    except (
        UsageError,
        ScenarioError,
        WeatherError,
        ParamsError,
        PipelineError,
        PredictorDataError,
        ArtifactError,
        StorageError,
    ) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"trainclimate: error: {message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
