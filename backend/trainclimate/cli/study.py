"""``study fleet``: what the layer would save on a whole fleet over many days, on Dask."""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
from pathlib import Path

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    add_model_options,
    emit,
    objective_of,
    out_dir,
    out_file,
    predictor_from,
    progress_bar,
    warn,
)


def _file_id(path: str | Path) -> str:
    """A file's name and the start of its SHA-256 (what identifies an input of the study)."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
    return f"{Path(path).name}:{digest}"


def fleet_from_file(path: str) -> tuple[tuple[str, ...], tuple[dict, ...]]:
    """The coaches of a fleet file and their parameters.

    The file is JSON: ``{"coaches": [{"coach": ID, "params": {…}}, …]}`` — the shape
    ``calibrate --json`` prints — with each ``params`` in the ``coach-params`` format (missing
    keys take the defaults).

    Raises
    ------
    UsageError
        If the file is missing, not JSON, or a coach or its parameters are malformed.
    """
    from trainclimate.sim.params import CoachParams, ParamsError

    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise UsageError(f"--fleet: no such file {path}") from None
    except (OSError, ValueError) as exc:
        raise UsageError(f"--fleet: {path} is not a JSON file ({exc})") from None
    coaches = data.get("coaches") if isinstance(data, dict) else None
    if not isinstance(coaches, list) or not coaches:
        raise UsageError(f'--fleet: {path} needs {{"coaches": [{{"coach": ID, "params": {{…}}}}]}}')
    ids, params = [], []
    for i, entry in enumerate(coaches):
        if not isinstance(entry, dict) or not isinstance(entry.get("coach"), str):
            raise UsageError(f"--fleet: entry {i} of {path} has no coach id")
        try:
            params.append(CoachParams.from_dict(entry.get("params") or {}).to_dict())
        except ParamsError as exc:
            raise UsageError(f"--fleet: coach {entry['coach']}: {exc}") from None
        ids.append(entry["coach"])
    return tuple(ids), tuple(params)


def _twin_warnings(args: argparse.Namespace, weather, spec) -> list[str]:
    """The warnings of the twins (``--coach-params``, or each coach of ``--fleet``): their
    savings' when their calibration did not validate their response to setpoint changes, and
    theirs whose validated ambient range (:mod:`trainclimate.twin.validity`) the study's
    weather leaves."""
    from trainclimate.sim.params import TWIN_KEY, ParamsError
    from trainclimate.twin import validity

    during = (weather.time >= spec.first_utc()) & (weather.time < spec.end_utc())
    t_amb = weather.t_amb_c[during]
    try:
        if args.fleet:
            coaches = json.loads(Path(args.fleet).read_text())["coaches"]
            records = [(c["coach"], c, f"--fleet: coach {c['coach']}") for c in coaches]
        else:
            file = args.coach_params
            record = json.loads(Path(file).read_text()).get(TWIN_KEY) if file else None
            records = [("the --coaches", record, f"--coach-params {file}")]
        found = [validity.savings_warning(record, where) for _, record, where in records]
        found += [
            validity.range_warning(
                validity.validated_range(record, where), t_amb, f"the study's weather, {who}"
            )
            for who, record, where in records
        ]
    except ParamsError as exc:
        raise UsageError(str(exc)) from None
    return [w for w in found if w]


def _twin_record(args: argparse.Namespace) -> dict:
    """The calibration's record in ``--coach-params`` (what ``--twin-ends`` varies)."""
    from trainclimate.sim.params import TWIN_KEY

    if args.fleet or not args.coach_params:
        raise UsageError(
            "--twin-ends needs --coach-params: a twin's file written by calibrate --out"
        )
    record = json.loads(Path(args.coach_params).read_text()).get(TWIN_KEY)
    if record is None:
        raise UsageError(
            f"--twin-ends: {args.coach_params} carries no calibration (calibrate --out writes one)"
        )
    return record


