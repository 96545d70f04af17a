"""A pair's 30-minute windows labelled by what each coach really ran, and its trial estimate.

A window counts towards the savings only where one coach ran under the layer (every tick in the
window a DDPC setpoint) and the other on T_rule with the layer off (every tick ``rule`` /
``inactive``, or ``costing_energy`` where the train's guard handed the layer back); a window
where both ran on T_rule with the layer off is a *reference* window (the coaches' own ratio).
Every other window is excluded with its reason, first that applies:

- from the telemetry: ``disconnected`` (a coach's link to its HVAC lost), ``override`` (an
  operator's setpoint in force), ``missing_data`` (a minute missing, or without power);
- from the setpoints: ``no_setpoint`` (a coach had no tick), ``override``, ``preparing`` (no
  predictor model yet), ``fallback`` (a DDPC fallback: stale data, solver, …), ``not_regular``
  (the HVAC not in regular mode, where the layer does not act), ``mixed_roles`` (the roles
  changed within the window, or both coaches ran the layer);
- ``plan_switch``: the lead-in after the activated coach changed (:data:`LEAD_IN_MIN`), while the
  coaches' temperatures settle to their new roles.

Counted windows are summed per service day and estimated by :mod:`trainclimate.analysis.trial`
(crossover where both coaches had activated days, corrected by reference days, or the naive
figure labelled as confounded). The pair comparison and the fleet summary both build their
figures here, from the same window sums (:func:`.fleet_summary.window_sums`) and setpoint
counts (:func:`setpoint_counts`).
"""

from __future__ import annotations

from datetime import datetime
from typing import cast

import numpy as np
import pandas as pd
from sqlalchemy import Table, select
from sqlalchemy.orm import Session

from trainclimate.analysis import trial
from trainclimate.analysis.savings import PairTotals, savings_pct
from trainclimate.service.store import setpoint_rollups
from trainclimate.service.store.models import Setpoint
from trainclimate.service.store.setpoint_rollups import COUNTS
from trainclimate.service.store.sqltime import EpochSeconds
from trainclimate.sim.power import HEADLINE_METER, METERS

#: What :func:`.fleet_summary.window_sums` returns per window, in order.
SUMS = (
    "minutes",
    "affected_minutes",
    "energy_0_kwh",
    "energy_1_kwh",
    "counted_minutes",
    *(f"discomfort_0_{d}_kh" for d in ("up", "mid", "low")),
    *(f"discomfort_1_{d}_kh" for d in ("up", "mid", "low")),
    "energy_0_hvac_kwh",
    "energy_1_hvac_kwh",
    "unsplit_minutes",
    "disconnected_minutes",
    "overridden_minutes",
)
#: Name → column of the :data:`SUMS`.
SUMS_INDEX = {name: i for i, name in enumerate(SUMS)}

#: After the activated coach changes, windows starting within this are excluded. [min]
LEAD_IN_MIN = 60.0
#: A service day counts with at least this many counted windows.
MIN_DAY_WINDOWS = 4
#: No coach activated in the window, or its label unknown (excluded).
UNLABELLED = -2


def setpoint_counts(
    session: Session, coaches: list[str], lo: datetime, hi: datetime, window_min: float
) -> dict[str, dict[int, np.ndarray]]:
    """Per coach and window, how many ticks in [lo, hi) issued what
    (:data:`~.setpoint_rollups.COUNTS`). A setpoint issued at tick t acts from t: its window is
    ⌊t / window⌋. Read from the setpoint rollups (:mod:`.setpoint_rollups`) when the windows are
    theirs (30 minutes, ``lo`` and ``hi`` on window boundaries), else counted over the setpoints
    (:func:`setpoint_counts_raw`).

    Parameters
    ----------
    coaches : list of str
    lo, hi : datetime
        The ticks counted. (timezone-aware)
    window_min : float
        Window length. [min]

    Returns
    -------
    dict
        Coach id → window index (the window's start in window lengths since 1970) → counts.
    """
    window_s = setpoint_rollups.WINDOW_MIN * 60
    lo_s, hi_s = lo.timestamp(), hi.timestamp()
    if window_min != setpoint_rollups.WINDOW_MIN or lo_s % window_s or hi_s % window_s:
        return setpoint_counts_raw(session, coaches, lo, hi, window_min)
    lo_w, hi_w = round(lo_s) // window_s, round(hi_s) // window_s
    return {
        cid: dict(zip(index.tolist(), counts, strict=True))
        for cid, (index, counts) in setpoint_rollups.read(session, coaches, lo_w, hi_w).items()
    }


