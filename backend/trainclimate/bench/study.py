"""``bench study``: fleet-study throughput on Dask, its scaling, its memory, where a coach-tick's
time goes, and what a fleet-year would take.

1. The same study (``coaches`` × ``days``, rule + DDPC, chunks of ``chunk_coaches`` × 1 day) on a
   LocalCluster of 1 worker and of 2 workers, each into a fresh ``--out``: coach-days/s and the
   ratio (the two runs must give the same totals).
2. Each chunk's worker peak resident memory, in completion order: the first chunks' against the
   last ones' shows whether memory grows with the study's length.
3. One chunk profiled in this process (cProfile): the time of the simulator's steps, the DDPC
   controller's state estimate, T_opt run and OCP solve, per coach-tick.
4. The fleet-year (``FLEET_COACHES`` × 365 days, rule + DDPC): the 1-worker seconds per
   coach-day times its coach-days, divided by N cores at the 2-worker run's parallel efficiency.
"""

from __future__ import annotations

import cProfile
import pstats
import tempfile
from pathlib import Path

from trainclimate.bench.common import machine

#: The fleet of the fleet-year estimate (SBB's Regio-Dosto half coaches, order of magnitude).
FLEET_COACHES = 900
#: Target: the fleet-year on a 64-core cluster within an hour. [h]
TARGET = {"fleet_year_64_cores_h": 1.0}


def _spec(coaches: int, days: int, chunk_coaches: int, model: str):
    from trainclimate.sim.params import CoachParams
    from trainclimate.study.plan import StudySpec

    return StudySpec(
        coach_ids=tuple(f"B{i:04d}" for i in range(coaches)),
        coach_params=(CoachParams().to_dict(),) * coaches,
        start="2025-01-13",
        days=days,
        chunk_coaches=chunk_coaches,
        chunk_days=1,
        model=model,
    )


def _profile(spec, weather, predictor) -> dict:
    """One chunk in this process under cProfile: the cumulative time of each part, per
    coach-tick of the DDPC run (ms) and in all (s)."""
    from trainclimate.study.chunk import run_chunk

    prof = cProfile.Profile()
    prof.enable()
    frame = run_chunk(spec, spec.chunks()[0], weather, predictor)
    prof.disable()
    stats = pstats.Stats(prof).stats  # (file, line, name) → (cc, nc, tt, ct, callers)

    def cumulative(file_end: str, name: str) -> float:
        return sum(v[3] for k, v in stats.items() if k[0].endswith(file_end) and k[2] == name)

    parts = {
        "simulator_step": cumulative("sim/simulator.py", "step"),
        "closed_loop_tick": cumulative("control/closed_loop.py", "_tick"),
        "controller_step": cumulative("control/controller.py", "step"),
        "state_estimate": cumulative("control/estimator.py", "run")
        + cumulative("control/estimator.py", "update"),
        "t_opt": cumulative("control/controller.py", "t_opt"),
        "ocp_solve": cumulative("control/ocp.py", "solve"),
        "osqp": cumulative("osqp/interface.py", "solve"),
    }
    ticks = sum(frame.attrs["ddpc_ticks"].values())
    return {
        "coach_ticks": ticks,
        "total_s": sum(frame.attrs["seconds"].values()),
        "seconds": parts,
        "per_coach_tick_ms": {k: 1e3 * v / ticks for k, v in parts.items()},
    }


def run(coaches: int = 128, days: int = 2, chunk_coaches: int = 64, progress=None) -> dict:
    """The figures (see the module docstring); ``progress(1)`` after each of the four stages."""
    from trainclimate.predict.default import default_model_path, default_predictor
    from trainclimate.study.plan import study_weather
    from trainclimate.study.runner import read_chunks, run_study
    from trainclimate.study.summary import summarise

    predictor = default_predictor()
    spec = _spec(coaches, days, chunk_coaches, default_model_path().name)
    weather = study_weather(spec)
    runs, totals = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            out = Path(tmp) / f"w{workers}"
            run_ = run_study(spec, out, weather=weather, predictor=predictor, workers=workers)
            runs[workers] = run_
            totals[workers] = summarise(read_chunks(spec, out), spec)
            if progress:
                progress(1)
    profile = _profile(_spec(chunk_coaches, 1, chunk_coaches, spec.model), weather, predictor)
    if progress:
        progress(1)
    rate = {w: r.coach_days_run / r.seconds for w, r in runs.items()}
    efficiency = rate[2] / (2 * rate[1])
    s_per_coach_day = 1.0 / rate[1]
    fleet_year = FLEET_COACHES * 365
    core_h = fleet_year * s_per_coach_day / 3600.0
    rss = runs[2].timings["worker_peak_rss_mb"]
    half = max(1, len(rss) // 2)
    estimate = {n: core_h / (n * efficiency) for n in (2, 8, 64)}
    if progress:
        progress(1)
    return {
        "coaches": coaches,
        "days": days,
        "chunk": [chunk_coaches, 1],
        "coach_days": spec.coach_days,
        "coach_days_per_s_1_worker": rate[1],
        "coach_days_per_s_2_workers": rate[2],
        "scaling_2_over_1": rate[2] / rate[1],
        "parallel_efficiency": efficiency,
        "same_totals": totals[1]["energy_ddpc_kwh"] == totals[2]["energy_ddpc_kwh"]
        and totals[1]["energy_rule_kwh"] == totals[2]["energy_rule_kwh"],
        "savings_pct": totals[2]["savings_pct"],
        "worker_peak_rss_mb": rss,
        "worker_peak_rss_first_half_mb": max(rss[:half]),
        "worker_peak_rss_second_half_mb": max(rss[half:]) if rss[half:] else max(rss),
        "profile": profile,
        "fleet_year": {
            "coaches": FLEET_COACHES,
            "coach_days": fleet_year,
            "seconds_per_coach_day_1_worker": s_per_coach_day,
            "core_hours": core_h,
            "hours_on_cores": {str(n): h for n, h in estimate.items()},
        },
        "target": TARGET,
        "target_met": estimate[64] <= TARGET["fleet_year_64_cores_h"],
        "machine": machine(),
    }


def text(d: dict) -> str:
    """The throughput, scaling, memory, profile and fleet-year lines."""
    fy = d["fleet_year"]
    per = d["profile"]["per_coach_tick_ms"]
    return (
        f"{d['coach_days']} coach-days (rule + DDPC, chunks {d['chunk'][0]}×1 day): "
        f"{d['coach_days_per_s_1_worker']:.2f} coach-days/s on 1 worker, "
        f"{d['coach_days_per_s_2_workers']:.2f} on 2 (×{d['scaling_2_over_1']:.2f}, efficiency "
        f"{d['parallel_efficiency']:.0%}); same totals: {d['same_totals']}\n"
        f"worker peak memory: first chunks {d['worker_peak_rss_first_half_mb']:.0f} MB, last "
        f"{d['worker_peak_rss_second_half_mb']:.0f} MB\n"
        f"per coach-tick (cProfile, ms): simulator steps {per['simulator_step']:.2f}, controller "
        f"{per['controller_step']:.3f} (estimate {per['state_estimate']:.3f}, T_opt "
        f"{per['t_opt']:.3f}, solve {per['ocp_solve']:.3f})\n"
        f"fleet-year ({fy['coaches']} coaches × 365 days): {fy['core_hours']:.1f} core-hours; "
        + ", ".join(f"{h:.2f} h on {n} cores" for n, h in fy["hours_on_cores"].items())
    )
