"""One chunk of a fleet study: its coaches over its days, under every controller, in closed loop.

Each day the chunk's coaches are one vectorised fleet (:class:`~trainclimate.sim.simulator.
FleetSimulator`), run once per controller from the same initial state and the same sensor-noise
seed: ``rule`` (T_ref = T_rule, the baseline), ``ddpc`` (the layer, :class:`~trainclimate.
control.closed_loop.ClosedLoop`) and optionally ``edge`` (the band-edge reference). The result
is a table with one row per coach, day and *situation*, classified step by step from the
baseline's run, so every controller is counted over the same steps:

- ``parked heating`` / ``parked cooling``: a parked coach-day (regular mode all day) whose HVAC
  heats or cools;
- ``in service``: regular mode on a service day, the HVAC heating or cooling;
- ``mixed mode``: the HVAC heats one deck and cools another (any day);
- ``off or slumber``: depot, layovers and the night — the layer does not act there.

Energy is counted on both meters (:data:`~trainclimate.coach.meters.METERS`: the HVAC units alone,
the headline, and the whole coach with floor and wall heating), over every step; comfort as
the discomfort of the true deck temperatures against T_rule ± 1 K (paper, Eq. (4)), over the
regular-mode steps.
"""

from __future__ import annotations

import resource
import time

import numpy as np
import pandas as pd
import psutil

from trainclimate.analysis.kpi import violation_k
from trainclimate.coach.meters import HEADLINE_METER, METERS
from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.coach.states import COOLING, MIXED, PRECOOLING
from trainclimate.control.closed_loop import ClosedLoop, build_controllers
from trainclimate.control.ocp import OFFLINE_TIME_LIMIT_S, OCPSettings
from trainclimate.predict.base import MultistepPredictor
from trainclimate.sim.seeding import seed_of
from trainclimate.sim.simulator import FleetSimulator, SimulationResult
from trainclimate.sim.weather import Weather
from trainclimate.study.plan import Chunk, StudySpec, day_environment

SITUATIONS = ("parked heating", "parked cooling", "in service", "mixed mode", "off or slumber")
_PARKED_HEATING, _PARKED_COOLING, _IN_SERVICE, _MIXED, _OFF = range(len(SITUATIONS))
#: The meter beside the headline one.
OTHER_METER = next(m for m in METERS if m != HEADLINE_METER)


def situations(result: SimulationResult, parked: np.ndarray) -> np.ndarray:
    """Each step's situation (an index into :data:`SITUATIONS`), from a run's HVAC state.

    Parameters
    ----------
    result : SimulationResult
        The baseline's run, S steps of N coaches.
    parked : numpy.ndarray of bool, shape (N,)
        Whether each coach is parked all day.

    Returns
    -------
    numpy.ndarray of int, shape (S, N)
    """
    state = result.hvac_state
    regular = result.env.mode[: len(state)] == MODE_REGULAR
    cooling = np.isin(state, (COOLING, PRECOOLING))
    out = np.where(
        parked[None, :], np.where(cooling, _PARKED_COOLING, _PARKED_HEATING), _IN_SERVICE
    )
    out = np.where(state == MIXED, _MIXED, out)
    return np.where(regular, out, _OFF)


