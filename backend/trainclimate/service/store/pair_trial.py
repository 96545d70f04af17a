"""A pair's trial estimate and figures from its labelled windows (:mod:`.pair_labels`): what the
windows add up to per service day (:data:`FIELDS`), the totals and the estimate over a range, and
the figures the API shows.

Counted windows are summed per service day and estimated by :mod:`trainclimate.analysis.trial`
(crossover where both coaches had activated days, corrected by reference days, or the naive
figure labelled as confounded). The pair comparison and the fleet summary both build their
figures here, from the same window sums (:func:`.pair_windows.window_sums`) and setpoint
counts (:func:`.pair_labels.setpoint_counts`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from trainclimate.analysis import trial, trial_plan
from trainclimate.analysis.savings import PairTotals, savings_pct
from trainclimate.coach.meters import HEADLINE_METER, METERS
from trainclimate.service.store.pair_labels import REASONS, SUMS_INDEX, UNLABELLED, windows

#: A service day counts with at least this many counted windows.
MIN_DAY_WINDOWS = 4
_REASON_NAMES = np.array(REASONS, dtype=object)
#: The reasons to exclude a window by name, with their codes.
_REASONS_BY_NAME = sorted((str(name), code) for code, name in enumerate(REASONS) if code)

_DECKS = ("up", "mid", "low")
_GROUPS = {"0": 0, "1": 1, "neither": trial_plan.NEITHER}
#: What a pair's windows add up to over a service day (or any part of one): its windows, those
#: counted and those excluded by reason; the minutes counted for comfort and the discomfort per
#: deck of the activated and the deactivated coach over every window in which a coach ran the
#: layer; the counted windows with a row that does not split the floor heating off; each meter's
#: energy of the activated and the deactivated coach over the counted windows [kWh]; and what the
#: trial estimate judges the day by (:func:`trainclimate.analysis.trial.daily_sums`): its
#: counted and reference windows, by activated coach, and each coach's energy over them on each
#: meter [kWh]. Two parts of a day add up to the whole day's.
FIELDS = (
    "windows",
    "counted",
    *(f"excluded_{r}" for r in REASONS[1:]),
    "role_minutes",
    *(f"discomfort_{role}_{d}_kh" for role in ("activated", "deactivated") for d in _DECKS),
    "unsplit_counted",
    *(f"{m}_{role}_kwh" for m in METERS for role in ("activated", "deactivated")),
    "trial_windows",
    *(f"trial_{g}_windows" for g in _GROUPS),
    *(f"trial_{m}_energy_{c}_kwh" for m in METERS for c in (0, 1)),
)
FIELDS_INDEX = {name: i for i, name in enumerate(FIELDS)}
#: The columns of :data:`FIELDS` with each meter's activated and deactivated energy (a chart's).
CHART_FIELDS = [
    FIELDS_INDEX[f"{m}_{role}_kwh"] for m in METERS for role in ("activated", "deactivated")
]


def window_fields(grid: np.ndarray, label: np.ndarray, code: np.ndarray) -> np.ndarray:
    """What each window adds to its day's :data:`FIELDS`, shape (..., W, len(FIELDS)), from
    its sums (..., W, S) and its label and code (:func:`.pair_labels.windows`)."""
    out = np.zeros((*label.shape, len(FIELDS)))

    def put(name: str, values) -> None:
        out[..., FIELDS_INDEX[name]] = values

    counted = (code == 0) & (label >= 0)
    one, roles = label == 1, label >= 0
    put("windows", 1.0)
    put("counted", counted)
    for i, reason in enumerate(REASONS[1:], 1):
        put(f"excluded_{reason}", code == i)
    put("role_minutes", np.where(roles, grid[..., SUMS_INDEX["counted_minutes"]], 0.0))
    for d in _DECKS:
        d0 = grid[..., SUMS_INDEX[f"discomfort_0_{d}_kh"]]
        d1 = grid[..., SUMS_INDEX[f"discomfort_1_{d}_kh"]]
        put(f"discomfort_activated_{d}_kh", np.where(roles, np.where(one, d1, d0), 0.0))
        put(f"discomfort_deactivated_{d}_kh", np.where(roles, np.where(one, d0, d1), 0.0))
    put("unsplit_counted", counted & (grid[..., SUMS_INDEX["unsplit_minutes"]] > 0))
    in_trial = (code == 0) & (label != UNLABELLED)
    put("trial_windows", in_trial)
    for name, g in _GROUPS.items():
        put(f"trial_{name}_windows", in_trial & (label == g))
    for m in METERS:
        e0, e1 = (grid[..., c] for c in energy_columns(m))
        put(f"{m}_activated_kwh", np.where(counted, np.where(one, e1, e0), 0.0))
        put(f"{m}_deactivated_kwh", np.where(counted, np.where(one, e0, e1), 0.0))
        put(f"trial_{m}_energy_0_kwh", np.where(in_trial, e0, 0.0))
        put(f"trial_{m}_energy_1_kwh", np.where(in_trial, e1, 0.0))
    return out


def day_starts(day: np.ndarray) -> np.ndarray:
    """Where each service day starts among consecutive windows' days (W,): the windows' indices
    at which the day changes, the first one included."""
    return np.flatnonzero(np.r_[True, day[1:] != day[:-1]]) if len(day) else np.zeros(0, int)


def trial_days(fields: np.ndarray, days: np.ndarray) -> list[trial.TrialDays]:
    """Each pair's days for its trial estimate on the headline meter (the whole coach's where a
    counted minute does not split the floor heating off,
    :func:`trainclimate.analysis.trial.days_from_sums`), from its service days'
    :data:`FIELDS` (P, D, len(FIELDS)) and their ordinals (P, D)."""
    split = fields[..., FIELDS_INDEX["unsplit_counted"]].sum(axis=1) == 0
    trial_energy = np.where(
        split[:, None, None],
        fields[..., [FIELDS_INDEX[f"trial_{HEADLINE_METER}_energy_{c}_kwh"] for c in (0, 1)]],
        fields[..., [FIELDS_INDEX[f"trial_hvac_and_floor_energy_{c}_kwh"] for c in (0, 1)]],
    )
    return trial.days_from_sums(
        days,
        fields[..., FIELDS_INDEX["trial_windows"]],
        trial_energy,
        fields[..., [FIELDS_INDEX[f"trial_{g}_windows"] for g in _GROUPS]],
        MIN_DAY_WINDOWS,
    )


def results_from_fields(
    fields: np.ndarray,
    days: np.ndarray,
    window_min: float,
    estimates: list[trial.TrialEstimate] | None = None,
) -> list[dict]:
    """Pairs' figures from their service days' :data:`FIELDS`: the totals on each meter, the
    trial estimate on the headline meter (:func:`trial_days` and
    :func:`~trainclimate.analysis.trial.estimate_many`; with counted windows but no day of
    :data:`MIN_DAY_WINDOWS`, the naive figure over them, confounded) and the
    :func:`figures` they make.

    Parameters
    ----------
    fields : numpy.ndarray of shape (P, D, len(FIELDS))
        Each pair's days' fields (a day without windows: zeros).
    days : numpy.ndarray of int, shape (P, D)
        The days (ordinals), ascending for each pair.
    window_min : float
        Window length. [min]
    estimates : list of TrialEstimate, optional
        The pairs' trial estimates of :func:`trial_days` if already computed.

    Returns
    -------
    list of dict
        Per pair: ``meter`` (the HVAC units' when every counted minute splits the floor heating
        off, else the whole coach's), ``totals`` (meter → :class:`PairTotals`, the HVAC units'
        only where split), ``estimate``, ``reasons`` (windows per code of
        :data:`~.pair_labels.REASONS`), ``counted_windows`` and ``figures``.
    """
    f = fields.sum(axis=1)
    column = {name: f[:, i] for name, i in FIELDS_INDEX.items()}
    split = column["unsplit_counted"] == 0
    meter = np.where(split, HEADLINE_METER, "hvac_and_floor")
    if estimates is None:
        estimates = trial.estimate_many(trial_days(fields, days))
    n_reasons = np.stack(
        [column["windows"] * 0, *(column[f"excluded_{r}"] for r in REASONS[1:])], -1
    ).astype(np.int64)
    # per pair as Python numbers, and the decks' discomfort as rows of one array each: the loop
    # below runs once per pair
    value = {name: column[name].tolist() for name in column}
    discomfort, baseline_discomfort = (
        f[:, [FIELDS_INDEX[f"discomfort_{role}_{d}_kh"] for d in _DECKS]]
        for role in ("activated", "deactivated")
    )
    out = []
    for p in range(len(fields)):
        windows = int(value["windows"][p])
        excluded = int(value["windows"][p] - value["counted"][p])
        totals = {
            m: PairTotals(
                energy_activated_kwh=value[f"{m}_activated_kwh"][p],
                energy_deactivated_kwh=value[f"{m}_deactivated_kwh"][p],
                windows=windows,
                excluded_windows=excluded,
                window_min=window_min,
                counted_hours=value["role_minutes"][p] / 60.0,
                discomfort_kh=discomfort[p],
                baseline_discomfort_kh=baseline_discomfort[p],
            )
            for m in (METERS if split[p] else ("hvac_and_floor",))
        }
        estimate = estimates[p]
        counted = int(value["counted"][p])
        if estimate.estimator is None and counted:
            t = totals[str(meter[p])]
            naive = savings_pct(t.energy_activated_kwh, t.energy_deactivated_kwh)
            why = "fewer than a day's windows: the saving is confounded with the coaches"
            estimate = trial.TrialEstimate("fixed_naive", naive, None, why, naive, estimate.days)
        result = {
            "meter": str(meter[p]),
            "totals": totals,
            "estimate": estimate,
            "reasons": n_reasons[p],
            "counted_windows": counted,
        }
        result["figures"] = figures(result, window_min)
        out.append(result)
    return out


def excluded_minutes_by_reason(n_windows: np.ndarray, window_min: float) -> dict[str, float]:
    """Reason → minutes of the windows excluded for it, from how many windows have each code of
    :data:`~.pair_labels.REASONS` (by name). [min]"""
    n = n_windows.tolist()
    return {name: float(n[i] * window_min) for name, i in _REASONS_BY_NAME if n[i]}


def reasons(result: dict) -> np.ndarray:
    """A :func:`pair_results` result's reason per window (None where it counts) by name."""
    return _REASON_NAMES[result["code"]]


