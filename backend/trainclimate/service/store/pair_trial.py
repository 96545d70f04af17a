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
figures here, from the same window sums (:func:`.pair_windows.window_sums`) and setpoint
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
from trainclimate.coach.meters import HEADLINE_METER, METERS
from trainclimate.service.store import setpoint_rollups
from trainclimate.service.store.models import Setpoint
from trainclimate.service.store.setpoint_rollups import COUNTS
from trainclimate.service.store.sqltime import EpochSeconds

#: What :func:`.pair_windows.window_sums` returns per window, in order.
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


#: Why a window does not count, by code: 0 where it counts (or is a reference window), then the
#: telemetry's reasons (:func:`exclusions`), the setpoints' (:func:`labels`) and the lead-in.
REASONS = (
    None,
    "disconnected",
    "override",
    "missing_data",
    "no_setpoint",
    "preparing",
    "fallback",
    "not_regular",
    "mixed_roles",
    "plan_switch",
)
_CODE = {name: i for i, name in enumerate(REASONS)}
_REASON_NAMES = np.array(REASONS, dtype=object)


def labels(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which coach ran the layer in each window, from both coaches' setpoint counts.

    Parameters
    ----------
    counts : numpy.ndarray of shape (..., W, 2, len(COUNTS))
        Per window, coach 0's and coach 1's :data:`COUNTS` (any leading axes: pairs).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The label per window (..., W): 0 or 1 (the coach under the layer, the other on
        T_rule), :data:`~trainclimate.analysis.trial.NEITHER` (both on T_rule, layer off:
        reference) or :data:`UNLABELLED`; and the code of the reason a window is not labelled
        (..., W) in :data:`REASONS`, 0 where it is.
    """
    c = {name: counts[..., i] for i, name in enumerate(COUNTS)}
    ticks = c["ticks"]
    ddpc = (ticks > 0) & (c["ddpc"] == ticks)
    rule = (ticks > 0) & (c["inactive"] == ticks)
    label = np.full(counts.shape[:-2], UNLABELLED)
    label[ddpc[..., 0] & rule[..., 1]] = 0
    label[ddpc[..., 1] & rule[..., 0]] = 1
    label[rule[..., 0] & rule[..., 1]] = trial.NEITHER
    conditions = [
        (ticks == 0).any(axis=-1),
        (c["override"] > 0).any(axis=-1),
        (c["no_model"] > 0).any(axis=-1),
        (c["fallback"] > 0).any(axis=-1),
        (c["not_regular"] > 0).any(axis=-1),
    ]
    reasons = ["no_setpoint", "override", "preparing", "fallback", "not_regular"]
    code = np.select(conditions, [_CODE[r] for r in reasons], default=_CODE["mixed_roles"])
    code[label != UNLABELLED] = 0
    return label, code


def lead_in(label: np.ndarray, window_min: float, lead_in_min: float = LEAD_IN_MIN) -> np.ndarray:
    """The windows within ``lead_in_min`` of a change of the activated coach (between labelled
    windows: 0, 1 or reference), shape (..., W) bool, along the last axis."""
    n = int(np.ceil(lead_in_min / window_min))
    w = label.shape[-1]
    if w == 0:
        return np.zeros(label.shape, bool)
    labelled = label != UNLABELLED
    # the last labelled window before each window (−1: none)
    last = np.maximum.accumulate(np.where(labelled, np.arange(w), -1), axis=-1)
    before = np.concatenate([np.full((*label.shape[:-1], 1), -1), last[..., :-1]], axis=-1)
    previous = np.take_along_axis(label, np.maximum(before, 0), axis=-1)
    change = labelled & (before >= 0) & (label != previous)
    # a change at w marks w … w + n − 1: the windows with a change in the n up to them
    changes = np.cumsum(change, axis=-1)
    earlier = np.zeros_like(changes)
    if n < w:
        earlier[..., n:] = changes[..., : w - n]
    return changes - earlier > 0


def exclusions(sums: np.ndarray, window_min: float) -> np.ndarray:
    """The telemetry's reason to exclude each window, as a code of :data:`REASONS` (..., W), 0
    where it has none: a coach's link lost, an override in force, a minute missing or without
    power."""
    minutes = sums[..., SUMS_INDEX["minutes"]]
    affected = sums[..., SUMS_INDEX["affected_minutes"]]
    conditions = [
        sums[..., SUMS_INDEX["disconnected_minutes"]] > 0,
        sums[..., SUMS_INDEX["overridden_minutes"]] > 0,
        (minutes < round(window_min)) | (affected > 0),
    ]
    codes = [_CODE[r] for r in ("disconnected", "override", "missing_data")]
    return np.select(conditions, codes, default=0)


def windows(
    sums: np.ndarray,
    counts: np.ndarray,
    window_min: float,
    lead_in_min: float = LEAD_IN_MIN,
) -> tuple[np.ndarray, np.ndarray]:
    """Each window's label and reason to exclude it (see the module docstring).

    Parameters
    ----------
    sums : numpy.ndarray of shape (..., W, S)
        The pair's consecutive windows' sums (:data:`SUMS`, coach 0 first; leading axes: pairs).
    counts : numpy.ndarray of shape (..., W, 2, len(COUNTS))
        Both coaches' setpoint counts per window.
    window_min : float
        Window length. [min]
    lead_in_min : float
        See :func:`lead_in`. [min]

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Labels (..., W) as :func:`labels`, and the code of the reason per window (..., W) in
        :data:`REASONS`, 0 where it counts (a window labelled reference counts for the
        reference estimate only).
    """
    label, code = labels(counts)
    telemetry = exclusions(sums, window_min)
    code = np.where(telemetry != 0, telemetry, code)
    code[lead_in(label, window_min, lead_in_min) & (code == 0)] = _CODE["plan_switch"]
    return label, code


def _totals(
    grids: np.ndarray,
    label: np.ndarray,
    counted: np.ndarray,
    window_min: float,
    meter_columns: tuple[int, int],
) -> list[PairTotals]:
    """Each pair's totals on one meter over its counted windows (activated and deactivated by
    each window's label); violation and discomfort over the minutes in band, nothing affected,
    of every window in which a coach ran the layer (counted or not: an excluded window's
    comfort still happened).

    Parameters
    ----------
    grids : numpy.ndarray of shape (P, W, S)
        Window sums, coach 0 first.
    label : numpy.ndarray of int, shape (P, W)
    counted : numpy.ndarray of bool, shape (P, W)
        Windows labelled 0 or 1 and not excluded.
    window_min : float
        Window length. [min]
    meter_columns : (int, int)
        Coach 0's and coach 1's energy columns of the meter.
    """
    e0, e1 = grids[..., meter_columns[0]], grids[..., meter_columns[1]]
    one = label == 1
    e_act = np.where(counted, np.where(one, e1, e0), 0.0).sum(axis=-1)
    e_deact = np.where(counted, np.where(one, e0, e1), 0.0).sum(axis=-1)
    d0 = grids[..., [SUMS_INDEX[f"discomfort_0_{d}_kh"] for d in ("up", "mid", "low")]]
    d1 = grids[..., [SUMS_INDEX[f"discomfort_1_{d}_kh"] for d in ("up", "mid", "low")]]
    roles = (label >= 0)[..., None]
    d_act = np.where(roles, np.where(one[..., None], d1, d0), 0.0).sum(axis=-2)
    d_deact = np.where(roles, np.where(one[..., None], d0, d1), 0.0).sum(axis=-2)
    minutes = np.where(roles[..., 0], grids[..., SUMS_INDEX["counted_minutes"]], 0.0)
    n_windows = grids.shape[-2]
    excluded = n_windows - counted.sum(axis=-1)
    return [
        PairTotals(
            energy_activated_kwh=float(e_act[p]),
            energy_deactivated_kwh=float(e_deact[p]),
            windows=n_windows,
            excluded_windows=int(excluded[p]),
            window_min=window_min,
            counted_hours=float(minutes[p].sum() / 60.0),
            discomfort_kh=d_act[p],
            baseline_discomfort_kh=d_deact[p],
        )
        for p in range(len(grids))
    ]


def _estimates(
    index: np.ndarray,
    energy: np.ndarray,
    label: np.ndarray,
    code: np.ndarray,
    window_min: float,
    switch_hours: list[int],
) -> list[trial.TrialEstimate]:
    """Each pair's trial estimate from its windows: counted and reference windows summed per
    service day (:func:`trial.daily_many`), then :func:`trial.estimate_many`. With counted
    windows but no day of :data:`MIN_DAY_WINDOWS`, the naive figure over them (confounded).

    Parameters
    ----------
    index : numpy.ndarray of int, shape (W,)
        Window indices (starts in window lengths since 1970), the same for every pair.
    energy : numpy.ndarray of shape (P, W, 2)
        Coach 0's and coach 1's energy per window on each pair's headline meter. [kWh]
    label, code : numpy.ndarray of shape (P, W)
        From :func:`windows`.
    window_min : float
        Window length. [min]
    switch_hours : list of int
        Each pair's train's local switch hour. [h]
    """
    starts = pd.to_datetime(index * round(window_min * 60), unit="s", utc=True)
    usable = code == 0
    activated = np.where(usable, label, trial.NEITHER)
    counts_for_days = usable & (label != UNLABELLED)
    days: list = [None] * len(label)
    hours = np.asarray(switch_hours)
    for hour in np.unique(hours):
        mine = np.flatnonzero(hours == hour)
        found = trial.daily_many(
            trial.service_days(starts, int(hour)),
            energy[mine],
            activated[mine],
            counts_for_days[mine],
            min_windows=MIN_DAY_WINDOWS,
        )
        for i, d in zip(mine, found, strict=True):
            days[i] = d
    out = trial.estimate_many(days)
    counted = usable & (label >= 0)
    for p, result in enumerate(out):
        if result.estimator is None and counted[p].any():
            lab = label[p, counted[p]]
            naive = savings_pct(
                energy[p, counted[p], lab].sum(), energy[p, counted[p], 1 - lab].sum()
            )
            why = "fewer than a day's windows: the saving is confounded with the coaches"
            out[p] = trial.TrialEstimate("fixed_naive", naive, None, why, naive, result.days)
    return out


def excluded_minutes_by_reason(code: np.ndarray, window_min: float) -> dict[str, float]:
    """Reason → minutes of the windows excluded for it, from the windows' codes in
    :data:`REASONS` (by name). [min]"""
    n = np.bincount(code, minlength=len(REASONS))
    found = {str(REASONS[i]): float(n[i] * window_min) for i in range(1, len(REASONS)) if n[i]}
    return dict(sorted(found.items()))


def reasons(result: dict) -> np.ndarray:
    """A :func:`pair_results` result's reason per window (None where it counts) by name."""
    return _REASON_NAMES[result["code"]]


def energy_columns(meter: str) -> tuple[int, int]:
    """The columns of :data:`SUMS` with coach 0's and coach 1's energy on ``meter``."""
    suffix = "_kwh" if meter == "hvac_and_floor" else "_hvac_kwh"
    return SUMS_INDEX[f"energy_0{suffix}"], SUMS_INDEX[f"energy_1{suffix}"]


def pair_results(
    index: np.ndarray,
    grids: np.ndarray,
    counts: np.ndarray,
    window_min: float,
    switch_hours: list[int],
) -> list[dict]:
    """Pairs' figures over the same windows: each window labelled and excluded with its reason
    (:func:`.windows`), the totals on each meter over the counted windows, and the trial
    estimate on the headline meter — all pairs at once, each exactly as alone.

    Parameters
    ----------
    index : numpy.ndarray of int, shape (W,)
        The windows (starts in window lengths since 1970).
    grids : numpy.ndarray of shape (P, W, len(SUMS))
        Each pair's window sums (:data:`SUMS`, coach 0 first; zeros where it has no row).
    counts : numpy.ndarray of shape (P, W, 2, len(COUNTS))
        Both coaches' setpoint counts per window (:func:`setpoint_counts`).
    window_min : float
        Window length. [min]
    switch_hours : list of int
        Each pair's train's local switch hour. [h]

    Returns
    -------
    list of dict
        Per pair: ``index``, ``grid``, ``label``, ``code`` (the reason a window is excluded,
        in :data:`REASONS`, 0 where it counts; :func:`reasons` by name), ``counted`` (arrays
        per window), ``meter`` (the HVAC units' when every counted minute splits the floor
        heating off, else the whole coach's), ``totals`` (meter → :class:`PairTotals`),
        ``estimate`` (:class:`~trainclimate.analysis.trial.TrialEstimate`) and its ``figures``
        (:func:`figures`). (Codes, not names, so that a kept result holds no object per window
        for the garbage collector to walk.)
    """
    label, code = windows(grids, counts, window_min)
    counted = (code == 0) & (label >= 0)
    split = ~np.any(counted & (grids[..., SUMS_INDEX["unsplit_minutes"]] > 0), axis=-1)
    totals = {m: _totals(grids, label, counted, window_min, energy_columns(m)) for m in METERS}
    headline = np.where(
        split[:, None, None],
        grids[..., list(energy_columns(HEADLINE_METER))],
        grids[..., list(energy_columns("hvac_and_floor"))],
    )
    estimates = _estimates(index, headline, label, code, window_min, switch_hours)
    out = []
    for p in range(len(grids)):
        meters = METERS if split[p] else ("hvac_and_floor",)
        result = {
            "index": index,
            "grid": grids[p],
            "label": label[p],
            "code": code[p],
            "counted": counted[p],
            "meter": HEADLINE_METER if split[p] else "hvac_and_floor",
            "totals": {m: totals[m][p] for m in meters},
            "estimate": estimates[p],
        }
        result["figures"] = figures(result, window_min)
        out.append(result)
    return out


def pair_result(
    grid: np.ndarray,
    counts: np.ndarray,
    first: pd.Timestamp,
    window_min: float,
    switch_hour: int = trial.DEFAULT_SWITCH_HOUR,
) -> dict:
    """One pair's :func:`pair_results` over its windows from ``first``.

    Parameters
    ----------
    grid : numpy.ndarray of shape (W, len(SUMS))
        The pair's window sums (:func:`.pair_windows.pair_data`).
    counts : numpy.ndarray of shape (W, 2, len(COUNTS))
        Both coaches' setpoint counts per window.
    first : pandas.Timestamp
        The first window's start.
    window_min : float
        Window length. [min]
    switch_hour : int
        The train's local switch hour. [h]
    """
    w0 = round(first.timestamp()) // round(window_min * 60)
    index = np.arange(w0, w0 + len(grid))
    return pair_results(index, grid[None], counts[None], window_min, [switch_hour])[0]


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
        "excluded_minutes_by_reason": excluded_minutes_by_reason(result["code"], window_min),
        "counted_windows": int(result["counted"].sum()),
        "counted_hours": t.counted_hours,
        **estimate,
    }
