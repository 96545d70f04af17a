"""``bench pipeline``: the data pipeline's throughput (raw rows/s) and peak memory at two dataset
sizes, against plain CSV parsing of the same files."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pandas as pd

from trainclimate.bench.common import child, machine

#: The fleet-year the estimates are for: coaches × days.
FLEET_COACHES, YEAR_DAYS = 900, 365


#: Bounded memory: the peak at ``copies[1] / copies[0]`` times the data may be at most this
#: many times the small run's. [-]
TARGET_MEMORY_GROWTH = 1.2
#: The size of the one big export read, and the most peak memory its build may take. [MB]
BIG_FILE_MB, TARGET_BIG_FILE_PEAK_MB = 2048, 500


def run(days: int = 4, copies: tuple[int, int] = (2, 20), big_file_mb: float = BIG_FILE_MB) -> dict:
    """Pipeline throughput (raw rows/s) and peak memory (MB) at two dataset sizes.

    Generates ``days`` days of one winter (1-min HVAC) and one summer (2-s HVAC) coach, then
    links those files under new coach names ``copies[0]`` and ``copies[1]`` times and runs
    :func:`~trainclimate.data.dataset.build_dataset` on each in a fresh process, reading its
    peak resident memory. The baseline, in the same run, only parses the same CSV files with
    pandas (no cleaning, fusion, resampling or output): the pipeline's cost over bare I/O.
    Equal peak memory at both sizes is the bounded-memory property: the pipeline holds one
    coach-day at a time, so a fleet-year (900 coaches × 365 days) needs no more. The fleet-year
    time (h) is extrapolated from the large run (half 2-s, half 1-min logs) and from a run of
    1-min winter logs alone.

    Then one export ``big_file_mb`` MB large (a coach's whole 2-s log saved under one day's
    name: :func:`_big_export`) is built, and one a tenth of its size: the reader holds one block
    and the day's rows, so the peak must stay under :data:`TARGET_BIG_FILE_PEAK_MB` and about
    the same at both sizes; the baseline is the same coach-days without the added days.
    """
    import tempfile

    from trainclimate.data import fleetlogs

    with tempfile.TemporaryDirectory(prefix="tc-bench-") as tmp:
        tmp = Path(tmp)
        fleetlogs.generate(tmp / "seed", max_days=days, max_coaches=1)
        runs = []
        for n in copies:
            raw = tmp / f"raw{n}"
            _replicate(tmp / "seed", raw, n)
            run = child("run_pipeline", str(raw), str(tmp / f"out{n}"))
            base = child("run_parse_only", str(raw))
            run["rows_per_s"] = run["raw_rows"] / run["seconds"]
            run["parse_only_rows_per_s"] = base["rows"] / base["seconds"]
            run["ratio_to_parse_only"] = run["rows_per_s"] / run["parse_only_rows_per_s"]
            runs.append(run)
        # a fleet-year of 1-min logs: the winter campaign's format alone
        raw = tmp / "winter"
        _replicate(tmp / "seed", raw, copies[1], campaign="winter-spring")
        winter = child("run_pipeline", str(raw), str(tmp / "out-winter"))
        big = _big_runs(tmp, big_file_mb)
    small, large = runs
    return {
        "rows_per_s": large["rows_per_s"],
        "peak_rss_mb": large["peak_rss_mb"],
        "runs": runs,
        "memory_growth": large["peak_rss_mb"] / small["peak_rss_mb"],
        "size_ratio": large["raw_rows"] / small["raw_rows"],
        "fleet_year_hours_estimate": _fleet_year_hours(large),
        "fleet_year_1min_hours_estimate": _fleet_year_hours(winter),
        "winter_1min_run": winter,
        "big_file": big,
        "target": {
            "memory_growth_max": TARGET_MEMORY_GROWTH,
            "big_file_peak_rss_mb_max": TARGET_BIG_FILE_PEAK_MB,
        },
        "target_met": large["peak_rss_mb"] / small["peak_rss_mb"] <= TARGET_MEMORY_GROWTH
        and big["runs"][-1]["peak_rss_mb"] <= TARGET_BIG_FILE_PEAK_MB,
        "machine": machine(),
    }


def text(d: dict) -> str:
    """One line: raw rows/s against plain parsing, peak MB at both sizes, the fleet-year in h."""
    return (
        f"pipeline: {d['rows_per_s']:,.0f} raw rows/s "
        f"({d['runs'][-1]['ratio_to_parse_only']:.2f}× plain CSV parsing); peak memory "
        f"{d['runs'][0]['peak_rss_mb']:.0f} MB → {d['peak_rss_mb']:.0f} MB for "
        f"{d['size_ratio']:.0f}× the data; "
        f"fleet-year at 1 min ≈ {d['fleet_year_1min_hours_estimate']:.1f} h; "
        + "; ".join(
            f"a {r['file_mb']:,.0f} MB export: {r['peak_rss_mb']:.0f} MB peak, "
            f"{r['file_mb'] / r['seconds']:.0f} MB/s"
            for r in d["big_file"]["runs"]
        )
        + f" (baseline without the added days: {d['big_file']['baseline']['peak_rss_mb']:.0f} MB)"
    )


def _big_runs(tmp: Path, big_file_mb: float) -> dict:
    """The build of one coach-day whose HVAC export is ``big_file_mb`` / 10 and ``big_file_mb``
    MB, each in a fresh process, and the baseline: the same coach-days as generated."""
    from trainclimate.data import fleetlogs

    seed = tmp / "big"
    fleetlogs.generate(seed, max_days=2, max_coaches=1)
    baseline = child("run_pipeline", str(seed), str(tmp / "out-big0"))
    runs = []
    for mb in (big_file_mb / 10, big_file_mb):
        raw = tmp / f"big-{mb:.0f}"
        shutil.copytree(seed, raw)
        path = _big_export(raw, mb)
        run = child("run_pipeline", str(raw), str(tmp / "out-big"))
        run["file_mb"] = path.stat().st_size / 2**20
        runs.append(run)
        shutil.rmtree(raw)
    return {"baseline": baseline, "runs": runs}


def _fleet_year_hours(run: dict) -> float:
    """Hours a fleet-year would take at ``run``'s seconds per coach-day."""
    return FLEET_COACHES * YEAR_DAYS * run["seconds"] / run["coach_days"] / 3600