def energy_columns(meter: str) -> tuple[int, int]:
    """The columns of :data:`~.pair_labels.SUMS` with coach 0's and coach 1's energy on
    ``meter``."""
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
    (:func:`.pair_labels.windows`), the totals on each meter over the counted windows, and the
    trial estimate on the headline meter — all pairs at once, each exactly as alone.

    Parameters
    ----------
    index : numpy.ndarray of int, shape (W,)
        The windows (starts in window lengths since 1970).
    grids : numpy.ndarray of shape (P, W, len(SUMS))
        Each pair's window sums (:data:`~.pair_labels.SUMS`, coach 0 first; zeros where it has
        no row).
    counts : numpy.ndarray of shape (P, W, 2, len(COUNTS))
        Both coaches' setpoint counts per window (:func:`.pair_labels.setpoint_counts`).
    window_min : float
        Window length. [min]
    switch_hours : list of int
        Each pair's train's local switch hour. [h]

    Returns
    -------
    list of dict
        Per pair: ``index``, ``grid``, ``label``, ``code`` (the reason a window is excluded,
        in :data:`~.pair_labels.REASONS`, 0 where it counts; :func:`reasons` by name),
        ``counted`` (arrays per window), ``chart`` (the counted windows' indices and each
        meter's activated and deactivated energy in them, :data:`CHART_FIELDS`, (k, 4) [kWh])
        and what :func:`results_from_fields` gives: ``meter``, ``totals`` (meter →
        :class:`PairTotals`), ``estimate``
        (:class:`~trainclimate.analysis.trial.TrialEstimate`), ``reasons``,
        ``counted_windows`` and ``figures`` (:func:`figures`). Their totals are summed per
        service day, then over the days. (Codes, not names, so that a kept result holds no
        object per window for the garbage collector to walk.)
    """
    label, code = windows(grids, counts, window_min)
    counted = (code == 0) & (label >= 0)
    per_window = window_fields(grids, label, code)
    out: list = [None] * len(grids)
    starts = pd.to_datetime(index * round(window_min * 60), unit="s", utc=True)
    hours = np.asarray(switch_hours)
    for hour in np.unique(hours):
        mine = np.flatnonzero(hours == hour)
        day = trial_plan.service_days(starts, int(hour))
        first = day_starts(day)
        fields = (
            np.add.reduceat(per_window[mine], first, axis=1)
            if len(first)
            else np.zeros((len(mine), 0, len(FIELDS)))
        )
        found = results_from_fields(
            fields, np.broadcast_to(day[first], fields.shape[:2]), window_min
        )
        for p, result in zip(mine, found, strict=True):
            chart = per_window[p][counted[p]][:, CHART_FIELDS]
            out[p] = {
                "index": index,
                "grid": grids[p],
                "label": label[p],
                "code": code[p],
                "counted": counted[p],
                "chart": (index[counted[p]], chart),
                **result,
            }
    return out


def pair_result(
    grid: np.ndarray,
    counts: np.ndarray,
    first: pd.Timestamp,
    window_min: float,
    switch_hour: int = trial_plan.DEFAULT_SWITCH_HOUR,
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
        "excluded_minutes_by_reason": excluded_minutes_by_reason(result["reasons"], window_min),
        "counted_windows": result["counted_windows"],
        "counted_hours": t.counted_hours,
        **estimate,
    }
