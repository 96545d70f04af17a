"""Model health: a predictor model's stored predictions against what happened.

Every DDPC setpoint stores the deck temperatures the controller predicted, y(1|t) … y(T|t)
(``predicted["y_pred_c"]``, T × 3: up, mid, low deck, °C), and the model it came from. What
happened at step k of a prediction issued at tick t is the controller's reading at t + k·Δ: the
telemetry row of the minute up to it, i.e. the row stamped t + k·Δ (:mod:`.telemetry`). A row
that is missing, was not connected or not in regular mode is no actual (the model only knows
regular mode), nor is a deck without a value.

The window is the data's clock, not the wall clock (the demo fleet's clock is simulated): the
``hours`` up to the newest tick at which the model predicted (for the active model, the latest
tick; for an older one, its last hours of use), one window for every coach it predicted for.

:func:`model_health` reads the window in three queries (the newest tick, the model's setpoints in
the window, the telemetry of their coaches up to a horizon after it); :func:`actual_at` and
:func:`mae_per_step` are the maths on arrays.
"""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from trainclimate.service.store.models import (
    PredictorModel,
    Setpoint,
    ShadowPrediction,
    Telemetry,
)

#: The bound on the predictor's mean absolute error the paper holds it to (MAE ≤ 0.25 °C at every
#: step up to 60 min; docs/experiments.md). A model whose online first-step MAE over all its
#: coaches exceeds it is flagged (``exceeds_bound``). [°C]
BOUND_C = 0.25
#: Drift: the online MAE above this many times the model's validation MAE (the setting
#: ``drift_factor``). [–]
DRIFT_FACTOR = 1.5


def actual_at(
    time_s: np.ndarray, y: np.ndarray, usable: np.ndarray, at_s: np.ndarray
) -> np.ndarray:
    """The actual deck temperatures at the times ``at_s`` (any shape, Unix time, s): per time
    the newest row in the minute (at − 60 s, at] — the row stamped ``at`` — as shape
    ``at_s.shape + (3,)``, °C; NaN where there is no such row or it is not ``usable``.

    ``time_s`` (n,) are one coach's row times (Unix time, s, ascending), ``y`` (n, 3) its deck
    temperatures (°C, NaN where missing) and ``usable`` (n,) whether a row counts (connected and
    in regular mode)."""
    if len(time_s) == 0:
        return np.full((*np.shape(at_s), 3), np.nan)
    i = np.searchsorted(time_s, at_s, side="right") - 1  # the newest row at or before the time
    j = np.maximum(i, 0)  # (i = −1: none)
    found = (i >= 0) & (time_s[j] > at_s - 60.0) & usable[j]
    return np.where(found[..., None], y[j], np.nan)


def mae_per_step(errors: np.ndarray) -> tuple[list[float | None], list[int]]:
    """The mean absolute error per prediction step (°C; None for a step without a sample) and the
    number of samples behind it, from the absolute errors ``errors`` (m predictions × T steps ×
    3 decks, K; NaN where there is no actual)."""
    counts = np.isfinite(errors).sum(axis=(0, 2))
    sums = np.nansum(errors, axis=(0, 2))
    mae = [float(s / n) if n else None for s, n in zip(sums, counts, strict=True)]
    return mae, [int(n) for n in counts]


def _predictions(session: Session, model_id: int, start, end, horizon: int) -> dict:
    """A model's predictions with a whole trajectory in (start, end], by coach: its DDPC
    setpoints' (while active) and its shadow predictions (while a candidate)."""
    out: dict[str, list[tuple[datetime, np.ndarray]]] = {}
    setpoints = session.execute(
        select(Setpoint.coach_id, Setpoint.tick, Setpoint.predicted).where(
            Setpoint.model_id == model_id, Setpoint.tick > start, Setpoint.tick <= end
        )
    ).all()
    shadows = session.execute(
        select(ShadowPrediction.coach_id, ShadowPrediction.tick, ShadowPrediction.y_pred_c).where(
            ShadowPrediction.model_id == model_id,
            ShadowPrediction.tick > start,
            ShadowPrediction.tick <= end,
        )
    ).all()
    for coach_id, tick, predicted in setpoints:
        _add(out, coach_id, tick, (predicted or {}).get("y_pred_c", []), horizon)
    for coach_id, tick, y_pred in shadows:
        _add(out, coach_id, tick, y_pred, horizon)
    return out


