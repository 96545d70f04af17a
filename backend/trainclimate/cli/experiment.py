"""``experiment run|trial|summary``: paired experiments, activated against deactivated coaches,
and simulated trials beside their truth."""

from __future__ import annotations

import argparse
import functools

import numpy as np

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    add_model_options,
    emit,
    objective_of,
    out_dir,
    out_file,
    predictor_from,
    progress_bar,
    warn,
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


def _twin_warnings(args: argparse.Namespace, t_amb_of: dict) -> list[str]:
    """The warnings of the twin in ``--coach-params`` (none without one): its savings' when its
    calibration did not validate its response to setpoint changes, then each run ``what`` in
    ``t_amb_of`` ({what: a function giving its ambient temperatures, °C}) whose weather leaves
    the twin's validated ambient range."""
    from trainclimate.twin import validity

    record = validity.record_of_file(args.coach_params)
    validated = validity.validated_range(record, f"coach parameter file {args.coach_params}")
    found = [validity.savings_warning(record, f"--coach-params {args.coach_params}")]
    if validated is not None:
        found += [
            validity.range_warning(validated, t_amb(), what) for what, t_amb in t_amb_of.items()
        ]
    return [w for w in found if w]


def _scenario_warnings(args: argparse.Namespace, names: list[str], hours: float | None = None):
    """:func:`_twin_warnings` of the scenarios ``names`` (their first ``hours``)."""
    from trainclimate.twin import validity

    return _twin_warnings(
        args, {f"scenario {n}": functools.partial(validity.scenario_t_amb, n, hours) for n in names}
    )


def _trial_warnings(args: argparse.Namespace, seeds: range) -> list[str]:
    """:func:`_twin_warnings` of the trials of ``seeds``."""
    from trainclimate.analysis.trial_environment import trial_environment
    from trainclimate.sim import scenarios

    scenario = scenarios.get(args.scenario)
    return _twin_warnings(
        args,
        {
            f"the trial of {args.scenario}, seed {seed}": (
                lambda seed=seed: (
                    trial_environment(scenario, args.days, seed, args.switch_hour).t_amb_c
                )
            )
            for seed in seeds
        },
    )


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
    warnings = _scenario_warnings(args, [args.scenario], args.hours)
    pair = run_pair(
        args.scenario,
        predictor_from(args),
        hours=args.hours,
        forecast=args.forecast,
        coach_spread=args.coach_spread,
        base_params=_coach_params(args),
        objective=objective_of(args),
    )
    data = pair.to_dict()
    if args.html:
        data["html"] = str(write_experiment_report(pair, args.html).resolve())
    warn(data, warnings)
    emit(args, data, _experiment_text)


def _pct(v: float | None, fmt: str = ".2f", unit: str = " %") -> str:
    return "–" if v is None else f"{v:{fmt}}{unit}"


def _trial_text(d: dict) -> str:
    ci = d["savings_ci95_pct"]
    interval = (
        f"95 % interval [{ci[0]:.2f}, {ci[1]:.2f}] %, {d['days_to_target']} more days to ±2 points"
        if ci
        else f"no interval: {d['savings_ci95_reason']}"
    )
    coaches = ", ".join(_pct(v) for v in d["true_savings_by_coach_pct"])
    return (
        f"{d['scenario']}, {d['plan']} plan, {d['days_simulated']} days, seed {d['seed']}, "
        f"coach spread {d['coach_spread']:g}: estimate {_pct(d['savings_pct'])} "
        f"({d['estimator']}, days {d['days']['coach_0']} + {d['days']['coach_1']}), {interval}\n"
        f"truth {_pct(d['true_savings_pct'])} (coaches {coaches}): error "
        f"{_pct(d['error_pct'], '+.2f', ' points')}; naive {_pct(d['naive_savings_pct'])} "
        f"(error {_pct(d['naive_error_pct'], '+.2f', ' points')})"
    )


#: The columns of ``experiment trial --seeds``'s table: heading, summary key, format.
_TRIAL_COLUMNS = (
    ("coverage %", "coverage_pct", ".0f"),
    ("MAE", "mae_pct", ".2f"),
    ("bias", "mean_error_pct", "+.2f"),
    ("half-width", "mean_half_width_pct", ".2f"),
    ("days to target", "mean_days_to_target", ".1f"),
    ("naive MAE", "naive_mae_pct", ".2f"),
)


