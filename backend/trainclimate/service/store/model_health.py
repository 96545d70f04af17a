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

from trainclimate.service.store.models import PredictorModel, Setpoint, Telemetry

#: The bound on the predictor's mean absolute error the paper holds it to (MAE ≤ 0.25 °C at every
#: step up to 60 min; docs/experiments.md). A model whose online first-step MAE over all its
#: coaches exceeds it is flagged (``exceeds_bound``). [°C]
BOUND_C = 0.25


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


def model_health(session: Session, model: PredictorModel, hours: float, period_min: float) -> dict:
    """``model``'s predictions issued in the window (start, end] of ``hours`` (h) up to its newest
    prediction tick, against the telemetry that followed them (see the module docstring).

    The step Δ is the model's ``sampling_min``, or ``period_min`` (the controller's period, min)
    for a model that does not record it. Per step 1 … T: the MAE over every coach, prediction
    and deck with an actual (°C, None without any) and the number of those (prediction, deck)
    pairs; per coach (by id): its first-step MAE (°C) and its samples over every step. Without a
    setpoint of the model, ``start`` and ``end`` are None; without a prediction in the window,
    the lists are empty. About 0.2 s for 10 coaches over 24 h at Δ = 5 min."""
    step_min = model.sampling_min or period_min
    answer = {
        "version": model.version,
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
    }
    of_model = Setpoint.model_id == model.id
    end = session.scalar(select(func.max(Setpoint.tick)).where(of_model))
    if end is None:
        return answer
    start = end - timedelta(hours=hours)
    in_window = (of_model, Setpoint.tick > start, Setpoint.tick <= end)
    setpoints = session.execute(
        select(Setpoint.coach_id, Setpoint.tick, Setpoint.predicted).where(*in_window)
    ).all()
    horizon = model.horizon
    predictions: dict[str, list[tuple[datetime, np.ndarray]]] = {}
    for coach_id, tick, predicted in setpoints:
        y_pred = np.asarray((predicted or {}).get("y_pred_c", []), float)
        if y_pred.shape == (horizon, 3):  # a setpoint without a whole trajectory is left out
            predictions.setdefault(coach_id, []).append((tick, y_pred))
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
        .where(Telemetry.coach_id.in_(select(Setpoint.coach_id).where(*in_window)))
        .where(Telemetry.time > start)
        .where(Telemetry.time <= end + horizon * timedelta(minutes=step_min))
        .order_by(Telemetry.coach_id, Telemetry.time)
    ).all()
    by_coach: dict[str, list] = {}
    for row in rows:
        by_coach.setdefault(row[0], []).append(row[1:])
    steps_s = np.arange(1, horizon + 1) * step_min * 60.0
    errors, coaches = [], []
    for coach_id in sorted(predictions):
        coach_rows = by_coach.get(coach_id, [])
        time_s = np.array([r[0].timestamp() for r in coach_rows], float)
        y = np.array([r[1:4] for r in coach_rows], float).reshape(-1, 3)
        usable = np.array([r[4] and r[5] == "regular" for r in coach_rows], bool)
        ticks_s = np.array([t.timestamp() for t, _ in predictions[coach_id]], float)
        y_pred = np.stack([p for _, p in predictions[coach_id]])
        actual = actual_at(time_s, y, usable, ticks_s[:, None] + steps_s)
        coach_errors = np.abs(y_pred - actual)
        first_mae, _ = mae_per_step(coach_errors[:, :1])
        samples = int(np.isfinite(coach_errors).sum())
        coaches.append({"coach_id": coach_id, "first_step_mae_c": first_mae[0], "samples": samples})
        errors.append(coach_errors)
    answer.update(start=start, end=end, predictions=sum(len(p) for p in predictions.values()))
    if not errors:
        return answer
    mae, counts = mae_per_step(np.concatenate(errors))
    answer.update(
        samples=sum(counts),
        samples_per_step=counts,
        mae_per_step_c=mae,
        coaches=coaches,
        exceeds_bound=mae[0] is not None and mae[0] > BOUND_C,
    )
    return answer
