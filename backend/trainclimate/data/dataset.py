"""The whole dataset: every raw log file under a directory, through the pipeline
(:mod:`trainclimate.data.pipeline`) coach-day by coach-day, into one Parquet file per sampling time
and ``dataset.json`` — Table I, every row accounted for per source, every file reported.
"""

from __future__ import annotations

import json
import logging
import os
from collections import defaultdict
from collections.abc import Callable, Collection
from dataclasses import asdict, dataclass
from pathlib import Path

import pandas as pd

from trainclimate.data.formats import FORMATS, SOURCES, FormatError, parse_log_name
from trainclimate.data.pipeline import (
    Counts,
    PipelineError,
    PipelineSettings,
    by_column,
    process_coach_day,
)
from trainclimate.data.reader import TimezoneError, read_source
from trainclimate.data.trajectory import TrajectoryWriter
from trainclimate.paths import writable_dir

log = logging.getLogger(__name__)


@dataclass
class DatasetSummary:
    """What :func:`build_dataset` produced: Table I, the counts and the files."""

    table: list[dict]
    dropped_rows: dict[str, int]
    repaired_rows: dict[str, int]
    #: cells invalidated (made NaN; their rows kept), by reason, over every source and column
    invalid_cells: dict[str, int]
    unreadable_files: list[str]
    #: how many of ``unreadable_files`` were corrupted on purpose by the generator
    unreadable_as_generated: int
    coach_days: int
    raw_rows: int
    #: the Parquet file of each sampling time, relative to the output directory
    outputs: dict[str, str]
    #: per source: rows ``read``, ``kept`` and ``dropped`` by reason (read == kept + dropped),
    #: and ``invalid_cells`` by column and reason
    rows: dict[str, dict]
    #: the zone times without one were read in (None: each campaign's own)
    timezone: str | None
    #: per raw file (relative to the raw directory): ``source``, ``campaign``, ``encoding``,
    #: ``delimiter``, ``rows_read``, ``rows_kept`` (by the reader), ``dropped`` (reason → rows),
    #: ``invalid_cells`` (column → reason → cells), ``extra_columns``; or ``error`` for a file
    #: not read, ``ignored`` for one not used
    files: list[dict]

    def to_dict(self) -> dict:
        """JSON-ready, as ``dataset.json`` holds it."""
        return asdict(self)


def _coach_day_window(day: str) -> tuple[pd.Timestamp, pd.Timestamp]:
    """The coach-day [03:00 local, 03:00 local next day) in UTC (the loggers' day files)."""
    start = pd.Timestamp(f"{day} 03:00", tz="Europe/Zurich")
    nxt = pd.Timestamp(day) + pd.Timedelta(days=1)
    end = pd.Timestamp(f"{nxt:%Y-%m-%d} 03:00", tz="Europe/Zurich")
    return start.tz_convert("UTC"), end.tz_convert("UTC")


def _source_windows(day: str, settings: PipelineSettings) -> dict[str, tuple]:
    """Per source, the times of the rows the coach-day ``day`` uses: its window, widened for
    the weather by the longest gap interpolated across (the window's edges are interpolated
    from readings just outside it)."""
    start, end = _coach_day_window(day)
    margin = pd.Timedelta(minutes=settings.max_weather_gap_min)
    return {"hvac": (start, end), "weather": (start - margin, end + margin), "trips": (start, end)}


def _campaign_order(name: str) -> tuple[int, str]:
    """Known campaigns in their chronological order (as in the paper's Table I), others after."""
    known = list(FORMATS)
    return (known.index(name) if name in known else len(known), name)


def discover(raw: Path) -> tuple[dict[tuple[str, str, str, str], list[Path]], list[str]]:
    """Group raw files by (campaign directory, train, coach, day); names outside the layout
    are returned as warnings."""
    groups: dict[tuple[str, str, str, str], list[Path]] = defaultdict(list)
    skipped = []
    for path in sorted(p for p in raw.rglob("*") if p.suffix.lower() == ".csv" and p.is_file()):
        parsed = parse_log_name(path)
        if parsed is None or len(path.relative_to(raw).parts) < 3:
            skipped.append(str(path))
            continue
        campaign = path.relative_to(raw).parts[-3]
        groups[(campaign, *parsed)].append(path)
    return dict(sorted(groups.items())), skipped


