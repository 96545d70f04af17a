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

from trainclimate.analysis import trial, trial_plan
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
        T_rule), :data:`~trainclimate.analysis.trial_plan.NEITHER` (both on T_rule, layer off:
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
    label[rule[..., 0] & rule[..., 1]] = trial_plan.NEITHER
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


#: A pair's lead-in state where its windows start when nothing came before them: no labelled
#: window before, no change within reach (:func:`lead_in`).
NO_STATE = (UNLABELLED, 1 << 30)


def _lead_windows(window_min: float, lead_in_min: float) -> int:
    """The windows a change of the activated coach marks as lead-in."""
    return int(np.ceil(lead_in_min / window_min))


def lead_in(
    label: np.ndarray,
    window_min: float,
    lead_in_min: float = LEAD_IN_MIN,
    entering: tuple | None = None,
) -> np.ndarray:
    """The windows within ``lead_in_min`` of a change of the activated coach (between labelled
    windows: 0, 1 or reference), shape (..., W) bool, along the last axis.

    ``entering`` is the state before the first window (:func:`lead_state`; default
    :data:`NO_STATE`): the label of the last labelled window before it, and how many windows
    before the first one the last change was — so that windows taken in parts, each from the
    state the part before left, are marked as taken whole."""
    n = _lead_windows(window_min, lead_in_min)
    w = label.shape[-1]
    if w == 0:
        return np.zeros(label.shape, bool)
    change = _changes(label, entering)
    # a change at w marks w … w + n − 1: the windows with a change in the n up to them
    changes = np.cumsum(change, axis=-1)
    earlier = np.zeros_like(changes)
    if n < w:
        earlier[..., n:] = changes[..., : w - n]
    marked = changes - earlier > 0
    if entering is not None:  # the lead-in of a change before the first window
        age = np.asarray(entering[1])[..., None]
        marked |= np.arange(w) < n - age
    return marked


def _changes(label: np.ndarray, entering: tuple | None) -> np.ndarray:
    """Where the activated coach changes (..., W) bool: a labelled window whose label differs
    from the last labelled window's before it (the ``entering`` state's before the first)."""
    w = label.shape[-1]
    prev = np.full(label.shape[:-1], UNLABELLED) if entering is None else entering[0]
    prev = np.broadcast_to(np.asarray(prev)[..., None], (*label.shape[:-1], 1))
    labelled = label != UNLABELLED
    # the last labelled window before each window (−1: none, the entering state's label)
    last = np.maximum.accumulate(np.where(labelled, np.arange(w), -1), axis=-1)
    before = np.concatenate([np.full((*label.shape[:-1], 1), -1), last[..., :-1]], axis=-1)
    previous = np.where(
        before >= 0, np.take_along_axis(label, np.maximum(before, 0), axis=-1), prev
    )
    return labelled & (previous != UNLABELLED) & (label != previous)


def lead_state(label: np.ndarray, entering: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The lead-in state after windows ``label`` (..., W) taken from the ``entering`` state:
    the last labelled window's label (UNLABELLED if none so far) and how many windows before
    the next one the last change was (large if none)."""
    prev0, age0 = NO_STATE if entering is None else entering
    w = label.shape[-1]
    if w == 0:
        shape = label.shape[:-1]
        return np.broadcast_to(prev0, shape).copy(), np.broadcast_to(age0, shape).copy()
    labelled = label != UNLABELLED
    last = np.where(labelled, np.arange(w), -1).max(axis=-1, initial=-1)
    prev = np.where(
        last >= 0,
        np.take_along_axis(label, np.maximum(last, 0)[..., None], axis=-1)[..., 0],
        prev0,
    )
    change = _changes(label, entering)
    last_change = np.where(change, np.arange(w), -1).max(axis=-1, initial=-1)
    age = np.where(last_change >= 0, w - last_change, np.minimum(np.asarray(age0) + w, NO_STATE[1]))
    return prev, age


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


def base_windows(
    sums: np.ndarray, counts: np.ndarray, window_min: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each window's label (:func:`labels`) and its own reason to be excluded (the telemetry's
    first, then the setpoints'), before the lead-in: what a window is, whatever came before it.
    Shapes as :func:`windows`."""
    label, code = labels(counts)
    telemetry = exclusions(sums, window_min)
    return label, np.where(telemetry != 0, telemetry, code)


def with_lead_in(
    label: np.ndarray,
    code: np.ndarray,
    window_min: float,
    lead_in_min: float = LEAD_IN_MIN,
    entering: tuple | None = None,
) -> np.ndarray:
    """:func:`base_windows`' codes with the windows of the lead-in (:func:`lead_in` from the
    ``entering`` state) that have no other reason marked ``plan_switch``."""
    code = code.copy()
    code[lead_in(label, window_min, lead_in_min, entering) & (code == 0)] = _CODE["plan_switch"]
    return code


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
    label, code = base_windows(sums, counts, window_min)
    return label, with_lead_in(label, code, window_min, lead_in_min)


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
    its sums (..., W, S) and its label and code (:func:`windows`)."""
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


def results_from_fields(fields: np.ndarray, days: np.ndarray, window_min: float) -> list[dict]:
    """Pairs' figures from their service days' :data:`FIELDS`: the totals on each meter, the
    trial estimate on the headline meter (:func:`trainclimate.analysis.trial.days_from_sums`
    and :func:`~trainclimate.analysis.trial.estimate_many`; with counted windows but no day of
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

    Returns
    -------
    list of dict
        Per pair: ``meter`` (the HVAC units' when every counted minute splits the floor heating
        off, else the whole coach's), ``totals`` (meter → :class:`PairTotals`, the HVAC units'
        only where split), ``estimate``, ``reasons`` (windows per code of :data:`REASONS`),
        ``counted_windows`` and ``figures``.
    """
    f = fields.sum(axis=1)
    column = {name: f[:, i] for name, i in FIELDS_INDEX.items()}
    split = column["unsplit_counted"] == 0
    meter = np.where(split, HEADLINE_METER, "hvac_and_floor")
    trial_energy = np.where(
        split[:, None, None],
        fields[..., [FIELDS_INDEX[f"trial_{HEADLINE_METER}_energy_{c}_kwh"] for c in (0, 1)]],
        fields[..., [FIELDS_INDEX[f"trial_hvac_and_floor_energy_{c}_kwh"] for c in (0, 1)]],
    )
    estimates = trial.estimate_many(
        trial.days_from_sums(
            days,
            fields[..., FIELDS_INDEX["trial_windows"]],
            trial_energy,
            fields[..., [FIELDS_INDEX[f"trial_{g}_windows"] for g in _GROUPS]],
            MIN_DAY_WINDOWS,
        )
    )
    n_reasons = np.stack(
        [column["windows"] * 0, *(column[f"excluded_{r}"] for r in REASONS[1:])], -1
    )
    out = []
    for p in range(len(fields)):
        totals = {
            m: PairTotals(
                energy_activated_kwh=float(column[f"{m}_activated_kwh"][p]),
                energy_deactivated_kwh=float(column[f"{m}_deactivated_kwh"][p]),
                windows=int(column["windows"][p]),
                excluded_windows=int(column["windows"][p] - column["counted"][p]),
                window_min=window_min,
                counted_hours=float(column["role_minutes"][p] / 60.0),
                discomfort_kh=f[p, [FIELDS_INDEX[f"discomfort_activated_{d}_kh"] for d in _DECKS]],
                baseline_discomfort_kh=f[
                    p, [FIELDS_INDEX[f"discomfort_deactivated_{d}_kh"] for d in _DECKS]
                ],
            )
            for m in (METERS if split[p] else ("hvac_and_floor",))
        }
        estimate = estimates[p]
        counted = int(column["counted"][p])
        if estimate.estimator is None and counted:
            t = totals[str(meter[p])]
            naive = savings_pct(t.energy_activated_kwh, t.energy_deactivated_kwh)
            why = "fewer than a day's windows: the saving is confounded with the coaches"
            estimate = trial.TrialEstimate("fixed_naive", naive, None, why, naive, estimate.days)
        result = {
            "meter": str(meter[p]),
            "totals": totals,
            "estimate": estimate,
            "reasons": n_reasons[p].astype(np.int64),
            "counted_windows": counted,
        }
        result["figures"] = figures(result, window_min)
        out.append(result)
    return out


def excluded_minutes_by_reason(n_windows: np.ndarray, window_min: float) -> dict[str, float]:
    """Reason → minutes of the windows excluded for it, from how many windows have each code of
    :data:`REASONS` (by name). [min]"""
    found = {
        str(REASONS[i]): float(n_windows[i] * window_min)
        for i in range(1, len(REASONS))
        if n_windows[i]
    }
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
        per window), ``chart`` (the counted windows' indices and each meter's activated and
        deactivated energy in them, :data:`CHART_FIELDS`, (k, 4) [kWh]) and what
        :func:`results_from_fields` gives: ``meter``, ``totals`` (meter →
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
