"""``experiment run|summary``: paired experiments, activated against deactivated coaches."""

from __future__ import annotations

import argparse

import numpy as np

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    add_model_options,
    emit,
    out_dir,
    out_file,
    predictor_from,
    progress_bar,
)


def _experiment_text(d: dict) -> str:
    def pct(v):
        return "–" if v is None else f"{v:.2f} %"

    return (
        f"{d['scenario']}: savings {pct(d['savings_pct'])} on the {d['meter']} meter, "
        f"{pct(d['savings_by_meter_pct']['hvac_and_floor'])} with the floor heating (band-edge "
        "reference "
        f"{pct(d['edge_savings_pct'])}), average hourly violation "
        f"{d['avg_hourly_violation_k']:.4f} K (deactivated coach {d['baseline_violation_k']:.4f} K)"
        f", {d['excluded_minutes']:.0f} min excluded, counted from {d['counted_from']}"
        + (f"\nreport written: {d['html']}" if "html" in d else "")
    )


def _coach_params(args: argparse.Namespace):
    """``--coach-params FILE`` read and checked (None: each scenario's own coach)."""
    from trainclimate.sim.params import load_params

    return load_params(args.coach_params) if args.coach_params else None


def cmd_experiment_run(args: argparse.Namespace) -> None:
    """``experiment run``: one scenario as a paired experiment (savings, violations)."""
    from trainclimate.analysis.experiment import run_pair
    from trainclimate.analysis.report import write_experiment_report
    from trainclimate.sim import scenarios

    scenarios.get(args.scenario)  # an unknown name is a usage error before any work
    if args.hours is not None and not (np.isfinite(args.hours) and args.hours > 0):
        raise UsageError("--hours must be positive")
    if not 0 <= args.coach_spread < 1:
        raise UsageError("--coach-spread must lie in [0, 1)")
    out_file(args.html, "the HTML report")
    pair = run_pair(
        args.scenario,
        predictor_from(args),
        hours=args.hours,
        forecast=args.forecast,
        coach_spread=args.coach_spread,
        base_params=_coach_params(args),
    )
    data = pair.to_dict()
    if args.html:
        data["html"] = str(write_experiment_report(pair, args.html).resolve())
    emit(args, data, _experiment_text)


def cmd_experiment_ablation(args: argparse.Namespace) -> None:
    """``experiment summary --ablation``: Table II with one column per condition of the paper's
    text, added in order."""
    from trainclimate.analysis.ablation import STEPS, run_ablation, write_ablation
    from trainclimate.analysis.experiment import EXPERIMENTS

    out = out_dir(args.out, "the ablation table")
    base = _coach_params(args)
    predictor = predictor_from(args)
    with progress_bar(len(EXPERIMENTS), "ablation", "experiment") as bar:
        rows = run_ablation(
            predictor, forecast=args.forecast, base_params=base, progress=lambda _: bar.update(1)
        )
    data = {"steps": list(STEPS), "experiments": rows, "markdown": str(write_ablation(rows, out))}

    def human(d: dict) -> str:
        lines = [
            f"{r['scenario']}: "
            + ", ".join(
                f"{STEPS[k]} " + ("–" if s["savings_pct"] is None else f"{s['savings_pct']:.2f} %")
                for k, s in r["steps"].items()
            )
            for r in d["experiments"]
        ]
        return "\n".join(lines) + f"\nablation written: {d['markdown']}"

    emit(args, data, human)


def cmd_experiment_summary(args: argparse.Namespace) -> None:
    """``experiment summary``: every paired experiment, the table and the reports."""
    from trainclimate.analysis.experiment import EXPERIMENTS, run_pair
    from trainclimate.analysis.report import write_experiment_report, write_summary

    if args.ablation:
        return cmd_experiment_ablation(args)
    out = out_dir(args.out, "the experiment reports")
    base = _coach_params(args)
    predictor = predictor_from(args)
    rows = []
    with progress_bar(len(EXPERIMENTS), "paired experiments", "experiment") as bar:
        for name in EXPERIMENTS:
            pair = run_pair(name, predictor, forecast=args.forecast, base_params=base)
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

    emit(args, data, human)


def register(sub) -> None:
    """Add ``experiment run|summary`` to ``sub``."""
    esub = add_group(sub, "experiment", "paired experiments (activated vs deactivated)")
    for name, func, help_ in (
        ("run", cmd_experiment_run, "run one scenario as a paired experiment"),
        ("summary", cmd_experiment_summary, "run every paired experiment and write the table"),
    ):
        p = add_command(esub, name, func, help_)
        add_model_options(p)
        p.add_argument(
            "--coach-params",
            default=None,
            help="coach parameter file (coach-params, calibrate --out) for the coaches of every "
            "experiment (default: the scenario's)",
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
            p.add_argument(
                "--ablation",
                action="store_true",
                help="Table II step by step: as before, on the HVAC meter, with the October "
                "conditions, the field events, the sensors' violation (writes ablation.md)",
            )
