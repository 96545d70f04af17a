"""``predictor evaluate|fit|default|study``: the prediction models."""

from __future__ import annotations

import argparse

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    dataset_dir,
    emit,
    given_dataset,
    out_file,
    progress_bar,
    stage_bars,
)
from trainclimate.predict import METHODS


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
    """``predictor evaluate``: MAE per step on the held-out coaches."""
    from trainclimate.predict.evaluate import evaluate, load_split

    _check_predictor_args(args)
    split = None
    if args.train_data:  # fitted on another dataset's training coaches, measured on this one's
        train, _ = load_split(given_dataset(args.train_data, "--train-data"), args.sampling_min)
        _, validation = load_split(dataset_dir(args), args.sampling_min)
        split = (train, validation)
    _, data = evaluate(
        args.method, args.sampling_min, args.rho, args.horizon, dataset_dir(args), split
    )
    emit(args, data, _mae_human)


def cmd_predictor_fit(args: argparse.Namespace) -> None:
    """``predictor fit``: fit on the training coaches, evaluate, save the model file."""
    from trainclimate.predict.artifact import save_predictor
    from trainclimate.predict.evaluate import evaluate

    _check_predictor_args(args)
    out_file(args.out, "the model file")
    predictor, result = evaluate(
        args.method, args.sampling_min, args.rho, args.horizon, dataset_dir(args)
    )
    path = save_predictor(predictor, args.out, validation=result)
    data = {**result, "out": str(path)}
    emit(args, data, lambda d: _mae_human(d) + f"\nmodel written: {d['out']}")


def cmd_predictor_default(args: argparse.Namespace) -> None:
    """``predictor default``: build (once) and cache the default or quick model."""
    from trainclimate.predict import default as models

    path = models.quick_model_path() if args.quick else models.default_model_path()
    built = not path.exists()
    which = "quick" if args.quick else "default"
    with stage_bars(f"{which} dataset") as progress:
        predictor = (models.quick_predictor if args.quick else models.default_predictor)(
            progress=progress
        )
    data = {
        "model": which,
        "path": str(path),
        "built": built,
        "trajectories": predictor.n_trajectories,
        "hankel_columns": predictor.n_columns,
    }
    emit(args, data, lambda d: f"{d['model']} model {'built' if built else 'cached'}: {d['path']}")


def cmd_predictor_study(args: argparse.Namespace) -> None:
    """``predictor study``: the paper's three sensitivity studies, optionally as HTML."""
    from trainclimate.predict import study

    out_file(args.html, "the HTML report")
    data_dir = dataset_dir(args)
    with progress_bar(study.n_runs(), "sensitivity studies", "fit") as bar:
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

    emit(args, data, human)


def register(sub) -> None:
    """Add ``predictor evaluate|fit|default|study`` to ``sub``."""
    psub = add_group(sub, "predictor", "fit and evaluate the prediction models")

    def add(name: str, func, help_: str, setting: bool = True) -> argparse.ArgumentParser:
        p = add_command(psub, name, func, help_)
        p.add_argument("--data", default=None, help="dataset directory (default: built once)")
        if setting:
            p.add_argument(
                "--method", choices=("transient", "subspace", "arx"), default="transient"
            )
            p.add_argument("--sampling-min", type=int, default=5, help="1, 5 or 10 (default 5)")
            p.add_argument("--rho", type=int, default=12, help="lead-in samples (default 12)")
            p.add_argument("--horizon", type=int, default=12, help="prediction steps (default 12)")
        return p

    p = add("evaluate", cmd_predictor_evaluate, "MAE per step on the held-out coaches")
    p.add_argument(
        "--train-data",
        default=None,
        help="fit on the training coaches of this dataset instead (measured on --data's "
        "held-out coaches), e.g. the quick dataset the service starts with",
    )
    p = add("fit", cmd_predictor_fit, "fit on the training coaches and save the model")
    p.add_argument("--out", required=True, help="model file to write (.npz)")
    p = add(
        "default",
        cmd_predictor_default,
        "build (once) and cache the model the controller and the service use by default",
        setting=False,
    )
    p.add_argument(
        "--quick", action="store_true", help="the quick model (a 4-day campaign, ≈ 1 min)"
    )
    p = add("study", cmd_predictor_study, "the paper's three sensitivity studies", setting=False)
    p.add_argument("--html", default=None, help="write the report with Plotly figures here")
