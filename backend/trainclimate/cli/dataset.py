"""``dataset build``: raw fleet logs (generated, or read with ``--raw``) through the pipeline."""

from __future__ import annotations

import argparse
import zoneinfo
from pathlib import Path

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    emit,
    out_dir,
    progress_bar,
)


def cmd_dataset_build(args: argparse.Namespace) -> None:
    """``dataset build``: generate (or read ``--raw``) raw logs and run the pipeline; Table I."""
    from trainclimate.data import dataset, fleetlogs
    from trainclimate.sim.params import load_params

    if (args.days is not None and args.days < 1) or (args.coaches is not None and args.coaches < 1):
        raise UsageError("--days and --coaches must be at least 1")
    if args.timezone is not None:
        try:
            zoneinfo.ZoneInfo(args.timezone)
        except (zoneinfo.ZoneInfoNotFoundError, ValueError):
            raise UsageError(f"--timezone: unknown time zone {args.timezone!r}") from None
    out = out_dir(args.out, "the dataset")
    generated = None
    if args.raw and args.coach_params:
        raise UsageError("--coach-params sets the generated coaches' parameters: not with --raw")
    if args.raw:
        raw = Path(args.raw)
        if not raw.is_dir():
            raise UsageError(f"--raw: no such directory: {raw}")
    else:
        raw = out / "raw"
        coach_params = load_params(args.coach_params) if args.coach_params else None
        campaigns = tuple(fleetlogs.CAMPAIGNS[c] for c in args.campaign or fleetlogs.CAMPAIGNS)
        total = sum(
            len(c.days[: args.days] if args.days else c.days)
            * min(len(c.coaches), args.coaches or len(c.coaches))
            for c in campaigns
        )
        with progress_bar(total, "generate raw logs", "coach-day") as bar:
            generated = fleetlogs.generate(
                raw,
                campaigns=campaigns,
                max_days=args.days,
                max_coaches=args.coaches,
                progress=bar.update,
                coach_params=coach_params,
            )
    groups, _ = dataset.discover(raw)
    with progress_bar(len(groups), "pipeline", "coach-day") as bar:
        summary = dataset.build_dataset(
            raw,
            out,
            progress=bar.update,
            expected_unreadable=generated.corrupted if generated else (),
            timezone=args.timezone,
        )
    data = {**summary.to_dict(), "raw": str(raw), "out": str(out)}
    if generated is not None:
        data["generated"] = {
            "files": generated.files,
            "rows": generated.rows,
            "coach_days": generated.coach_days,
        }

    def human(d: dict) -> str:
        lines = [f"{'campaign':<15}{'sampling':>9}{'#T':>7}{'#D':>8}"]
        lines += [
            f"{r['campaign']:<15}{r['sampling_min']:>6} min{r['trajectories']:>7}"
            f"{r['mean_points']:>8.0f}"
            for r in d["table"]
        ]
        lines.append("dropped: " + ", ".join(f"{k} {v}" for k, v in d["dropped_rows"].items()))
        lines.append("repaired: " + ", ".join(f"{k} {v}" for k, v in d["repaired_rows"].items()))
        others = len(d["unreadable_files"]) - d["unreadable_as_generated"]
        if d["unreadable_as_generated"]:
            lines.append(f"corrupted files skipped, as generated: {d['unreadable_as_generated']}")
        if others:
            lines.append(f"unreadable files: {others} (see warnings)")
        zone = d["timezone"] or "each campaign's (winter-spring: Europe/Zurich)"
        lines.append(f"times without a zone read in: {zone}")
        lines.append(f"trajectories written under {d['out']}")
        return "\n".join(lines)

    emit(args, data, human)


def register(sub) -> None:
    """Add ``dataset build`` to ``sub``."""
    dsub = add_group(sub, "dataset", "fleet logs and the data pipeline")
    p = add_command(
        dsub,
        "build",
        cmd_dataset_build,
        "generate raw fleet logs (or read --raw) and run the pipeline",
    )
    p.add_argument("--out", required=True, help="output directory (trajectories, dataset.json)")
    p.add_argument("--raw", default=None, help="read raw logs from here instead of generating")
    p.add_argument(
        "--timezone",
        default=None,
        help="the zone of times written without one, e.g. Europe/Zurich (default: each "
        "campaign's: winter-spring local Zurich time; summer files must carry their Z)",
    )
    p.add_argument("--days", type=int, default=None, help="only the first N days per campaign")
    p.add_argument("--coaches", type=int, default=None, help="only the first N coaches")
    p.add_argument(
        "--coach-params",
        default=None,
        help="coach parameter JSON file (coach-params): every generated coach uses it "
        "(default: each coach its own, seeded ±15 %% around the default)",
    )
    p.add_argument(
        "--campaign", action="append", choices=("winter-spring", "summer"), help="repeatable"
    )