def _twin_ends(args, spec, record: dict, weather, predictor, savings_pct: float) -> dict:
    """``--twin-ends``: the study again with each fitted knob of the twin at each end of its
    95 % interval, the others as calibrated (one at a time, the same seed and weather), under
    ``<out>/twin-ends/<knob>-<low|high>`` (resumable as the study is). Returns the savings'
    range over those runs and the twin's own, and each run's figures."""
    from trainclimate.sim.params import CoachParams, ParamsError, load_params
    from trainclimate.study.runner import read_chunks, run_study
    from trainclimate.study.summary import summarise
    from trainclimate.twin import validity

    try:
        ends, without = validity.interval_ends(record)
    except ParamsError as exc:
        raise UsageError(f"--twin-ends: {exc}") from None
    base = load_params(args.coach_params)
    runs = []
    for knob, value, side, end in ends:
        try:  # the end must still be a plausible coach
            varied = CoachParams.from_dict(
                validity.at_end(base, knob, value, end).to_dict()
            ).to_dict()
        except ParamsError as exc:
            raise UsageError(f"--twin-ends: {knob} at {end:g}: {exc}") from None
        variant = dataclasses.replace(spec, coach_params=(varied,) * spec.n_coaches)
        where = Path(args.out) / "twin-ends" / f"{knob}-{side}"
        where.mkdir(parents=True, exist_ok=True)
        run_study(variant, where, weather=weather, predictor=predictor,
                  scheduler=args.scheduler, workers=args.workers)  # fmt: skip
        figures = summarise(read_chunks(variant, where), variant)
        kept = {k: figures[k] for k in ("savings_pct", "energy_rule_kwh", "energy_ddpc_kwh")}
        runs.append({"param": knob, "end": side, "value": end, **kept, "out": str(where)})
    found = [r["savings_pct"] for r in runs if r["savings_pct"] is not None] + [savings_pct]
    return {
        "savings_pct": [min(found), max(found)],
        "runs": runs,
        "without_interval": without,
    }


def spec_from_args(args: argparse.Namespace):
    """The :class:`~trainclimate.study.plan.StudySpec` the command's arguments ask for."""
    from trainclimate.sim.params import CoachParams, load_params
    from trainclimate.study.plan import StudySpec

    if args.fleet and args.coaches is not None:
        raise UsageError("give --coaches N or --fleet FILE, not both")
    if args.fleet:
        if args.coach_params:
            raise UsageError("--coach-params is for --coaches N; a --fleet has its own")
        ids, params = fleet_from_file(args.fleet)
    else:
        n = 8 if args.coaches is None else args.coaches
        if n < 1:
            raise UsageError("--coaches must be at least 1")
        base = (load_params(args.coach_params) if args.coach_params else CoachParams()).to_dict()
        ids = tuple(f"S{i + 1:04d}" for i in range(n))
        params = (base,) * n
    return StudySpec(
        coach_ids=ids,
        coach_params=params,
        start=args.start,
        days=args.days,
        controllers=tuple(c.strip() for c in args.controllers.split(",") if c.strip()),
        parked_share=args.parked_share,
        occupancy_scale=args.occupancy_scale,
        coach_spread=args.coach_spread,
        seed=args.seed,
        weather_source=_file_id(args.weather) if args.weather else "generated",
        chunk_coaches=args.chunk_coaches,
        chunk_days=args.chunk_days,
        forecast=args.forecast,
        objective=objective_of(args),
    )


