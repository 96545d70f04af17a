"""What every command shares: the parser class, the exit-2 error, JSON or text output, progress
bars, checked output paths, and the inputs several commands take (a database URL, a dataset
directory, a predictor model)."""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from trainclimate.paths import writable_dir, writable_file

#: What to do when an output path named on the command line cannot be written.
OUT_HINT = "choose another path"


class UsageError(Exception):
    """Bad input from the user: exit code 2 with a one-line message."""


class Parser(argparse.ArgumentParser):
    """An argparse parser whose errors are a :class:`UsageError` (one line, exit 2)."""

    def error(self, message: str) -> NoReturn:
        """Raise :class:`UsageError` with argparse's message."""
        raise UsageError(message)


def add_group(sub, name: str, help_: str):
    """A command group ``trainclimate NAME …`` in ``sub``; returns its subcommands' parsers."""
    group = sub.add_parser(name, help=help_)
    return group.add_subparsers(dest=f"{name}_command", required=True, parser_class=Parser)


def add_model_options(
    p: argparse.ArgumentParser,
    prefix: str = "",
    forecast: str = "perfect",
    objective: bool = True,
) -> None:
    """``--predictor FILE``, ``--forecast`` (default ``forecast``) and, with ``objective``,
    ``--objective`` (unset: :func:`objective_of` gives the default) for commands that run the
    DDPC layer."""
    p.add_argument("--predictor", default=None, help=f"{prefix}model file (default: cached model)")
    p.add_argument(
        "--forecast",
        choices=("perfect", "persistence", "noisy"),
        default=forecast,
        help=f"{prefix}disturbance forecast (default {forecast})",
    )
    if objective:
        from trainclimate.control.ocp import DEFAULT_OBJECTIVE, OBJECTIVES

        p.add_argument(
            "--objective",
            choices=OBJECTIVES,
            default=None,
            help=f"{prefix}the optimisation's objective: paper (the paper's Eq. (10)), margin "
            "(T_ref kept within a margin of the predicted room) or states (Eq. (10), T_ref "
            "raised only where the HVAC's state rules keep a cooling unit cooling; default "
            f"{DEFAULT_OBJECTIVE})",
        )


def objective_of(args: argparse.Namespace) -> str:
    """The ``--objective`` asked for, else the layer's default."""
    from trainclimate.control.ocp import DEFAULT_OBJECTIVE

    return getattr(args, "objective", None) or DEFAULT_OBJECTIVE


def add_command(sub, name: str, func, help_: str) -> argparse.ArgumentParser:
    """A subcommand ``name`` of ``sub`` running ``func``, with the ``--json`` every command has."""
    p = sub.add_parser(name, help=help_, description=help_)
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=func)
    return p


def emit(args: argparse.Namespace, data: dict, human: Callable[[dict], str]) -> None:
    """Print ``data`` as one JSON object with ``--json``, else ``human(data)``."""
    if args.json:
        print(json.dumps(data, default=json_default))
    else:
        print(human(data))


def warn(data: dict, warnings: list[str]) -> None:
    """Print each of ``warnings`` to stderr (``trainclimate: warning: …``) and list them in
    ``data["warnings"]`` (the ``--json`` output), after any already there."""
    for w in warnings:
        print(f"trainclimate: warning: {w}", file=sys.stderr)
    data["warnings"] = [*data.get("warnings", []), *warnings]


def json_default(value):
    """JSON for numpy scalars and arrays (``json.dumps(default=…)``)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


#: Without a terminal, a progress line at most this often. [s]
PROGRESS_LINE_EVERY_S = 5.0


class _Lines(io.TextIOBase):
    """A stream for tqdm when stderr is not a terminal (a log file, CI): each redraw becomes a
    line of its own instead of a carriage return over the last."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> int:
        for part in text.replace("\r", "\n").split("\n"):
            if part.strip():
                self.stream.write(part.rstrip() + "\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(total: int, desc: str, unit: str = "step"):
    """A tqdm progress bar on stderr, with how far, the rate and the time left: redrawn in place
    on a terminal, else, once the run has taken :data:`PROGRESS_LINE_EVERY_S` s, a line at most
    that often and one at the end."""
    from tqdm import tqdm

    tty = sys.stderr.isatty()
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr if tty else _Lines(sys.stderr),
        leave=not tty,
        mininterval=0.5 if tty else PROGRESS_LINE_EVERY_S,
        delay=0 if tty else PROGRESS_LINE_EVERY_S,  # short runs (and quick errors) print none
        dynamic_ncols=tty,
        ncols=None if tty else 100,
    )


