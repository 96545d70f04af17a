"""The ``trainclimate`` command line: one module per command group, each registering its parsers
and owning its handlers and their human-readable output.

Every command takes ``--json`` and then prints exactly one JSON object on stdout; logs and
progress go to stderr. Bad arguments, an unknown scenario, a malformed input file or a path that
cannot be written end with exit code 2 and a one-line message on stderr. The commands and their
JSON keys are listed in the README and in ``docs/``.

- :mod:`.common` — the parser class, output, progress bars, checked paths, shared inputs
- :mod:`.simulate` — ``scenarios``, ``simulate``, ``coach-params``, ``demo``
- :mod:`.dataset` — ``dataset build``
- :mod:`.calibrate` — ``calibrate``
- :mod:`.predictor` — ``predictor evaluate|fit|default|study``
- :mod:`.experiment` — ``experiment run|trial|summary``
- :mod:`.study` — ``study fleet``
- :mod:`.model` — ``model retrain``
- :mod:`.service` — ``serve``, ``token create``, ``gateway``
- :mod:`.train` — ``train plan``
- :mod:`.retention` — ``retention``
- :mod:`.bench` — ``bench …``
"""

from __future__ import annotations

import argparse
import logging
import sys

from trainclimate.cli import (
    bench,
    calibrate,
    dataset,
    experiment,
    model,
    predictor,
    retention,
    service,
    simulate,
    study,
    train,
)
from trainclimate.cli.common import Parser, UsageError
from trainclimate.data.pipeline import PipelineError
from trainclimate.paths import StorageError
from trainclimate.predict import PredictorDataError
from trainclimate.predict.artifact import ArtifactError
from trainclimate.service.logs import StderrHandler
from trainclimate.sim.params import ParamsError
from trainclimate.sim.scenarios import ScenarioError
from trainclimate.sim.weather import WeatherError

DESCRIPTION = "Data-driven predictive HVAC energy management for SBB Regio-Dosto coaches."
#: The command groups, in the order ``--help`` lists them.
GROUPS = (
    simulate,
    bench,
    dataset,
    calibrate,
    predictor,
    experiment,
    study,
    model,
    service,
    train,
    retention,
)
#: Errors that are the user's input, not a bug: exit 2 with their first line.
USER_ERRORS = (
    UsageError,
    ScenarioError,
    WeatherError,
    ParamsError,
    PipelineError,
    PredictorDataError,
    ArtifactError,
    StorageError,
)


def build_parser() -> argparse.ArgumentParser:
    """The ``trainclimate`` parser, with every command group's subcommands."""
    parser = Parser(prog="trainclimate", description=DESCRIPTION)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for group in GROUPS:
        group.register(sub)
    return parser


class _LogFormat(logging.Formatter):
    """``trainclimate: warning: …`` for warnings and errors, ``trainclimate: …`` for news."""

    def format(self, record: logging.LogRecord) -> str:
        warning = record.levelno >= logging.WARNING
        return ("trainclimate: warning: " if warning else "trainclimate: ") + super().format(record)


def main(argv: list[str] | None = None) -> int:
    """Run the command ``argv`` (default: the process's arguments); returns the exit code."""
    handler = StderrHandler()
    handler.setFormatter(_LogFormat())
    logging.basicConfig(level=logging.WARNING, handlers=[handler], force=True)
    logging.getLogger("trainclimate").setLevel(logging.INFO)
    try:
        args = build_parser().parse_args(argv)
        if args.command == "coach-params" and not (args.default or args.file):
            raise UsageError("coach-params needs --default or --file FILE")
        args.func(args)
    except USER_ERRORS as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"trainclimate: error: {message}", file=sys.stderr)
        return 2
    return 0
