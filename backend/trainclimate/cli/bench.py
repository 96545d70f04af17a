"""``bench …``: the benchmarks of :mod:`trainclimate.bench`, with their human output."""

from __future__ import annotations

import argparse

from trainclimate.cli.common import (
    UsageError,
    add_command,
    emit,
    progress_bar,
)


def cmd_bench(args: argparse.Namespace) -> None:
    """``bench TARGET``: run one benchmark and print its figures (``--json``: its dict)."""
    from trainclimate.bench import controller, pipeline, predictor, service, simulator

    if args.target == "simulator":
        if args.coaches < 1 or args.days <= 0:
            raise UsageError("--coaches must be ≥ 1 and --days positive")
        emit(args, simulator.run(args.coaches, args.days, args.loop_coaches), simulator.text)
    elif args.target == "pipeline":
        emit(args, pipeline.run(), pipeline.text)
    elif args.target == "predictor":
        try:
            scales = tuple(int(x) for x in args.scales.split(","))
        except ValueError:
            raise UsageError("--scales takes integers separated by commas, e.g. 1,10,100") from None
        with progress_bar(len(scales) + 1, "predictor fits", "fit") as bar:
            data = predictor.run(scales, args.data, progress=bar.update)
        emit(args, data, predictor.text)
    elif args.target == "service":
        with progress_bar(4, "service benchmark", "stage") as bar:
            try:
                data = service.run(args.db, progress=bar.update)
            except service.ServiceBenchError as exc:
                raise UsageError(str(exc)) from None
        emit(args, data, service.text)
    else:
        emit(args, controller.run(), controller.text)


def register(sub) -> None:
    """Add ``bench`` to ``sub``."""
    p = add_command(sub, "bench", cmd_bench, "run a benchmark")
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