def build_dataset(
    raw: str | Path,
    out: str | Path,
    settings: PipelineSettings | None = None,
    *,
    progress: Callable[[int], None] | None = None,
    expected_unreadable: Collection[str] = (),
    timezone: str | None = None,
) -> DatasetSummary:
    """Run the pipeline over every raw file under ``raw``; write one Parquet file per sampling
    time (``trajectories_<S>min.parquet``) and ``dataset.json`` under ``out``.

    Coach-days are processed one at a time in a fixed order, so memory is bounded and the
    output byte-identical for the same input. Unreadable files are named in a warning and
    counted — except ``expected_unreadable``, the files the generator corrupted on purpose
    (:attr:`~trainclimate.data.fleetlogs.GenerationSummary.corrupted`), which are counted in one
    line; :class:`PipelineError` if nothing usable was found, or for times without a zone where
    the format has one and no ``timezone`` (an IANA name: the zone of times written without one;
    default each campaign's, :func:`~trainclimate.data.reader.read_source`).
    """
    settings = settings or PipelineSettings()
    raw, out = Path(raw), Path(out)
    if not raw.is_dir():
        raise PipelineError(f"raw log directory not found: {raw}")
    writable_dir(out, "the dataset", hint="choose another output directory")
    expected = {str(Path(p).resolve()) for p in expected_unreadable}
    groups, skipped = discover(raw)
    files: list[dict] = []
    total = Counts()
    for path in skipped:
        log.warning("skipped %s: not named <campaign>/<source>/<train>_<coach>_<day>.csv", path)
        where = str(Path(path).relative_to(raw))
        files.append(
            {"path": where, "error": "not named <campaign>/<source>/<train>_<coach>_<day>.csv"}
        )
        _count_unread(total, Path(path), "unrecognised_file")
    if not groups:
        raise PipelineError(f"no raw log files under {raw}")
    unreadable: list[str] = []
    raw_rows = 0
    stats: dict[tuple[str, int], list[int]] = defaultdict(lambda: [0, 0])
    campaigns_seen: list[str] = []
    paths = {s: out / f"trajectories_{s}min.parquet" for s in settings.sampling_min}
    # written beside their targets and renamed into place at the end: a failed run leaves the
    # previous output whole
    partial = {s: _partial(p) for s, p in paths.items()}
    writers = {s: TrajectoryWriter(p) for s, p in partial.items()}
    done = False
    try:
        for (campaign_dir, train, coach, day), paths_of_day in groups.items():
            sources: dict[str, pd.DataFrame | None] = {"hvac": None, "weather": None, "trips": None}
            campaign = campaign_dir
            windows = _source_windows(day, settings)
            for path in paths_of_day:
                where = str(path.relative_to(raw))
                try:
                    table = read_source(path, timezone, windows)
                except TimezoneError as exc:
                    raise PipelineError(f"{where}: {exc}") from None
                except (FormatError, OSError, ValueError) as exc:
                    unreadable.append(str(path))
                    files.append({"path": where, "error": str(exc).splitlines()[0]})
                    _count_unread(total, path, "unreadable_file")
                    if str(path.resolve()) not in expected:
                        log.warning("unreadable raw file %s: %s", path, str(exc).splitlines()[0])
                    continue
                report = {
                    "path": where,
                    "source": table.source,
                    "campaign": table.campaign,
                    "encoding": table.encoding,
                    "delimiter": table.delimiter,
                    "rows_read": table.rows_read,
                    "rows_kept": len(table.frame),
                    "dropped": dict(sorted(table.dropped.items())),
                    "invalid_cells": by_column(table.cells),
                    "extra_columns": list(table.extra_columns),
                }
                files.append(report)
                if table.extra_columns:
                    log.info("%s: columns ignored: %s", path, ", ".join(table.extra_columns))
                total.read[table.source] += table.rows_read
                if sources.get(table.source) is not None:
                    report["ignored"] = f"a second {table.source} file for the coach-day"
                    total.drop(table.source, "second_file_for_coach_day", table.rows_read)
                    log.warning(
                        "ignored %s: a second %s file for the coach-day", path, table.source
                    )
                    continue
                sources[table.source] = table.frame
                campaign = table.campaign
                for reason, n in table.dropped.items():
                    total.drop(table.source, reason, n)
                for (column, reason), n in table.cells.items():
                    total.invalidate(table.source, column, reason, n)
                raw_rows += table.rows_read
            start, end = _coach_day_window(day)
            meta = {"campaign": campaign, "train": train, "coach": coach}
            result, counts = process_coach_day(
                sources, start=start, end=end, meta=meta, settings=settings
            )
            total.update(counts)
            if campaign not in campaigns_seen:
                campaigns_seen.append(campaign)
            for step, trajectories in result.items():
                writers[step].write(trajectories)
                stats[(campaign, step)][0] += len(trajectories)
                stats[(campaign, step)][1] += sum(len(t) for t in trajectories)
            if progress:
                progress(1)
        for writer in writers.values():
            writer.close()
        if not any(n for n, _ in stats.values()):
            raise PipelineError(
                f"no usable trajectory in {raw}: {len(groups)} coach-day(s), "
                f"{len(unreadable)} unreadable file(s), nothing in regular mode long enough"
            )
        done = True
    finally:
        for writer in writers.values():
            writer.close()
        if not done:
            for path in partial.values():
                path.unlink(missing_ok=True)
    as_generated = sum(str(Path(p).resolve()) in expected for p in unreadable)
    if as_generated:
        log.info(
            "%d corrupted file%s skipped, as generated", as_generated, "s"[: as_generated != 1]
        )
    table = [
        {
            "campaign": c,
            "sampling_min": s,
            "trajectories": stats[(c, s)][0],
            "mean_points": round(stats[(c, s)][1] / stats[(c, s)][0], 1) if stats[(c, s)][0] else 0,
        }
        for c in sorted(campaigns_seen, key=_campaign_order)
        for s in settings.sampling_min
    ]
    summary = DatasetSummary(
        table=table,
        dropped_rows={k: int(v) for k, v in sorted(total.dropped.items()) if v},
        repaired_rows={k: int(v) for k, v in sorted(total.repaired.items()) if v},
        invalid_cells=total.invalid_cells(),
        unreadable_files=unreadable,
        unreadable_as_generated=as_generated,
        coach_days=len(groups),
        raw_rows=raw_rows,
        outputs={f"{s}min": p.name for s, p in paths.items()},
        rows=total.rows(),
        timezone=timezone,
        files=files,
    )
    report = _partial(out / "dataset.json")
    report.write_text(
        json.dumps({**summary.to_dict(), "settings": asdict(settings)}, indent=2) + "\n"
    )
    for s, path in paths.items():
        os.replace(partial[s], path)
    os.replace(report, out / "dataset.json")  # last: it describes the files now in place
    return summary


def _count_unread(counts: Counts, path: Path, reason: str) -> None:
    """A file not read: its non-blank lines after the first, as rows of the source its directory
    names (``unknown`` if none), read and dropped for ``reason``."""
    try:
        lines = sum(1 for line in path.read_bytes().splitlines() if line.strip())
    except OSError:
        lines = 0
    source = path.parent.name if path.parent.name in SOURCES else "unknown"
    counts.read[source] += max(0, lines - 1)
    counts.drop(source, reason, max(0, lines - 1))


def _partial(path: Path) -> Path:
    """Where ``path`` is written before it is renamed into place (same directory, hidden)."""
    return path.with_name(f".{path.name}.partial")
