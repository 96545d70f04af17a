"""A pair's 30-minute windows labelled by what each coach really ran: the window sums and setpoint
counts they are judged by, each window's label and its reason to be excluded, and the lead-in.

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

The trial estimate and the figures over the labelled windows are :mod:`.pair_trial`'s.
"""

from __future__ import annotations

from datetime import datetime
from typing import cast

import numpy as np
from sqlalchemy import Table, select
from sqlalchemy.orm import Session

from trainclimate.analysis import trial_plan
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