def cmd_study_fleet(args: argparse.Namespace) -> None:
    """``study fleet``: run (or resume) a fleet study and print its answer."""
    from trainclimate.predict.default import default_model_path
    from trainclimate.sim.weather import load_weather_csv
    from trainclimate.study.plan import StudyError, check_weather, study_weather
    from trainclimate.study.report import write_study_report
    from trainclimate.study.runner import check_scheduler, read_chunks, run_study
    from trainclimate.study.summary import summarise

    if args.workers is not None and args.workers < 1:
        raise UsageError("--workers must be at least 1")
    if args.price_chf_kwh < 0 or args.co2_kg_kwh < 0:
        raise UsageError("--price-chf-kwh and --co2-kg-kwh must not be negative")
    measured = load_weather_csv(args.weather) if args.weather else None
    try:
        spec = spec_from_args(args)
        weather = measured or study_weather(spec)
        check_weather(weather, spec)
        check_scheduler(args.scheduler)
    except StudyError as exc:
        raise UsageError(str(exc)) from None
    warnings = _twin_warnings(args, weather, spec)
    record = _twin_record(args) if args.twin_ends else None
    out = out_dir(args.out, "the study's results")
    html = None
    if args.html is not None:  # checked before any work, its directory created
        html = out_file(args.html, "the study's report") if args.html else out / "report.html"
    predictor = predictor_from(args)
    spec = dataclasses.replace(spec, model=_file_id(args.predictor or default_model_path()))
    with progress_bar(spec.coach_days, "study fleet", "coach-day") as bar:

        def progress(chunks: int, coach_days: int) -> None:
            bar.update(coach_days)

        try:
            run = run_study(
                spec,
                out,
                weather=weather,
                predictor=predictor,
                scheduler=args.scheduler,
                workers=args.workers,
                progress=progress,
            )
        except StudyError as exc:
            raise UsageError(str(exc)) from None
    frame = read_chunks(spec, out)
    data = summarise(
        frame, spec, price_chf_per_kwh=args.price_chf_kwh, co2_kg_per_kwh=args.co2_kg_kwh
    )
    data.update(
        chunks=run.chunks,
        chunks_skipped=run.chunks_skipped,
        chunks_run=run.chunks_run,
        workers=run.workers,
        seconds=run.seconds,
        coach_days_run=run.coach_days_run,
        coach_days_per_s=run.coach_days_run / run.seconds if run.seconds else None,
        timings=run.timings,
        fingerprint=spec.fingerprint(),
        study={
            "start": spec.start,
            "days": spec.days,
            "coaches": spec.n_coaches,
            "controllers": list(spec.controllers),
            "parked_share": spec.parked_share,
            "occupancy_scale": spec.occupancy_scale,
            "coach_spread": spec.coach_spread,
            "seed": spec.seed,
            "weather": spec.weather_source,
            "forecast": spec.forecast,
            "objective": spec.objective,
            "model": spec.model,
            "chunk": [spec.chunk_coaches, spec.chunk_days],
        },
        out=str(out),
    )
    if record is not None:
        data["twin_ends"] = _twin_ends(args, spec, record, weather, predictor, data["savings_pct"])
    warn(data, warnings)
    (out / "summary.json").write_text(json.dumps(data, indent=1) + "\n")
    if html is not None:
        data["html"] = str(write_study_report(data, frame, html).resolve())
    emit(args, data, _text)