def _add(out: dict, coach_id: str, tick: datetime, y_pred, horizon: int) -> None:
    y_pred = np.asarray(y_pred, float)
    if y_pred.shape == (horizon, 3):  # a prediction without a whole trajectory is left out
        out.setdefault(coach_id, []).append((tick, y_pred))


def _errors(session: Session, predictions: dict, start, end, horizon: int, step_min: float):
    """The absolute errors of ``predictions`` (by coach) against the telemetry that followed:
    by coach, an array (predictions × T steps × 3 decks, K; NaN without an actual)."""
    if not predictions:
        return {}
    rows = session.execute(
        select(
            Telemetry.coach_id,
            Telemetry.time,
            Telemetry.t_room_up_c,
            Telemetry.t_room_mid_c,
            Telemetry.t_room_low_c,
            Telemetry.connected,
            Telemetry.mode,
        )
        .where(Telemetry.coach_id.in_(sorted(predictions)))
        .where(Telemetry.time > start)
        .where(Telemetry.time <= end + horizon * timedelta(minutes=step_min))
        .order_by(Telemetry.coach_id, Telemetry.time)
    ).all()
    by_coach: dict[str, list] = {}
    for row in rows:
        by_coach.setdefault(row[0], []).append(row[1:])
    steps_s = np.arange(1, horizon + 1) * step_min * 60.0
    out = {}
    for coach_id in sorted(predictions):
        coach_rows = by_coach.get(coach_id, [])
        time_s = np.array([r[0].timestamp() for r in coach_rows], float)
        y = np.array([r[1:4] for r in coach_rows], float).reshape(-1, 3)
        usable = np.array([r[4] and r[5] == "regular" for r in coach_rows], bool)
        ticks_s = np.array([t.timestamp() for t, _ in predictions[coach_id]], float)
        y_pred = np.stack([p for _, p in predictions[coach_id]])
        actual = actual_at(time_s, y, usable, ticks_s[:, None] + steps_s)
        out[coach_id] = np.abs(y_pred - actual)
    return out


