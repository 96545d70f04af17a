"""The twin's response to setpoint changes: the changes found in the logged T_ref itself, and the
twin's metered energy and energy response over the minutes they affect, scored on the held-out
days and the training days (docs/model.md, "Calibration", "The response to setpoint changes").

The layer's savings rest on how the coach's energy responds when T_ref moves. Logs hold that
response only where the setpoint was moved by hand (a driver's change); the rule's own T_ref
follows T_amb slowly. So a *change* is found from steps of the logged T_ref alone — no rule
curve, no plan:

- a *step* is a minute whose T_ref differs from the minute before by at least :data:`STEP_K`;
- a change begins at a step and lasts while the steps since add up to :data:`STEP_K` / 2 or
  more (its departure; the rule's slow drift in between is no step and does not count); it ends
  at the step that brings them back below (or at the trajectory's end). A step within
  :data:`SETTLE_MIN` + :data:`BEFORE_MIN` minutes of that end belongs to the same change, so
  the windows and minutes before below do not overlap;
- the minutes it affects, its *window*, run from its first step to :data:`SETTLE_MIN` minutes
  after its end (the settling tail), at most :data:`WINDOW_MAX_MIN`; its *minutes before* are
  the :data:`BEFORE_MIN` minutes before its first step. A change is scored when its minutes
  before are all scored (past the replay's warm-up) and metered; its window counts its scored,
  metered minutes.

The score, over the scored changes c with windows W_c and minutes before B_c (1-min means of the
metered power p and the twin's p̂, kW):

- the energy's relative error over the windows, 100 · (Σ_c Σ_W_c p̂ − Σ_c Σ_W_c p) / Σ_c Σ_W_c p;
- each change's *response*, in each's own terms the energy above its own level before it:
  R_c = Σ_{k∈W_c} (p_k − mean_{B_c} p) · 1/60 h (kWh), and R̂_c likewise from p̂;
- the response error, 100 · Σ_c |R̂_c − R_c| / Σ_c |R_c| (%): 0 when the twin moves as the coach
  does, 100 when it is as far off as the response is large.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trainclimate.twin.replay import Replay

#: A step of the logged T_ref: the change from one minute to the next (K). The drivers' changes
#: are 0.5 K and more; the rule curve (at most 0.25 K/K of T_amb) moves T_ref by hundredths.
STEP_K = 0.25
#: Minutes after a change's end that still count to it: the room and the HVAC settling. [min]
SETTLE_MIN = 45
#: Minutes before a change whose mean power is its level before: long enough to average the
#: HVAC's switching out. [min]
BEFORE_MIN = 60
#: A change's window is cut after this many minutes: the level before stands for no longer.
WINDOW_MAX_MIN = 240
#: Fewer scored changes than this leave the response untested (a warning).
MIN_CHANGES = 3
#: A response error beyond this is warned of. [%]
MAX_RESPONSE_ERROR_PCT = 15.0


@dataclass(frozen=True)
class Change:
    """A setpoint change in replay column ``column``: its first step at minute ``start``, its
    end (the step back, or the end of the T_ref searched) at ``end``, its window
    ``[start, stop)`` and ``size`` its largest departure, the steps' sum (K, signed)."""

    column: int
    start: int
    end: int
    stop: int
    size: float


def changes_in(t_ref_c: np.ndarray, column: int = 0) -> list[Change]:
    """The setpoint changes of one trajectory's logged 1-min T_ref (°C; see the module
    docstring), as changes in replay column ``column``."""
    u = np.asarray(t_ref_c, dtype=float)
    length = len(u)
    steps = np.flatnonzero(np.abs(np.diff(u)) >= STEP_K) + 1
    out: list[Change] = []
    k = 0
    while k < len(steps):
        start = int(steps[k])
        away = size = 0.0
        end = length
        while k < len(steps):
            a = int(steps[k])
            away += u[a] - u[a - 1]
            if abs(away) > abs(size):
                size = float(away)
            k += 1
            if abs(away) < STEP_K / 2:
                # back at the base: the change ends unless another step follows before its
                # tail and the next change's minutes before have passed
                if k < len(steps) and steps[k] < a + SETTLE_MIN + BEFORE_MIN:
                    continue
                end = a
                break
        stop = min(end + SETTLE_MIN, start + WINDOW_MAX_MIN, length)
        out.append(Change(column, start, end, stop, size))
    return out