def _trials_text(d: dict) -> str:
    lines = [
        f"{d['scenario']}, {d['days']} days, seeds {d['seeds'][0]}–{d['seeds'][-1]}, coach spread "
        f"{d['coach_spread']:g}, forecast {d['forecast']} (percentage points but coverage)",
        f"{'plan':<11}" + "".join(f"  {h:>6}" for h, _, _ in _TRIAL_COLUMNS),
    ]
    for plan, s in d["summary"].items():
        cells = "".join(f"  {_pct(s[k], f, ''):>{max(6, len(h))}}" for h, k, f in _TRIAL_COLUMNS)
        lines.append(f"{plan:<11}{cells}")
    return "\n".join(lines)


def cmd_experiment_trial(args: argparse.Namespace) -> None:
    """``experiment trial``: a trial of a pair of coaches over days, beside the counterfactual
    truth; with ``--seeds N`` or several plans, the runs and how each plan fared."""
    from trainclimate.analysis.trial_runs import summarize
    from trainclimate.analysis.trial_sim import check_trial, simulate_seeds
    from trainclimate.sim import scenarios

    scenarios.get(args.scenario)  # an unknown name is a usage error before any work
    plans = tuple(p.strip() for p in args.plan.split(","))
    try:
        check_trial(args.days, plans, args.coach_spread, args.switch_hour, args.lead_in_min)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if min(args.seeds, args.batch, args.workers) < 1:
        raise UsageError("--seeds, --batch and --workers must be at least 1")
    base = _coach_params(args)
    predictor = predictor_from(args)
    seeds = range(args.seed, args.seed + args.seeds)
    warnings = _trial_warnings(args, seeds)
    with progress_bar(len(seeds) * args.days, f"trial {args.scenario}", "day") as bar:

        def progress(days: float) -> None:
            bar.n = round(days, 1)
            bar.update(0)

        runs = simulate_seeds(
            args.scenario,
            predictor,
            seeds,
            batch=args.batch,
            workers=args.workers,
            progress=progress,
            days=args.days,
            plans=plans,
            coach_spread=args.coach_spread,
            forecast=args.forecast,
            switch_hour=args.switch_hour,
            lead_in_min=args.lead_in_min,
            base_params=base,
        )
    if len(runs) == 1:
        data = runs[0].to_dict()
        warn(data, warnings)
        return emit(args, data, _trial_text)
    data = {
        "scenario": args.scenario,
        "days": args.days,
        "plans": list(plans),
        "seeds": list(seeds),
        "coach_spread": args.coach_spread,
        "forecast": args.forecast,
        "switch_hour": args.switch_hour,
        "lead_in_min": args.lead_in_min,
        "summary": summarize(runs),
        "runs": [r.to_dict() for r in runs],
    }
    warn(data, warnings)
    emit(args, data, _trials_text)


def cmd_experiment_ablation(args: argparse.Namespace) -> None:
    """``experiment summary --ablation``: Table II with one column per condition of the paper's
    text, added in order."""
    from trainclimate.analysis.ablation import STEPS, run_ablation, write_ablation
    from trainclimate.analysis.experiment import EXPERIMENTS

    out = out_dir(args.out, "the ablation table")
    base = _coach_params(args)
    warnings = _scenario_warnings(args, list(EXPERIMENTS))
    predictor = predictor_from(args)
    with progress_bar(len(EXPERIMENTS), "ablation", "experiment") as bar:
        rows = run_ablation(
            predictor, forecast=args.forecast, base_params=base, progress=lambda _: bar.update(1)
        )
    data = {"steps": list(STEPS), "experiments": rows, "markdown": str(write_ablation(rows, out))}
    warn(data, warnings)

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
        if args.objective not in (None, "paper"):
            raise UsageError("--ablation reproduces the paper's formulation: --objective paper")
        return cmd_experiment_ablation(args)
    out = out_dir(args.out, "the experiment reports")
    base = _coach_params(args)
    warnings = _scenario_warnings(args, list(EXPERIMENTS))
    predictor = predictor_from(args)
    rows = []
    with progress_bar(len(EXPERIMENTS), "paired experiments", "experiment") as bar:
        for name in EXPERIMENTS:
            pair = run_pair(
                name,
                predictor,
                forecast=args.forecast,
                base_params=base,
                objective=objective_of(args),
            )
            row = pair.to_dict()
            row["html"] = str(write_experiment_report(pair, out / f"{name}.html"))
            rows.append(row)
            bar.update(1)
    files = write_summary(rows, out)
    data = {"experiments": rows, **{k: str(v) for k, v in files.items()}}
    warn(data, warnings)

    def human(d: dict) -> str:
        return "\n".join(_experiment_text(r).splitlines()[0] for r in d["experiments"]) + (
            f"\nsummary written: {d['markdown']} and {d['html']}"
        )

    emit(args, data, human)