def model_health(
    session: Session,
    model: PredictorModel,
    hours: float,
    period_min: float,
    drift_factor: float = DRIFT_FACTOR,
) -> dict:
    """``model``'s predictions issued in the window (start, end] of ``hours`` (h) up to its newest
    prediction tick, against the telemetry that followed them (see the module docstring).

    The step Δ is the model's ``sampling_min``, or ``period_min`` (the controller's period, min)
    for a model that does not record it. Per step 1 … T: the MAE over every coach, prediction
    and deck with an actual (°C, None without any) and the number of those (prediction, deck)
    pairs; per coach (by id): its first-step MAE (°C) and its samples over every step. Without a
    prediction of the model, ``start`` and ``end`` are None; without one in the window, the
    lists are empty. For a candidate, ``beside`` is the MAE per step of the setpoints' own
    predictions (the active model's at the time) on the same coaches and ticks. ``drift`` flags
    an online MAE (mean over the steps) above ``drift_factor`` times the validation MAE recorded
    with the model (``validation_mae_per_step_c``, when it has one) or above the bound. About
    0.2 s for 10 coaches over 24 h at Δ = 5 min."""
    step_min = model.sampling_min or period_min
    answer = {
        "version": model.version,
        "state": model.state,
        "start": None,
        "end": None,
        "step_min": step_min,
        "bound_c": BOUND_C,
        "predictions": 0,
        "samples": 0,
        "samples_per_step": [],
        "mae_per_step_c": [],
        "coaches": [],
        "exceeds_bound": False,
        "beside": None,
        "validation_mae_per_step_c": validation_mae(model),
        "drift_factor": drift_factor,
        "drift": False,
        "drift_reason": None,
    }
    end = session.scalar(select(func.max(Setpoint.tick)).where(Setpoint.model_id == model.id))
    shadow_end = session.scalar(
        select(func.max(ShadowPrediction.tick)).where(ShadowPrediction.model_id == model.id)
    )
    end = max((t for t in (end, shadow_end) if t is not None), default=None)
    if end is None:
        return answer
    start = end - timedelta(hours=hours)
    horizon = model.horizon
    predictions = _predictions(session, model.id, start, end, horizon)
    errors = _errors(session, predictions, start, end, horizon, step_min)
    coaches = []
    for coach_id, coach_errors in errors.items():
        first_mae, _ = mae_per_step(coach_errors[:, :1])
        samples = int(np.isfinite(coach_errors).sum())
        coaches.append({"coach_id": coach_id, "first_step_mae_c": first_mae[0], "samples": samples})
    answer.update(start=start, end=end, predictions=sum(len(p) for p in predictions.values()))
    if not errors:
        return answer
    mae, counts = mae_per_step(np.concatenate(list(errors.values())))
    answer.update(
        samples=sum(counts),
        samples_per_step=counts,
        mae_per_step_c=mae,
        coaches=coaches,
        exceeds_bound=mae[0] is not None and mae[0] > BOUND_C,
    )
    if shadow_end is not None:
        answer["beside"] = _beside(session, model, predictions, start, end, step_min)
    answer["drift_reason"] = drift(mae, answer["validation_mae_per_step_c"], drift_factor)
    answer["drift"] = answer["drift_reason"] is not None
    return answer


def validation_mae(model: PredictorModel) -> list[float] | None:
    """The validation MAE per step recorded with the model (°C), if any."""
    values = ((model.info or {}).get("validation") or {}).get("mae_per_step_c")
    return [float(v) for v in values] if values else None


def drift(online: list, validation: list | None, factor: float) -> str | None:
    """Why the online MAE per step (°C) shows drift, or None: its mean over the steps above
    ``factor`` × the validation MAE's mean, or above :data:`BOUND_C`."""
    values = [v for v in online if v is not None]
    if not values:
        return None
    mean = float(np.mean(values))
    if validation and mean > factor * float(np.mean(validation)):
        return (
            f"online MAE {mean:.3f} °C is more than {factor:g}× the validation MAE "
            f"{float(np.mean(validation)):.3f} °C"
        )
    if mean > BOUND_C:
        return f"online MAE {mean:.3f} °C exceeds the bound {BOUND_C} °C"
    return None


def _beside(session: Session, model: PredictorModel, mine: dict, start, end, step_min: float):
    """The issued setpoints' predictions at the (coach, tick) pairs of ``mine``: their MAE per
    step and samples (the model that issued them: the active one at the time)."""
    keys = {(c, t) for c, items in mine.items() for t, _ in items}
    rows = session.execute(
        select(Setpoint.coach_id, Setpoint.tick, Setpoint.predicted).where(
            Setpoint.coach_id.in_(sorted(mine)),
            Setpoint.tick > start,
            Setpoint.tick <= end,
            Setpoint.model_id.is_not(None),
            Setpoint.model_id != model.id,
        )
    ).all()
    theirs: dict[str, list] = {}
    for coach_id, tick, predicted in rows:
        if (coach_id, tick) in keys:
            _add(theirs, coach_id, tick, (predicted or {}).get("y_pred_c", []), model.horizon)
    errors = _errors(session, theirs, start, end, model.horizon, step_min)
    if not errors:
        return {"mae_per_step_c": [], "samples": 0, "predictions": 0}
    mae, counts = mae_per_step(np.concatenate(list(errors.values())))
    return {
        "mae_per_step_c": mae,
        "samples": sum(counts),
        "predictions": sum(len(p) for p in theirs.values()),
    }
