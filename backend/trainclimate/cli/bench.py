"""``bench …``: the benchmarks of :mod:`trainclimate.bench`, with their human output."""

from __future__ import annotations

import argparse
import json

from trainclimate.cli.common import (
    UsageError,
    add_command,
    emit,
    progress_bar,
)


def report(args: argparse.Namespace, data: dict, text) -> None:
    """Print a benchmark's ``data`` (``--json``: the dict, with its ``target`` and
    ``target_met``), else ``text(data)`` and a line saying whether its target was met."""
    emit(args, data, lambda d: f"{text(d)}\ntarget {'met' if d['target_met'] else 'MISSED'}: "
                                 f"{json.dumps(d['target'])}")  # fmt: skip


def cmd_bench(args: argparse.Namespace) -> None:
    """``bench TARGET``: run one benchmark and print its figures (``--json``: its dict)."""
    from trainclimate.bench import (
        calibration,
        controller,
        dashboard,
        load,
        pipeline,
        predictor,
        replicas,
        service,
        simulator,
        study,
    )

    if args.target == "simulator":
        coaches = 100 if args.coaches is None else args.coaches
        days = 1.0 if args.days is None else args.days
        if coaches < 1 or days <= 0:
            raise UsageError("--coaches must be ≥ 1 and --days positive")
        report(args, simulator.run(coaches, days, args.loop_coaches), simulator.text)
    elif args.target == "pipeline":
        if args.file_mb <= 0:
            raise UsageError("--file-mb must be positive")
        report(args, pipeline.run(big_file_mb=args.file_mb), pipeline.text)
    elif args.target == "calibrate":
        report(args, calibration.run(), calibration.text)
    elif args.target == "predictor":
        try:
            scales = tuple(int(x) for x in args.scales.split(","))
        except ValueError:
            raise UsageError("--scales takes integers separated by commas, e.g. 1,10,100") from None
        with progress_bar(len(scales) + 1, "predictor fits", "fit") as bar:
            data = predictor.run(scales, args.data, progress=bar.update)
        report(args, data, predictor.text)
    elif args.target == "service":
        if args.pairs < 1 or (args.days is not None and args.days < 1) or args.samples < 1:
            raise UsageError("--pairs, --days and --samples must be ≥ 1")
        with progress_bar(5, "service benchmark", "stage") as bar:
            try:
                data = service.run(
                    args.db,
                    pairs=args.pairs,
                    days=30 if args.days is None else int(args.days),
                    samples=args.samples,
                    progress=bar.update,
                )
            except service.ServiceBenchError as exc:
                raise UsageError(str(exc)) from None
        report(args, data, service.text)
    elif args.target == "load":
        with progress_bar(3, "load benchmark", "stage") as bar:
            try:
                data = load.run(
                    args.clients,
                    args.requests,
                    args.db,
                    mqtt=args.mqtt or load.MQTT_URL,
                    mqtt_coaches=load.MQTT_COACHES
                    if args.mqtt_coaches is None
                    else args.mqtt_coaches,
                    progress=bar.update,
                )
            except load.LoadBenchError as exc:
                raise UsageError(str(exc)) from None
        report(args, data, load.text)
    elif args.target == "study":
        coaches = 128 if args.coaches is None else args.coaches
        days = 2 if args.days is None else int(args.days)
        if coaches < 2 or days < 1:
            raise UsageError("--coaches must be ≥ 2 and --days ≥ 1")
        with progress_bar(4, "study benchmark", "stage") as bar:
            data = study.run(coaches, days, chunk_coaches=max(1, coaches // 2), progress=bar.update)
        report(args, data, study.text)
    elif args.target == "replicas":
        coaches = 10_000 if args.coaches is None else args.coaches
        with progress_bar(3, "replicas benchmark", "stage") as bar:
            try:
                data = replicas.run(coaches, args.db, progress=bar.update)
            except replicas.ReplicasBenchError as exc:
                raise UsageError(str(exc)) from None
        report(args, data, replicas.text)
    elif args.target == "dashboard":
        if not args.url or not args.token:
            raise UsageError("bench dashboard needs --url and --token of a running service")
        with progress_bar(4, "dashboard benchmark", "stage") as bar:
            try:
                data = dashboard.run(args.url, args.token, args.idle_s, progress=bar.update)
            except dashboard.DashboardBenchError as exc:
                raise UsageError(str(exc)) from None
        report(args, data, dashboard.text)
    else:
        report(args, controller.run(), controller.text)


def register(sub) -> None:
    """Add ``bench`` to ``sub``."""
    p = add_command(sub, "bench", cmd_bench, "run a benchmark")
    p.add_argument(
        "target",
        choices=(
            "simulator",
            "pipeline",
            "calibrate",
            "predictor",
            "controller",
            "service",
            "load",
            "replicas",
            "study",
            "dashboard",
        ),
    )
    p.add_argument("--url", default=None, help="dashboard: the running service's URL")
    p.add_argument("--token", default=None, help="dashboard: a viewer's (or better) token")
    p.add_argument(
        "--idle-s", type=float, default=60.0, help="dashboard: seconds idle on each page"
    )
    p.add_argument("--scales", default="1,10,100", help="predictor: column multiples to fit")
    p.add_argument(
        "--file-mb",
        type=float,
        default=2048,
        help="pipeline: the size of the one big export read, in MB (default 2048)",
    )
    p.add_argument("--data", default=None, help="predictor: dataset directory")
    p.add_argument(
        "--db",
        default=None,
        help="service: an empty PostgreSQL database (default: a new one on the server "
        "$TRAINCLIMATE_TEST_PG_URL names, else 127.0.0.1:5432, dropped at the end); load: a "
        "PostgreSQL server to make a throw-away database on (default: SQLite); replicas: a "
        "PostgreSQL server to make a throw-away database on (default as for service)",
    )
    p.add_argument("--clients", type=int, default=50, help="load: concurrent clients")
    p.add_argument("--requests", type=int, default=2000, help="load: requests in all")
    p.add_argument(
        "--mqtt",
        default=None,
        metavar="URL",
        help="load: the broker MQTT gateways publish through during the load (default "
        "mqtt://127.0.0.1:1883; skipped if none answers there)",
    )
    p.add_argument(
        "--mqtt-coaches",
        type=int,
        default=None,
        help="load: live coaches fed over MQTT (pairs; default 10; 0: none)",
    )
    p.add_argument(
        "--coaches",
        type=int,
        default=None,
        help="simulator: coaches simulated (default 100); replicas: live coaches (default 10 000);"
        " study: coaches (default 128)",
    )
    p.add_argument(
        "--days",
        type=float,
        default=None,
        help="simulator: days (default 1); study: days (2); service: days of data stored (30)",
    )
    p.add_argument(
        "--pairs", type=int, default=50, help="service: coach pairs of data stored (default 50)"
    )
    p.add_argument(
        "--samples", type=int, default=30, help="service: requests per latency point (30)"
    )
    p.add_argument(
        "--loop-coaches", type=int, default=5, help="coaches simulated one by one for the baseline"
    )