def _text(d: dict) -> str:
    from trainclimate.study.summary import savings_text

    def pct(v):
        return "–" if v is None else f"{v:.2f} %"

    edge = (
        "; band-edge reference "
        + savings_text(
            d["edge_savings_pct"], d["edge_savings_ci95_pct"], d["edge_savings_ci95_reason"]
        )
        if "edge_savings_pct" in d
        else ""
    )
    ends = d.get("twin_ends")
    ends_text = (
        f"\nthe twin at its intervals' ends ({len(ends['runs'])} runs): savings "
        f"{ends['savings_pct'][0]:.2f} to {ends['savings_pct'][1]:.2f} %"
        if ends
        else ""
    )
    return (
        f"{d['coach_days']} coach-days ({d['coaches']} coaches × {d['days']} days, "
        f"{d['study']['forecast']} forecast): rule-based "
        f"{d['energy_rule_kwh'] / 1e3:.2f} MWh, DDPC {d['energy_ddpc_kwh'] / 1e3:.2f} MWh on the "
        f"{d['meter']} meter: savings "
        f"{savings_text(d['savings_pct'], d['savings_ci95_pct'], d['savings_ci95_reason'])}"
        f"{edge}; {pct(d['savings_by_meter_pct']['hvac_and_floor'])} with the floor heating; "
        f"{d['saved_mwh']:.2f} MWh, {d['saved_chf']:,.0f} CHF, {d['saved_t_co2']:.2f} t CO₂-eq; "
        f"average hourly violation {d['avg_hourly_violation_k']:.4f} K (rule-based "
        f"{d['avg_hourly_violation_rule_k']:.4f} K)\n"
        f"chunks: {d['chunks']} ({d['chunks_skipped']} already done); results in {d['out']}"
        + ends_text
        + (f"\nreport written: {d['html']}" if "html" in d else "")
    )


def register(sub) -> None:
    """Add ``study fleet`` to ``sub``."""
    from trainclimate.study.summary import CO2_KG_PER_KWH, PRICE_CHF_PER_KWH

    group = add_group(sub, "study", "fleet studies on Dask")
    p = add_command(
        group,
        "fleet",
        cmd_study_fleet,
        "rule-based against DDPC on a whole fleet over many days, in chunks on Dask "
        "(resumable: a re-run on the same --out skips finished chunks)",
    )
    p.add_argument("--coaches", type=int, default=None, help="fleet size (default 8)")
    p.add_argument("--fleet", default=None, help="fleet file: calibrate --json output")
    p.add_argument("--coach-params", default=None, help="the --coaches' parameter file")
    p.add_argument("--twin-ends", action="store_true",
                   help="run again with each fitted knob of the --coach-params twin at each end of "
                   "its 95 %% interval: the savings' sensitivity to the twin")  # fmt: skip
    p.add_argument("--start", default="2025-01-01", help="first local day (default 2025-01-01)")
    p.add_argument("--days", type=int, default=7, help="number of days (default 7)")
    p.add_argument("--weather", default=None, help="weather CSV (time,t_amb_c,ghi_w_m2)")
    p.add_argument("--parked-share", type=float, default=0.15,
                   help="share of coach-days parked in regular mode (0.15)")  # fmt: skip
    p.add_argument("--occupancy-scale", type=float, default=1.0,
                   help="factor on the service's occupancy (default 1)")  # fmt: skip
    p.add_argument("--controllers", default="rule,ddpc", help="rule,ddpc or rule,ddpc,edge")
    p.add_argument("--coach-spread", type=float, nargs="?", const=0.15, default=0.15,
                   help="coach parameters drawn ±this around their own (0.15)")  # fmt: skip
    p.add_argument("--seed", type=int, default=2025, help="seed (default 2025)")
    p.add_argument("--scheduler", default="local", help="local or tcp://HOST:PORT")
    p.add_argument("--workers", type=int, default=None, help="local workers (default: CPUs)")
    p.add_argument("--chunk-coaches", type=int, default=64, help="coaches per chunk (64)")
    p.add_argument("--chunk-days", type=int, default=7, help="days per chunk (7)")
    p.add_argument("--out", default="out/study", help="results directory (default out/study)")
    p.add_argument("--html", nargs="?", const="", default=None,
                   help="write the HTML report (default: OUT/report.html)")  # fmt: skip
    p.add_argument("--price-chf-kwh", type=float, default=PRICE_CHF_PER_KWH,
                   help=f"electricity price (default {PRICE_CHF_PER_KWH})")  # fmt: skip
    p.add_argument("--co2-kg-kwh", type=float, default=CO2_KG_PER_KWH,
                   help=f"emission factor (default {CO2_KG_PER_KWH})")  # fmt: skip
    add_model_options(p, "ddpc: ", forecast="persistence")