def _sums(code: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per coach and situation: the sum of ``values`` (S, N) over the steps of that situation,
    shape (N, len(SITUATIONS))."""
    n = code.shape[1]
    flat = code + np.arange(n)[None, :] * len(SITUATIONS)
    return np.bincount(flat.ravel(), weights=values.ravel(), minlength=n * len(SITUATIONS)).reshape(
        n, len(SITUATIONS)
    )


def _measures(result: SimulationResult, code: np.ndarray) -> dict[str, np.ndarray]:
    """Energy on both meters (kWh) and discomfort (K·h, mean of the decks, regular steps only)
    per coach and situation."""
    h = result.dt_s / 3600.0
    regular = result.env.mode[: len(code)] == MODE_REGULAR
    discomfort = violation_k(result.t_room_c, result.t_rule_c).mean(axis=-1) * regular
    return {
        "energy": _sums(code, result.meter_w(HEADLINE_METER)) * h / 1e3,
        "energy_other": _sums(code, result.meter_w(OTHER_METER)) * h / 1e3,
        "discomfort": _sums(code, discomfort) * h,
    }


def run_chunk(
    spec: StudySpec,
    chunk: Chunk,
    weather: Weather,
    predictor: MultistepPredictor | None,
) -> pd.DataFrame:
    """Simulate ``chunk`` of ``spec`` under every controller of the study.

    Parameters
    ----------
    spec : StudySpec
        The study.
    chunk : Chunk
        Which coaches and days.
    weather : Weather
        The study's weather (covering its days).
    predictor : MultistepPredictor or None
        The DDPC layer's model.

    Returns
    -------
    pandas.DataFrame
        One row per coach, day and situation with time in it: ``coach``, ``coach_index``,
        ``day`` (local date), ``parked``, ``situation``, ``t_amb_mean_c`` (the coach-day's
        mean, °C), ``hours`` and ``regular_hours`` (h), and per controller X ``energy_X_kwh``
        (the HVAC units), ``energy_whole_X_kwh`` (with floor and wall heating) and
        ``discomfort_X_kh`` (K·h). ``attrs`` carries the chunk's timings (s), the DDPC
        layer's ticks by reason, and the worker's peak and current resident memory (MB).
    """
    coaches = range(chunk.coach_lo, chunk.coach_hi)
    params = [spec.params_of(c) for c in coaches]
    n = len(coaches)
    loop_controllers = {
        kind: build_controllers(
            kind,
            n,
            predictor if kind == "ddpc" else None,
            OCPSettings(objective=spec.objective, time_limit_s=OFFLINE_TIME_LIMIT_S),
        )
        for kind in spec.controllers
        if kind != "rule"
    }
    frames = []
    seconds = dict.fromkeys(spec.controllers, 0.0)
    reasons: dict[str, int] = {}
    step_s = 0.0
    for day in range(chunk.day_lo, chunk.day_hi):
        env, plans = day_environment(spec, weather, coaches, day)
        parked = np.array([p.parked for p in plans])
        noise_seed = seed_of(spec.seed, 3, chunk.coach_lo, day)
        measures, code = {}, None
        for kind in spec.controllers:
            t0 = time.perf_counter()
            sim = FleetSimulator(params, env, seed=noise_seed)
            if kind == "rule":
                sim.run()
            else:
                loop = ClosedLoop(
                    sim,
                    loop_controllers[kind],
                    forecast="perfect" if kind == "edge" else spec.forecast,
                    seed=noise_seed,
                )
                sim.run(loop)
                if kind == "ddpc":
                    for r in loop.log.results:
                        reasons[r.reason] = reasons.get(r.reason, 0) + 1
                        step_s += r.step_time_s
            result = sim.result()
            if code is None:
                code = situations(result, parked)
            measures[kind] = _measures(result, code)
            seconds[kind] += time.perf_counter() - t0
        hours = _sums(code, np.ones(code.shape)) * env.dt_s / 3600.0
        regular = env.mode == MODE_REGULAR
        regular_hours = _sums(code, regular.astype(float)) * env.dt_s / 3600.0
        t_amb = float(np.mean(env.t_amb_c))
        for i, c in enumerate(coaches):
            for s, name in enumerate(SITUATIONS):
                if hours[i, s] == 0:
                    continue
                row = {
                    "coach": spec.coach_ids[c],
                    "coach_index": c,
                    "day": spec.dates[day],
                    "parked": bool(parked[i]),
                    "situation": name,
                    "t_amb_mean_c": t_amb,
                    "hours": hours[i, s],
                    "regular_hours": regular_hours[i, s],
                }
                for kind, m in measures.items():
                    row[f"energy_{kind}_kwh"] = m["energy"][i, s]
                    row[f"energy_whole_{kind}_kwh"] = m["energy_other"][i, s]
                    row[f"discomfort_{kind}_kh"] = m["discomfort"][i, s]
                frames.append(row)
    frame = pd.DataFrame(frames)
    frame.attrs = {
        "seconds": seconds,
        "ddpc_controller_s": step_s,
        "ddpc_ticks": reasons,
        "coach_days": chunk.coach_days,
        "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "worker_rss_mb": psutil.Process().memory_info().rss / 2**20,
    }
    return frame
