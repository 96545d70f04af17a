"""``scenarios``, ``coach-params``, ``simulate`` and ``demo``: the simulator, from the shell."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pandas as pd

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    add_model_options,
    emit,
    json_default,
    objective_of,
    out_dir,
    out_file,
    predictor_from,
    progress_bar,
)
from trainclimate.control.simulate import CONTROLLERS
from trainclimate.sim.params import CoachParams, load_params
from trainclimate.sim.scenarios import SCENARIOS
from trainclimate.sim.simulator import SimulationError


def cmd_scenarios(args: argparse.Namespace) -> None:
    """``scenarios``: the named scenarios with their descriptions."""
    data = {
        "scenarios": [{"name": s.name, "description": s.description} for s in SCENARIOS.values()]
    }
    emit(
        args,
        data,
        lambda d: "\n".join(f"{s['name']:<34} {s['description']}" for s in d["scenarios"]),
    )


def cmd_coach_params(args: argparse.Namespace) -> None:
    """``coach-params``: the default coach parameters, or a parameter file validated."""
    params = load_params(args.file) if args.file else CoachParams()
    data = params.to_dict()

    def human(d: dict) -> str:
        return "\n".join(f"{k:<32} {v}" for k, v in d.items())

    emit(args, data, human)


def _run(args: argparse.Namespace, scenario: str, controller: str, record_flows: bool):
    """:func:`~trainclimate.control.simulate.run_simulation` with the command's inputs and a
    progress bar; a diverging simulation (:class:`SimulationError`) is a :class:`UsageError`
    (exit 2, its one line), as its cause is the parameters or the weather given."""
    from trainclimate.control.simulate import run_simulation
    from trainclimate.sim import scenarios
    from trainclimate.sim.weather import load_weather_csv

    scenarios.get(scenario)  # an unknown name is a usage error before any work
    csv = getattr(args, "weather_csv", None)
    params = getattr(args, "coach_params", None)
    with progress_bar(0, f"simulate {scenario} ({controller})") as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        try:
            return run_simulation(
                scenario,
                controller,
                coaches=args.coaches,
                hours=getattr(args, "hours", None),
                weather=load_weather_csv(csv) if csv else None,
                base_params=load_params(params) if params else None,
                predictor=predictor_from(args) if controller == "ddpc" else None,
                forecast=getattr(args, "forecast", "perfect"),
                objective=objective_of(args),
                record_flows=record_flows,
                progress=progress,
            )
        except SimulationError as exc:
            raise UsageError(str(exc)) from exc


def _check_finite(data: dict) -> None:
    """Refuse KPIs that JSON cannot hold (NaN, ±inf) rather than print ``NaN``.

    Raises
    ------
    UsageError
        If a number in ``data`` is not finite (exit 2, one line).
    """
    try:
        json.dumps(data, default=json_default, allow_nan=False)
    except ValueError as exc:
        raise UsageError(
            f"the simulation's KPIs are not finite ({exc}); check the coach parameters and weather"
        ) from exc


def cmd_simulate(args: argparse.Namespace) -> None:
    """``simulate``: a scenario under one controller; its KPIs, optionally the time series."""
    from trainclimate.analysis.summary import fleet_kpis

    if args.coaches < 1:
        raise UsageError("--coaches must be at least 1")
    if args.hours is not None and not (np.isfinite(args.hours) and args.hours > 0):
        raise UsageError("--hours must be positive")
    out = out_file(args.out, "the simulation's Parquet file")
    run = _run(args, args.scenario, args.controller, record_flows=out is not None)
    data = {"scenario": run.scenario.name, "controller": args.controller, **fleet_kpis(run.result)}
    if run.ticks is not None:
        data["controller_ticks"] = run.ticks
    _check_finite(data)
    if out is not None:
        frames = []
        for c in range(len(data["coaches"])):
            frame = run.result.frame(c)
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

    emit(args, data, human)


def cmd_demo(args: argparse.Namespace) -> None:
    """``demo``: ``winter-day`` under the three controllers, as one HTML report."""
    from trainclimate.analysis.report import write_simulation_report
    from trainclimate.analysis.summary import fleet_kpis

    out = out_dir(args.out, "the demo report")
    runs = {c: _run(args, "winter-day", c, record_flows=True) for c in CONTROLLERS}
    results = {c: run.result for c, run in runs.items()}
    scenario = runs["rule"].scenario
    path = write_simulation_report(results, scenario, out / "winter-day.html")
    data = {
        "report": str(path.resolve()),
        "scenario": scenario.name,
        "controllers": {
            c: {k: v for k, v in fleet_kpis(r).items() if k != "coaches"}
            for c, r in results.items()
        },
    }
    emit(args, data, lambda d: f"report written: {d['report']}")


def register(sub) -> None:
    """Add ``scenarios``, ``simulate``, ``coach-params`` and ``demo`` to ``sub``."""
    add_command(sub, "scenarios", cmd_scenarios, "list the named scenarios")

    p = add_command(sub, "simulate", cmd_simulate, "simulate a scenario and print its KPIs")
    p.add_argument("--scenario", required=True, help="scenario name (see `scenarios`)")
    p.add_argument("--controller", choices=CONTROLLERS, default="rule")
    p.add_argument("--hours", type=float, default=None, help="duration (default: scenario's)")
    p.add_argument("--coaches", type=int, default=1, help="number of coaches (default 1)")
    p.add_argument("--weather-csv", default=None, help="measured weather (time,t_amb_c,ghi_w_m2)")
    p.add_argument("--coach-params", default=None, help="coach parameter JSON file")
    p.add_argument("--out", default=None, help="write the full time series (Parquet)")
    add_model_options(p, "ddpc: ")

    p = add_command(
        sub, "coach-params", cmd_coach_params, "print coach parameters (the file format)"
    )
    p.add_argument("--default", action="store_true", help="the default parameters")
    p.add_argument("--file", default=None, help="validate and print a parameter file")

    rsub = add_group(sub, "report", "HTML reports")
    p = add_command(
        rsub,
        "demo",
        cmd_demo,
        "simulate winter-day three ways (rule, DDPC, band edge) and write an HTML report "
        "(the dashboard's demo is `make demo`)",
    )
    p.add_argument("--out", default="out/demo", help="output directory")
    p.add_argument("--coaches", type=int, default=3)
    p.add_argument("--hours", type=float, default=None, help="how long (default: the day)")
    add_model_options(p, "ddpc: ")