def changes(rep: Replay) -> list[Change]:
    """The setpoint changes of every trajectory of the replay (its logged T_ref; a shorter
    trajectory's padding holds no step)."""
    t_ref = rep.t_ref_c[:: rep.per_minute]
    return [c for j in range(t_ref.shape[1]) for c in changes_in(t_ref[:, j], j)]


def score(rep: Replay, p: np.ndarray) -> dict:
    """The twin's score on the setpoint changes of the replay (``p``: its power, minutes ×
    columns, kW; see the module docstring).

    Returns ``changes`` (found), ``scored`` (of them: their minutes before scored and metered),
    ``minutes`` (scored and metered in their windows), ``energy_error_pct`` (%),
    ``response_error_pct`` (%), ``response_logged_kwh`` and ``response_twin_kwh`` (Σ_c |R_c| and
    Σ_c |R̂_c|) and ``per_change`` (each scored change's ``size_k``, its largest departure from
    the base, its ``minutes`` and its R_c and R̂_c as ``logged_kwh`` and ``twin_kwh``); the
    errors are None without a scored change.
    """
    metered = rep.scored & np.isfinite(rep.p_kw)
    found = changes(rep)
    rows = []
    logged_sum = twin_sum = 0.0
    for c in found:
        before = np.arange(c.start - BEFORE_MIN, c.start)
        if c.start < BEFORE_MIN or not metered[before, c.column].all():
            continue
        window = np.arange(c.start, c.stop)
        window = window[metered[window, c.column]]
        logged, twin = rep.p_kw[window, c.column], p[window, c.column]
        rows.append(
            {
                "size_k": round(c.size, 2),
                "minutes": len(window),
                "logged_kwh": float((logged - rep.p_kw[before, c.column].mean()).sum() / 60.0),
                "twin_kwh": float((twin - p[before, c.column].mean()).sum() / 60.0),
            }
        )
        logged_sum += float(logged.sum())
        twin_sum += float(twin.sum())
    response = sum(abs(r["logged_kwh"]) for r in rows)
    miss = sum(abs(r["twin_kwh"] - r["logged_kwh"]) for r in rows)
    return {
        "changes": len(found),
        "scored": len(rows),
        "minutes": sum(r["minutes"] for r in rows),
        "energy_error_pct": (
            100.0 * (twin_sum - logged_sum) / logged_sum if logged_sum > 0 else None
        ),
        "response_error_pct": 100.0 * miss / response if response > 0 else None,
        "response_logged_kwh": response,
        "response_twin_kwh": sum(abs(r["twin_kwh"]) for r in rows),
        "per_change": rows,
    }


def warnings(held_out: dict, train: dict | None = None) -> list[str]:
    """What :func:`score` on the held-out days (``held_out``) leaves to warn of, each on its
    own: fewer than :data:`MIN_CHANGES` scored changes (the response untested; the training
    days' score ``train`` quoted if given), and a response error beyond
    :data:`MAX_RESPONSE_ERROR_PCT`."""
    out = []
    scored, error = held_out["scored"], held_out["response_error_pct"]
    if scored < MIN_CHANGES:
        on_train = (
            f"; on the {train['scored']} scored changes of the training days its response is "
            f"{train['response_error_pct']:.0f} % off"
            if train is not None and train["response_error_pct"] is not None
            else ""
        )
        out.append(
            "the twin's response to a setpoint change is untested: the held-out days hold "
            f"{scored} scored setpoint change(s) ({held_out['changes']} found; {MIN_CHANGES} "
            f"needed), and the savings it predicts rest on it{on_train}"
        )
    if error is not None and error > MAX_RESPONSE_ERROR_PCT:
        out.append(
            f"the twin's energy response to the {scored} held-out setpoint change(s) is "
            f"{error:.0f} % off (beyond {MAX_RESPONSE_ERROR_PCT:g} %): the savings it predicts "
            "rest on it"
        )
    return out
