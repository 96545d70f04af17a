"""``calibrate``: fit the simulator to coaches from their logged trajectories."""

from __future__ import annotations

import argparse
import json

from trainclimate.cli.common import (
    UsageError,
    add_command,
    dataset_dir,
    emit,
    out_file,
    progress_bar,
)


def cmd_calibrate(args: argparse.Namespace) -> None:
    """``calibrate``: one twin per ``--coach`` (``A+B``: the trajectories of A and B as one
    coach's), fitted on its training days and judged on its held-out days."""
    from trainclimate.data.trajectory import read_trajectories
    from trainclimate.sim.params import CoachParams, load_params
    from trainclimate.twin import calibration, validity
    from trainclimate.twin.knobs import CALIBRATED, CalibrationError

    names = None
    if args.params is not None:
        names = tuple(n.strip() for n in args.params.split(",") if n.strip())
        unknown = [n for n in names if n not in CALIBRATED]
        if not names or unknown:
            what = f"unknown {unknown[0]!r}" if unknown else "none given"
            raise UsageError(f"--params: {what}; choose from {', '.join(CALIBRATED)}")
    if args.starts < 1:
        raise UsageError("--starts must be at least 1")
    if args.bootstrap < 0:
        raise UsageError("--bootstrap must not be negative")
    if args.out and len(args.coach or []) != 1:
        raise UsageError("--out writes one coach's parameters: give exactly one --coach")
    out = out_file(args.out, "the calibrated coach parameters")
    base = load_params(args.base_params) if args.base_params else CoachParams()
    path = dataset_dir(args) / "trajectories_1min.parquet"
    if not path.exists():
        raise UsageError(f"--data: no 1-min trajectories ({path.name}) in {path.parent}")
    trajectories = read_trajectories(path)
    coaches = sorted({t.coach for t in trajectories})
    wanted = args.coach or coaches
    for group in wanted:
        missing = [c for c in group.split("+") if c not in coaches]
        if missing:
            raise UsageError(f"--coach: no trajectories of coach {missing[0]!r} in the dataset")
    results = []
    with progress_bar(len(wanted), "calibrate", "coach") as bar:
        for group in wanted:
            members = set(group.split("+"))
            mine = [t for t in trajectories if t.coach in members]
            try:
                fit = calibration.calibrate(
                    group, mine, names, base, starts=args.starts, bootstrap=args.bootstrap
                )
            except CalibrationError as exc:
                raise UsageError(str(exc)) from None
            results.append(fit.to_dict())
            bar.update(1)
    if out is not None:
        out.write_text(json.dumps(validity.params_file(results[0]), indent=2) + "\n")
    data = {
        "coaches": results,
        "params_fitted": sorted({n for c in results for n in c["fitted"]}),
        "out": str(out) if out else None,
    }

    def human(d: dict) -> str:
        lines = []
        for c in d["coaches"]:
            fitted = ", ".join(
                f"{n} {v['value']:.4g} ± {v['std']:.2g}"
                + (" [{:.4g}, {:.4g}]".format(*v["ci95"]) if "ci95" in v else "")
                for n, v in c["fitted"].items()
            )
            h = c["holdout"]
            energy = "–" if h["energy_error_pct"] is None else f"{h['energy_error_pct']:+.1f} %"
            r = h["setpoint_response"]
            moved = "–" if r["response_error_pct"] is None else f"{r['response_error_pct']:.0f} %"
            held = "".join(f"; {n['param']} held: {n['reason']}" for n in c["not_identified"])
            validated = c["validated_t_amb_c"]
            lines.append(
                f"{c['coach']}: {fitted}{held}; held out: T_room MAE {h['t_room_mae_c']:.3f} K, "
                f"energy {energy}, response to {r['scored']} setpoint changes {moved} off; "
                "validated for T_amb "
                + ("nowhere" if validated is None else "{:g} to {:g} °C".format(*validated))
            )
            lines += [f"  warning: {w}" for w in c["warnings"]]
        if d["out"]:
            lines.append(f"coach parameters written to {d['out']}")
        return "\n".join(lines)

    emit(args, data, human)


def register(sub) -> None:
    """Add ``calibrate`` to ``sub``."""
    from trainclimate.twin.bootstrap import BOOTSTRAP_REPLICATES
    from trainclimate.twin.knobs import CALIBRATED

    p = add_command(sub, "calibrate", cmd_calibrate, "fit the simulator to coaches from their logs")
    p.add_argument("--data", default=None, help="dataset directory (default: built once)")
    p.add_argument(
        "--coach",
        nargs="+",
        action="extend",
        default=None,
        metavar="ID",
        help="coaches to calibrate, each on its own (A+B: the logs of A and B as one coach's; "
        "default: every coach of the dataset)",
    )
    p.add_argument(
        "--params",
        default=None,
        help="the parameters to fit, comma-separated, each refused if the data do not "
        f"determine it (default: of {','.join(CALIBRATED)} those the data identify; the "
        "others held at their base value, listed in not_identified)",
    )
    p.add_argument(
        "--bootstrap",
        type=int,
        default=BOOTSTRAP_REPLICATES,
        help="re-fits on training days resampled whole, for the 95 %% intervals (default "
        f"{BOOTSTRAP_REPLICATES}; 0: none)",
    )
    p.add_argument(
        "--base-params", default=None, help="coach parameter file to start from (default: the "
        "default coach)"
    )  # fmt: skip
    p.add_argument("--starts", type=int, default=3, help="starts of the fit (default 3)")
    p.add_argument("--out", default=None, help="write the coach's parameters (coach-params file)")
