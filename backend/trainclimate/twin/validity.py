"""A calibrated twin's file and validity: the ambient range its calibration validated it for,
carried in its coach-params file, the warning a scenario gets when its weather leaves that range,
the warning every use of its savings gets when its response to setpoint changes was not
validated, and the twin with a fitted knob moved to an end of its 95 % interval.

The file ``calibrate --out`` writes is a coach-params file with one more key, :data:`TWIN_KEY`
(``"twin"``), which :func:`~trainclimate.sim.params.load_params` skips::

    {"c_room_j_k": [...], ..., "twin": {"coach": "124A+124B",
     "validated_t_amb_c": [-2.0, 31.5], "fitted": {...}, "not_identified": [...],
     "holdout": {..., "setpoint_response": {"scored": 4, "response_error_pct": 8.1, ...}},
     "warnings": [...]}}

``validated_t_amb_c`` is ``[low, high]`` in °C, or null when the calibration validated the twin
at no ambient temperature. ``holdout`` is the twin's score on the held-out days, among it the
setpoint changes' (:func:`trainclimate.twin.response.score`). A fleet file (``calibrate
--json``) carries the same keys on each coach.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from trainclimate.sim.params import TWIN_KEY, CoachParams, ParamsError
from trainclimate.twin.knobs import QUANTITIES, apply
from trainclimate.twin.response import MAX_RESPONSE_ERROR_PCT, MIN_CHANGES

#: The calibration's record kept beside the parameters in a twin's coach-params file.
RECORD = ("coach", "validated_t_amb_c", "fitted", "not_identified", "holdout", "warnings")


def params_file(coach: dict) -> dict:
    """The coach-params file of one coach of ``calibrate --json``: its parameters and, under
    :data:`TWIN_KEY`, the calibration's record (:data:`RECORD`)."""
    return {**coach["params"], TWIN_KEY: {k: coach[k] for k in RECORD}}


def validated_range(record: object, where: str) -> list[float] | None:
    """The ``validated_t_amb_c`` of a calibration's ``record`` (a ``"twin"`` object or a fleet
    file's coach): None when it has none, ``[]`` when it is null (validated nowhere); ``where``
    names it in the error.

    Raises
    ------
    ParamsError
        If the range is not null or two finite temperatures, the first below the second.
    """
    if not isinstance(record, dict) or "validated_t_amb_c" not in record:
        return None
    value = record["validated_t_amb_c"]
    if value is None:
        return []
    if not (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        and np.isfinite(value).all()
        and value[0] < value[1]
    ):
        raise ParamsError(f"{where}: validated_t_amb_c must be [low, high] in °C, got {value!r}")
    return [float(value[0]), float(value[1])]


def record_of_file(path: str | Path | None) -> dict | None:
    """The calibration's record in coach-params file ``path`` (None: no file, or a file not
    written by a calibration). Read after :func:`load_params` accepted the file."""
    if path is None:
        return None
    record = json.loads(Path(path).read_text()).get(TWIN_KEY)
    return record if isinstance(record, dict) else None


def savings_warning(record: object, what: str) -> str | None:
    """The warning of every saving predicted with the twin ``what`` whose calibration's
    ``record`` (a ``"twin"`` object or a fleet file's coach) did not validate its response to
    setpoint changes — the response a saving rests on: fewer than
    :data:`~trainclimate.twin.response.MIN_CHANGES` changes scored on the held-out days, or a
    response error beyond :data:`~trainclimate.twin.response.MAX_RESPONSE_ERROR_PCT`. None
    when validated, or when the record holds no such score (a file of an older calibration, a
    coach-params file of one's own).

    Raises
    ------
    ParamsError
        If the record's score is not a count of scored changes and a response error (%, or
        null without one).
    """
    holdout = record.get("holdout") if isinstance(record, dict) else None
    score = holdout.get("setpoint_response") if isinstance(holdout, dict) else None
    if score is None:
        return None
    scored = score.get("scored") if isinstance(score, dict) else None
    error = score.get("response_error_pct") if isinstance(score, dict) else None
    if not (
        isinstance(scored, int)
        and not isinstance(scored, bool)
        and scored >= 0
        and (error is None or (isinstance(error, int | float) and np.isfinite(error)))
    ):
        raise ParamsError(
            f"{what}: holdout.setpoint_response must hold scored (a count) and "
            f"response_error_pct (%, or null), got {score!r}"
        )
    if scored < MIN_CHANGES:
        why = (
            f"its response to a setpoint change is untested: the held-out days hold {scored} "
            f"scored change(s), {MIN_CHANGES} needed"
        )
    elif error is not None and error > MAX_RESPONSE_ERROR_PCT:
        why = (
            f"its energy response to the {scored} held-out setpoint changes is {error:.0f} % "
            f"off (beyond {MAX_RESPONSE_ERROR_PCT:g} %)"
        )
    else:
        return None
    return f"{what}: the savings predicted with the twin are not validated: {why}"


