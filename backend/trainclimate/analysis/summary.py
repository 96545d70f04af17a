"""Per-coach KPIs of a simulation run, as the ``simulate`` command reports them."""

from __future__ import annotations

from typing import Any

import numpy as np

from trainclimate.analysis.kpi import avg_hourly_violation_k, discomfort_kh, energy_kwh
from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.coach.setpoint import COMFORT_BAND_K
from trainclimate.sim.simulator import SimulationResult


def coach_kpis(result: SimulationResult, coach: int, t_max_k: float = COMFORT_BAND_K) -> dict:
    """The KPIs of one coach of a simulation run, from its true room temperatures.

    Discomfort and violation count the time in regular mode, when the comfort band applies.

    Parameters
    ----------
    result : SimulationResult
        The run.
    coach : int
        Coach index.
    t_max_k : float, default COMFORT_BAND_K
        Comfort half-band T_max. [K]

    Returns
    -------
    dict
        ``energy_kwh`` (kWh), ``mean_power_kw`` (kW), ``discomfort_kh`` (K·h, mean over decks),
        ``avg_hourly_violation_k`` (K) and ``regular_mode_hours`` (h).
    """
    s = len(result.time)
    in_service = result.env.mode[:s, coach] == MODE_REGULAR
    t_room, t_rule = result.t_room_c[:, coach], result.t_rule_c[:, coach]
    power_kw = result.total_power_w[:, coach] / 1e3
    return {
        "energy_kwh": energy_kwh(power_kw, result.dt_s),
        "mean_power_kw": float(power_kw.mean()) if s else 0.0,
        "discomfort_kh": float(
            discomfort_kh(t_room, t_rule, result.dt_s, t_max_k=t_max_k, mask=in_service).mean()
        ),
        "avg_hourly_violation_k": avg_hourly_violation_k(
            t_room, t_rule, result.dt_s, t_max_k=t_max_k, mask=in_service
        ),
        "regular_mode_hours": float(np.count_nonzero(in_service) * result.dt_s / 3600.0),
    }


def fleet_kpis(result: SimulationResult, t_max_k: float = COMFORT_BAND_K) -> dict:
    """The KPIs of every coach of a simulation run, and their mean.

    Parameters
    ----------
    result : SimulationResult
        The run.
    t_max_k : float, default COMFORT_BAND_K
        Comfort half-band T_max. [K]

    Returns
    -------
    dict
        The keys of :func:`coach_kpis`, averaged over the coaches, plus ``hours`` (h, the run's
        length) and ``coaches`` (the list of per-coach dicts).
    """
    per_coach = [coach_kpis(result, c, t_max_k) for c in range(result.t_ref_c.shape[1])]
    out: dict[str, Any] = {key: float(np.mean([c[key] for c in per_coach])) for key in per_coach[0]}
    out["hours"] = len(result.time) * result.dt_s / 3600.0
    out["coaches"] = per_coach
    return out