def _replicate(src: Path, dst: Path, copies: int, campaign: str = "") -> int:
    """Link every raw file of ``src`` (of ``campaign``, if given) ``copies`` times under ``dst``
    with new coach names, so the pipeline sees ``copies`` × as many coach-days (they are
    processed independently); the number of links made."""
    from trainclimate.data.formats import parse_log_name

    n = 0
    for path in sorted(src.rglob(f"{campaign}*/*/*.csv")):
        train, coach, day = parse_log_name(path)
        rel = path.parent.relative_to(src)
        for c in range(copies):
            target = dst / rel / f"{train}_{coach}x{c}_{day}.csv"
            target.parent.mkdir(parents=True, exist_ok=True)
            os.link(path, target)
            n += 1
    return n


def _big_export(seed: Path, target_mb: float) -> Path:
    """Make the summer HVAC file of a coach-day in service under ``seed`` about ``target_mb`` MB:
    the coach's 2-s log of the days before and after added around its own (an export of a whole
    log saved under one day's name). The path of the file."""
    from trainclimate.data.formats import SUMMER_FORMAT, parse_log_name

    trips = max(seed.rglob("summer/trips/*.csv"), key=lambda p: p.stat().st_size)
    path = trips.parent.parent / "hvac" / trips.name
    _, _, day = parse_log_name(path)
    header, *rows = path.read_text(encoding="utf-8").splitlines(keepends=True)
    label = SUMMER_FORMAT.modes["regular"]
    clock = pd.date_range("2000-01-01", periods=43_200, freq="2s").strftime("T%H:%M:%SZ")
    template = "".join(f"DAY{t},{label},24.00,24.10,24.20,24.30,0.00\n" for t in clock)
    per_day = len(template.replace("DAY", day).encode())
    extra_days = max(0, round((target_mb * 2**20 - path.stat().st_size) / per_day))
    first = pd.Timestamp(day) - pd.Timedelta(days=extra_days // 2 + 1)
    with path.open("w", encoding="utf-8") as f:
        f.write(header)
        for k in range(extra_days // 2):
            f.write(template.replace("DAY", f"{first + pd.Timedelta(days=k):%Y-%m-%d}"))
        f.writelines(rows)
        after = pd.Timestamp(day) + pd.Timedelta(days=2)
        for k in range(extra_days - extra_days // 2):
            f.write(template.replace("DAY", f"{after + pd.Timedelta(days=k):%Y-%m-%d}"))
    return path