def out_file(path: str | None, what: str) -> Path | None:
    """An output file named on the command line, its directory created (None if not given);
    :class:`StorageError` (exit 2) when it cannot be written — before any work is done."""
    return writable_file(path, what, hint=OUT_HINT) if path else None


def out_dir(path: str | None, what: str) -> Path | None:
    """An output directory named on the command line, created with its parents (None if not
    given); :class:`StorageError` (exit 2) when it cannot be."""
    return writable_dir(path, what, hint=OUT_HINT) if path else None


def db_url(args: argparse.Namespace) -> str:
    """``--db``, else ``$TRAINCLIMATE_DATABASE_URL``, else the embedded SQLite file."""
    from trainclimate.service.settings import default_database_url

    return args.db or os.environ.get("TRAINCLIMATE_DATABASE_URL") or default_database_url()


#: The database URLs the service takes.
DB_FORMS = "sqlite:///FILE or postgresql://USER@HOST:PORT/NAME"


def migrated_database(url: str) -> str:
    """Bring the database at ``url`` to the newest migration and return ``url``; a URL or a
    database that cannot be used is one line (:class:`UsageError`, exit 2) saying what to do:
    a wrong scheme, an unparsable URL, a PostgreSQL database that does not exist (``createdb``),
    a server that does not answer."""
    import re

    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError, OperationalError

    from trainclimate.service.store.db import migrate

    try:
        parsed = make_url(url)
    except ArgumentError:
        raise UsageError(f"not a database URL: {url!r} (use {DB_FORMS})") from None
    shown = parsed.render_as_string(hide_password=True)
    if parsed.get_backend_name() not in ("sqlite", "postgresql"):
        raise UsageError(f"unsupported database {shown!r}: use {DB_FORMS}")
    try:
        migrate(url)
    except OperationalError as exc:
        first = str(exc.orig or exc).strip().splitlines()[0]
        missing = re.search(r'database "([^"]+)" does not exist', first)
        if missing:
            where = f"{parsed.host}:{parsed.port or 5432}"
            raise UsageError(
                f"the database {missing[1]!r} does not exist on {where}: create it first "
                f"(createdb {missing[1]}), then try again"
            ) from None
        raise UsageError(f"cannot use the database {shown}: {first}") from None
    return url


def predictor_from(args: argparse.Namespace):
    """``--predictor FILE`` or the cached default model (fitted once on the default dataset)."""
    from trainclimate.predict.artifact import load_predictor

    if getattr(args, "predictor", None):
        return load_predictor(args.predictor)
    from trainclimate.predict.default import default_predictor

    return default_predictor()


def given_dataset(value: str, flag: str) -> Path:
    """A dataset directory named on the command line (usage error if it holds none)."""
    path = Path(value)
    if not (path / "dataset.json").exists() and not any(path.glob("trajectories_*min.parquet")):
        raise UsageError(f"{flag}: {path} holds no dataset (run `trainclimate dataset build`)")
    return path


@contextmanager
def stage_bars(label: str):
    """A ``progress(stage, done, total)`` callback drawing one progress bar per stage (on stderr
    when it is a terminal), for the builds of the generated datasets and models."""
    bars: dict[str, Any] = {}  # tqdm bars

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in bars:
            for bar in bars.values():
                bar.close()
            bars[stage] = progress_bar(total, f"{label}: {stage}", "coach-day")
        bar = bars[stage]
        bar.update(done - bar.n)

    try:
        yield progress
    finally:
        for bar in bars.values():
            bar.close()


def dataset_dir(args: argparse.Namespace) -> Path:
    """``--data DIR`` or the default dataset (built once, with a progress bar)."""
    if args.data:
        return given_dataset(args.data, "--data")
    from trainclimate.data.cache import default_dataset

    with stage_bars("default dataset") as progress:
        return default_dataset(progress)
