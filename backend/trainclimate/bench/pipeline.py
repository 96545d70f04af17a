"""``bench pipeline``: the data pipeline's throughput (raw rows/s) and peak memory at two dataset
sizes, against plain CSV parsing of the same files."""

from __future__ import annotations

import os
from pathlib import Path

from trainclimate.bench.common import child, machine

#: The fleet-year the estimates are for: coaches × days.
FLEET_COACHES, YEAR_DAYS = 900, 365


#: Bounded memory: the peak at ``copies[1] / copies[0]`` times the data may be at most this
#: many times the small run's. [-]
TARGET_MEMORY_GROWTH = 1.2


def run(days: int = 4, copies: tuple[int, int] = (2, 20)) -> dict:
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
        "target": {"memory_growth_max": TARGET_MEMORY_GROWTH},
        "target_met": large["peak_rss_mb"] / small["peak_rss_mb"] <= TARGET_MEMORY_GROWTH,
        "machine": machine(),
    }


def text(d: dict) -> str:
    """One line: raw rows/s against plain parsing, peak MB at both sizes, the fleet-year in h."""
    return (
        f"pipeline: {d['rows_per_s']:,.0f} raw rows/s "
        f"({d['runs'][-1]['ratio_to_parse_only']:.2f}× plain CSV parsing); peak memory "
        f"{d['runs'][0]['peak_rss_mb']:.0f} MB → {d['peak_rss_mb']:.0f} MB for "
        f"{d['size_ratio']:.0f}× the data; "
        f"fleet-year at 1 min ≈ {d['fleet_year_1min_hours_estimate']:.1f} h"
    )


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