def _trial_options(p: argparse.ArgumentParser) -> None:
    """The options of ``experiment trial`` beside the shared ones."""
    from trainclimate.analysis.trial_plan import DEFAULT_SWITCH_HOUR
    from trainclimate.analysis.trial_sim import LEAD_IN_MIN, TRIAL_PLANS

    p.add_argument("--days", type=int, default=14, help="service days (default 14)")
    p.add_argument(
        "--coach-spread",
        type=float,
        default=0.1,
        help="parameter spread of each coach around the scenario's (default 0.1; 0: twins)",
    )
    p.add_argument(
        "--plan",
        default="alternate",
        help=f"{' | '.join(TRIAL_PLANS)}, or several comma-separated (simulated side by side "
        "against one counterfactual); fixed activates coach 0 (default alternate)",
    )
    p.add_argument("--seed", type=int, default=0, help="the trial's seed (default 0)")
    p.add_argument(
        "--seeds",
        type=int,
        default=1,
        help="run this many seeds from --seed on and summarise coverage and errors per plan",
    )
    p.add_argument(
        "--switch-hour",
        type=int,
        default=DEFAULT_SWITCH_HOUR,
        help=f"local hour a service day starts (default {DEFAULT_SWITCH_HOUR})",
    )
    p.add_argument(
        "--lead-in-min",
        type=float,
        default=LEAD_IN_MIN,
        help=f"minutes not counted after each switch (default {LEAD_IN_MIN:g})",
    )
    p.add_argument(
        "--batch",
        type=int,
        default=4,
        help="seeds simulated in one fleet (default 4; its memory ≈ 25 MB per seed and "
        "simulated day with three plans)",
    )
    p.add_argument("--workers", type=int, default=1, help="processes running fleets at once")


def register(sub) -> None:
    """Add ``experiment run|trial|summary`` to ``sub``."""
    esub = add_group(sub, "experiment", "paired experiments (activated vs deactivated)")
    for name, func, help_ in (
        ("run", cmd_experiment_run, "run one scenario as a paired experiment"),
        (
            "trial",
            cmd_experiment_trial,
            "simulate a trial of a pair of coaches over days, with the true saving beside it",
        ),
        ("summary", cmd_experiment_summary, "run every paired experiment and write the table"),
    ):
        p = add_command(esub, name, func, help_)
        add_model_options(p, objective=name != "trial")
        p.add_argument(
            "--coach-params",
            default=None,
            help="coach parameter file (coach-params, calibrate --out) for the coaches of every "
            "experiment (default: the scenario's)",
        )
        if name in ("run", "trial"):
            p.add_argument("--scenario", required=True, help="scenario name (see `scenarios`)")
        if name == "run":
            p.add_argument("--html", default=None, help="write the report (HTML, Plotly)")
            p.add_argument("--hours", type=float, default=None, help="duration (default: all)")
            p.add_argument(
                "--coach-spread",
                type=float,
                default=0.0,
                help="parameter spread of the deactivated coach (0: twins; e.g. 0.1)",
            )
        elif name == "trial":
            _trial_options(p)
        else:
            p.add_argument("--out", default="out/experiments", help="output directory")
            p.add_argument(
                "--ablation",
                action="store_true",
                help="Table II step by step: as before, on the HVAC meter, with the October "
                "conditions, the field events, the sensors' violation (writes ablation.md)",
            )