def setpoint_counts_raw(
    session: Session, coaches: list[str], lo: datetime, hi: datetime, window_min: float
) -> dict[str, dict[int, np.ndarray]]:
    """:func:`setpoint_counts` over the setpoints themselves, in one statement (any window
    length and range)."""
    if not coaches:
        return {}
    t = cast(Table, Setpoint.__table__)
    window = (EpochSeconds(t.c.tick) // round(window_min * 60)).label("w")
    rows = session.execute(
        select(t.c.coach_id, window, *setpoint_rollups.aggregates(t))
        .where(t.c.coach_id.in_(coaches), t.c.tick >= lo, t.c.tick < hi)
        .group_by(t.c.coach_id, window)
    ).all()
    out: dict[str, dict[int, np.ndarray]] = {}
    for cid, w, *values in rows:
        out.setdefault(cid, {})[int(w)] = np.array(values, float)
    return out


def labels(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which coach ran the layer in each window, from both coaches' setpoint counts.

    Parameters
    ----------
    counts : numpy.ndarray of shape (W, 2, len(COUNTS))
        Per window, coach 0's and coach 1's :data:`COUNTS`.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The label per window (W,): 0 or 1 (the coach under the layer, the other on T_rule),
        :data:`~trainclimate.analysis.trial.NEITHER` (both on T_rule, layer off: reference) or
        :data:`UNLABELLED`; and the reason a window is not labelled (W,), None where it is.
    """
    c = {name: counts[:, :, i] for i, name in enumerate(COUNTS)}
    ticks = c["ticks"]
    ddpc = (ticks > 0) & (c["ddpc"] == ticks)
    rule = (ticks > 0) & (c["inactive"] == ticks)
    label = np.full(len(counts), UNLABELLED)
    label[ddpc[:, 0] & rule[:, 1]] = 0
    label[ddpc[:, 1] & rule[:, 0]] = 1
    label[rule[:, 0] & rule[:, 1]] = trial.NEITHER
    conditions = [
        (ticks == 0).any(axis=1),
        (c["override"] > 0).any(axis=1),
        (c["no_model"] > 0).any(axis=1),
        (c["fallback"] > 0).any(axis=1),
        (c["not_regular"] > 0).any(axis=1),
    ]
    reasons = ["no_setpoint", "override", "preparing", "fallback", "not_regular"]
    reason = np.select(conditions, reasons, default="mixed_roles").astype(object)
    reason[label != UNLABELLED] = None
    return label, reason


def lead_in(label: np.ndarray, window_min: float, lead_in_min: float = LEAD_IN_MIN) -> np.ndarray:
    """The windows within ``lead_in_min`` of a change of the activated coach (between labelled
    windows: 0, 1 or reference), shape (W,) bool."""
    out = np.zeros(len(label), bool)
    n = int(np.ceil(lead_in_min / window_min))
    previous = None
    for w, x in enumerate(label):
        if x == UNLABELLED:
            continue
        if previous is not None and x != previous:
            out[w : w + n] = True
        previous = x
    return out


def exclusions(sums: np.ndarray, window_min: float) -> np.ndarray:
    """The telemetry's reason to exclude each window (W,), None where it has none: a coach's
    link lost, an override in force, a minute missing or without power."""
    minutes = sums[:, SUMS_INDEX["minutes"]]
    affected = sums[:, SUMS_INDEX["affected_minutes"]]
    conditions = [
        sums[:, SUMS_INDEX["disconnected_minutes"]] > 0,
        sums[:, SUMS_INDEX["overridden_minutes"]] > 0,
        (minutes < round(window_min)) | (affected > 0),
    ]
    reasons = np.select(conditions, ["disconnected", "override", "missing_data"], default="")
    return np.where(reasons == "", None, reasons).astype(object)


def windows(
    sums: np.ndarray,
    counts: np.ndarray,
    window_min: float,
    lead_in_min: float = LEAD_IN_MIN,
) -> tuple[np.ndarray, np.ndarray]:
    """Each window's label and reason to exclude it (see the module docstring).

    Parameters
    ----------
    sums : numpy.ndarray of shape (W, S)
        The pair's consecutive windows' sums (:data:`SUMS`, coach 0 first).
    counts : numpy.ndarray of shape (W, 2, len(COUNTS))
        Both coaches' setpoint counts per window.
    window_min : float
        Window length. [min]
    lead_in_min : float
        See :func:`lead_in`. [min]

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Labels (W,) as :func:`labels`, and the reason per window (W,), None where it counts
        (a window labelled reference counts for the reference estimate only).
    """
    label, reason = labels(counts)
    telemetry = exclusions(sums, window_min)
    reason = np.where(telemetry != None, telemetry, reason)  # noqa: E711 (element-wise)
    switching = lead_in(label, window_min, lead_in_min) & (reason == None)  # noqa: E711
    reason[switching] = "plan_switch"
    return label, reason


def pair_totals(
    grid: np.ndarray,
    label: np.ndarray,
    counted: np.ndarray,
    window_min: float,
    meter_columns: tuple[int, int],
) -> PairTotals:
    """The pair's totals on one meter over its counted windows (activated and deactivated by
    each window's label); violation and discomfort over the minutes in band, nothing affected,
    of every window in which a coach ran the layer (counted or not: an excluded window's
    comfort still happened).

    Parameters
    ----------
    grid : numpy.ndarray of shape (W, S)
        Window sums, coach 0 first.
    label : numpy.ndarray of int, shape (W,)
    counted : numpy.ndarray of bool, shape (W,)
        Windows labelled 0 or 1 and not excluded.
    window_min : float
        Window length. [min]
    meter_columns : (int, int)
        Coach 0's and coach 1's energy columns of the meter.
    """
    e0, e1 = grid[:, meter_columns[0]], grid[:, meter_columns[1]]
    one = label == 1
    e_act, e_deact = np.where(one, e1, e0), np.where(one, e0, e1)
    d0 = grid[:, [SUMS_INDEX[f"discomfort_0_{d}_kh"] for d in ("up", "mid", "low")]]
    d1 = grid[:, [SUMS_INDEX[f"discomfort_1_{d}_kh"] for d in ("up", "mid", "low")]]
    roles = label >= 0
    d_act = np.where(one[:, None], d1, d0)
    d_deact = np.where(one[:, None], d0, d1)
    return PairTotals(
        energy_activated_kwh=float(e_act[counted].sum()),
        energy_deactivated_kwh=float(e_deact[counted].sum()),
        windows=len(grid),
        excluded_windows=int(len(grid) - counted.sum()),
        window_min=window_min,
        counted_hours=float(grid[roles, SUMS_INDEX["counted_minutes"]].sum() / 60.0),
        discomfort_kh=d_act[roles].sum(axis=0),
        baseline_discomfort_kh=d_deact[roles].sum(axis=0),
    )


def estimate(
    index: np.ndarray,
    energy: np.ndarray,
    label: np.ndarray,
    reason: np.ndarray,
    window_min: float,
    switch_hour: int = trial.DEFAULT_SWITCH_HOUR,
) -> trial.TrialEstimate:
    """The pair's trial estimate from its windows: counted and reference windows summed per
    service day (:func:`trial.daily`), then :func:`trial.estimate`. With counted windows but no
    day of :data:`MIN_DAY_WINDOWS`, the naive figure over them (confounded).

    Parameters
    ----------
    index : numpy.ndarray of int, shape (W,)
        Window indices (starts in window lengths since 1970).
    energy : numpy.ndarray of shape (W, 2)
        Coach 0's and coach 1's energy per window on the headline meter. [kWh]
    label, reason : numpy.ndarray of shape (W,)
        From :func:`windows`.
    window_min : float
        Window length. [min]
    switch_hour : int
        The train's local switch hour. [h]
    """
    starts = pd.to_datetime(index * round(window_min * 60), unit="s", utc=True)
    usable = reason == None  # noqa: E711 (element-wise)
    days = trial.daily(
        trial.service_days(starts, switch_hour),
        energy,
        np.where(usable, label, trial.NEITHER),
        usable & (label != UNLABELLED),
        min_windows=MIN_DAY_WINDOWS,
    )
    result = trial.estimate(days)
    counted = usable & (label >= 0)
    if result.estimator is None and counted.any():
        act = energy[counted, label[counted]].sum()
        deact = energy[counted, 1 - label[counted]].sum()
        naive = savings_pct(act, deact)
        why = "fewer than a day's windows: the saving is confounded with the coaches"
        return trial.TrialEstimate("fixed_naive", naive, None, why, naive, result.days)
    return result


def excluded_minutes_by_reason(reason: np.ndarray, window_min: float) -> dict[str, float]:
    """Reason → minutes of the windows excluded for it. [min]"""
    values, n = np.unique([r for r in reason if r is not None], return_counts=True)
    return {str(v): float(k * window_min) for v, k in zip(values, n, strict=True)}


def pair_windows(
    sums: dict[int, np.ndarray], first: pd.Timestamp, n_windows: int, window_min: float
) -> tuple[np.ndarray, np.ndarray]:
    """A pair's ``n_windows`` windows from ``first``, from its :func:`.fleet_summary.window_sums`.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The windows' indices (n,) (starts in window lengths since 1970) and their sums
        (n, len(SUMS)) — zeros where the pair has no row.
    """
    w0 = int(first.timestamp() // (window_min * 60))
    index = np.arange(w0, w0 + n_windows)
    grid = np.array([sums.get(w, np.zeros(len(SUMS))) for w in index]).reshape(-1, len(SUMS))
    return index, grid


def energy_columns(meter: str) -> tuple[int, int]:
    """The columns of :data:`SUMS` with coach 0's and coach 1's energy on ``meter``."""
    suffix = "_kwh" if meter == "hvac_and_floor" else "_hvac_kwh"
    return SUMS_INDEX[f"energy_0{suffix}"], SUMS_INDEX[f"energy_1{suffix}"]


def pair_result(
    coaches: tuple[str, str],
    sums: dict[int, np.ndarray],
    counts: dict[str, dict[int, np.ndarray]],
    first: pd.Timestamp,
    n_windows: int,
    window_min: float,
    switch_hour: int = trial.DEFAULT_SWITCH_HOUR,
) -> dict:
    """A pair's figures over its windows: each window labelled and excluded with its reason
    (:func:`.windows`), the totals on each meter over the counted windows, and the
    trial estimate on the headline meter.

    Parameters
    ----------
    coaches : (str, str)
        Coach 0 and coach 1.
    sums : dict
        The pair's :func:`.fleet_summary.window_sums` (window index → sums).
    counts : dict
        :func:`.setpoint_counts` of (at least) both coaches.
    first : pandas.Timestamp
        The first window's start.
    n_windows : int
        How many windows are counted.
    window_min : float
        Window length. [min]
    switch_hour : int
        The train's local switch hour. [h]

    Returns
    -------
    dict
        ``index``, ``grid``, ``label``, ``reason``, ``counted`` (arrays per window), ``meter``
        (the HVAC units' when every counted minute splits the floor heating off, else the
        whole coach's), ``totals`` (meter → :class:`PairTotals`) and ``estimate``
        (:class:`~trainclimate.analysis.trial.TrialEstimate`).
    """
    index, grid = pair_windows(sums, first, n_windows, window_min)
    zeros = np.zeros(len(COUNTS))
    per_window = np.array(
        [[counts.get(c, {}).get(int(w), zeros) for c in coaches] for w in index]
    ).reshape(len(index), 2, len(COUNTS))
    label, reason = windows(grid, per_window, window_min)
    counted = (reason == None) & (label >= 0)  # noqa: E711 (element-wise)
    split = not np.any(grid[counted, SUMS_INDEX["unsplit_minutes"]] > 0)
    meters = METERS if split else ("hvac_and_floor",)
    totals = {m: pair_totals(grid, label, counted, window_min, energy_columns(m)) for m in meters}
    meter = HEADLINE_METER if split else "hvac_and_floor"
    result = estimate(
        index, grid[:, list(energy_columns(meter))], label, reason, window_min, switch_hour
    )
    return {
        "index": index,
        "grid": grid,
        "label": label,
        "reason": reason,
        "counted": counted,
        "meter": meter,
        "totals": totals,
        "estimate": result,
    }


def figures(result: dict, window_min: float) -> dict:
    """A :func:`pair_result`'s figures as the API shows them: those of the headline meter's
    totals (naive over the counted windows), the savings on every meter, the excluded minutes
    by reason, and the trial estimate (``savings_pct`` is the estimate's)."""
    t = result["totals"][result["meter"]]
    estimate = result["estimate"].to_dict()
    return {
        "meter": result["meter"],
        "savings_by_meter_pct": {
            m: result["totals"][m].savings_pct if m in result["totals"] else None for m in METERS
        },
        "energy_activated_kwh": t.energy_activated_kwh,
        "energy_deactivated_kwh": t.energy_deactivated_kwh,
        "avg_hourly_violation_activated_k": t.avg_hourly_violation_k,
        "avg_hourly_violation_deactivated_k": t.baseline_violation_k,
        "excluded_minutes": t.excluded_minutes,
        "excluded_minutes_by_reason": excluded_minutes_by_reason(result["reason"], window_min),
        "counted_windows": int(result["counted"].sum()),
        "counted_hours": t.counted_hours,
        **estimate,
    }