def range_warning(validated: list[float] | None, t_amb_c: np.ndarray, what: str) -> str | None:
    """The warning of ``what`` (e.g. a scenario) whose ambient temperatures ``t_amb_c`` (°C,
    any shape) leave the twin's ``validated`` range (:func:`validated_range`; None: in it, or
    no range known)."""
    if validated is None:
        return None
    if not validated:
        return f"{what}: the twin's calibration validated it at no ambient temperature"
    t = np.asarray(t_amb_c, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        return None
    low, high = validated
    outside = float(np.mean((t < low) | (t > high)))
    if outside == 0.0:
        return None
    return (
        f"{what}: T_amb {t.min():.1f} to {t.max():.1f} °C leaves the twin's validated range "
        f"{low:g} to {high:g} °C for {100 * outside:.0f} % of the time: its results there are "
        "extrapolated"
    )


def interval_ends(record: object) -> tuple[list[tuple[str, float, str, float]], list[str]]:
    """The ends of the 95 % intervals of a calibration's ``record`` (a ``"twin"`` object):
    ``[(knob, fitted value, "low" or "high", end)]``, and the fitted knobs without an interval
    (no bootstrap, one training day).

    Raises
    ------
    ParamsError
        If ``record`` carries no ``fitted`` knobs, or an interval is not two finite values.
    """
    fitted = record.get("fitted") if isinstance(record, dict) else None
    if not isinstance(fitted, dict) or not fitted:
        raise ParamsError("the coach-params file carries no calibration's fitted values")
    ends, without = [], []
    for knob, f in fitted.items():
        ci = f.get("ci95") if isinstance(f, dict) else None
        if ci is None:
            without.append(knob)
            continue
        if not (isinstance(ci, list) and len(ci) == 2 and np.isfinite(ci).all()):
            raise ParamsError(f"fitted {knob}: ci95 must be [low, high], got {ci!r}")
        ends += [(knob, float(f["value"]), "low", float(ci[0]))]
        ends += [(knob, float(f["value"]), "high", float(ci[1]))]
    return ends, without


def at_end(params: CoachParams, knob: str, value: float, end: float) -> CoachParams:
    """The twin ``params`` (calibrated with ``knob`` = ``value``) with ``knob`` moved to
    ``end`` of its interval, every other parameter as calibrated: a scale (envelope, COP level,
    …) multiplies by ``end / value``, a quantity (the fans' power, the fresh-air fraction) is
    set to ``end``."""
    if knob in QUANTITIES:
        return apply(params, {knob: end})
    return apply(params, {knob: end / value})


def scenario_t_amb(name: str, hours: float | None = None) -> np.ndarray:
    """The ambient temperatures of scenario ``name`` over its first ``hours`` (default: all),
    every 10 min (its weather, as :func:`~trainclimate.sim.scenarios.build` draws it). [°C]"""
    from trainclimate.sim import scenarios

    env, _ = scenarios.build(scenarios.get(name), n_coaches=1, hours=hours, dt_s=600.0)
    return env.t_amb_c[:, 0]
