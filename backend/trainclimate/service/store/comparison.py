"""A train's pair comparison over a range: each window with the coach that ran the layer and why
it is excluded if it is, the totals over the counted windows, and the trial estimate with its
interval (:mod:`.pair_trial`). The fleet summary computes every train's figures the same way, from
the same window sums and setpoint counts, in one statement for all trains.

:func:`comparison_state` reads what a comparison is computed from, in a few index probes: the
state its answer is kept under in :class:`~trainclimate.service.store.cache.ReadCache`.
"""

from __future__ import annotations

from datetime import datetime

import pandas as pd
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from trainclimate.analysis.savings import savings_pct
from trainclimate.service.store import pair_trial, pair_windows, plans, queries
from trainclimate.service.store.models import Telemetry, Train


def _range(
    session: Session, train: Train, start: datetime, end: datetime, window_min: float
) -> tuple:
    """The pair (coach 0, coach 1), its first window's start and number of windows over
    (start, end], and the pair's ranges as :func:`.pair_windows.pair_data` takes them."""
    c0, c1 = queries.pair_or_422(train)
    # each coach's first row on its own: one index probe each (a min over both coaches at once
    # reads every index entry of both)
    firsts = [
        session.scalar(select(func.min(Telemetry.time)).where(Telemetry.coach_id == c.id))
        for c in (c0, c1)
    ]
    first, n = queries.counted_range(
        start, end, min((t for t in firsts if t), default=None), window_min
    )
    hi = first + pd.Timedelta(minutes=window_min * n)
    return c0, c1, first, n, [(c0.id, c1.id, first.to_pydatetime(), hi.to_pydatetime())]


def _plan(session: Session, train: Train, end: datetime) -> tuple[str, int, int]:
    """(plan, switch hour [h], seed) of the train's plan in force at ``end``."""
    row = plans.plans_at(session, [train.id], end).get(train.id, (None, None))[0]
    return plans.terms(row)


def comparison_state(
    session: Session, train: Train, start: datetime, end: datetime, window_min: float
) -> tuple:
    """What :func:`comparison` of ``train`` over (start, end] is computed from, besides the
    parameters: the pair and its coaches' roles now, its counted range, and its rows, setpoints
    and overrides in it (:func:`.pair_windows.pair_states`)."""
    c0, c1, first, n, pairs = _range(session, train, start, end, window_min)
    overrides = pair_windows.overrides_over(session, pairs)
    states = pair_windows.pair_states(session, pairs, overrides)
    plan = _plan(session, train, end)
    return (c0.id, c0.ddpc_active, c1.id, c1.ddpc_active, plan, first, n, *states)


def comparison(
    session: Session, train: Train, start: datetime, end: datetime, window_min: float = 30.0
) -> dict:
    """The train's pair over (start, end]: per window the energies, the saving, the coach that
    ran the layer and the reason it is excluded; the totals on each meter; the trial estimate.

    Parameters
    ----------
    train : Train
        With a pair of coaches (:func:`.queries.pair_or_422`).
    start, end : datetime
        The range (timezone-aware); windows start at the first boundary after ``start`` (or
        the pair's first row).
    window_min : float, default 30.0
        Window length. [min]

    Returns
    -------
    dict
        ``train_id``, ``plan`` (in force at ``end``; its switch hour starts the service days),
        ``coaches`` (coach 0, coach 1), ``activated`` / ``deactivated`` (the
        coaches' roles now), ``start``, ``end``, ``window_min``, ``windows`` (per window:
        ``start``, ``activated`` — the coach under the layer, None for none —,
        ``energy_kwh`` per coach, ``energy_activated_kwh``, ``energy_deactivated_kwh``,
        ``savings_pct``, ``excluded``, ``excluded_reason``), the figures of
        :func:`.pair_trial.figures` (``savings_pct`` is the trial estimate's,
        ``naive_savings_pct`` the energies' over the counted windows) and, for the old field
        names, ``avg_hourly_violation_k`` and ``baseline_violation_k``.
    """
    c0, c1, first, _, pairs = _range(session, train, start, end, window_min)
    if pd.Timestamp(end) - first < pd.Timedelta(minutes=2):
        raise queries.RequestError("the range is shorter than two minutes")
    grid, counts = pair_windows.pair_data(session, pairs, window_min)[c0.id]
    plan, switch_hour, _ = _plan(session, train, end)
    r = pair_trial.pair_result(grid, counts, first, window_min, switch_hour)
    e0, e1 = r["grid"][:, list(pair_trial.energy_columns(r["meter"]))].T
    ids = (c0.id, c1.id)
    out_windows = []
    why = pair_trial.reasons(r)
    for i, w in enumerate(r["index"]):
        label, reason = int(r["label"][i]), why[i]
        act, deact = (e1[i], e0[i]) if label == 1 else (e0[i], e1[i])
        counted = bool(r["counted"][i])
        out_windows.append(
            {
                "start": pd.Timestamp(w * window_min * 60, unit="s", tz="UTC").to_pydatetime(),
                "activated": ids[label] if label >= 0 else None,
                "energy_kwh": {c0.id: float(e0[i]), c1.id: float(e1[i])},
                "energy_activated_kwh": float(act),
                "energy_deactivated_kwh": float(deact),
                "savings_pct": savings_pct(act, deact) if counted else None,
                "excluded": not counted,
                "excluded_reason": reason if reason is not None or counted else "reference",
            }
        )
    figures = r["figures"]
    return {
        "train_id": train.id,
        "plan": plan,
        "coaches": list(ids),
        "activated": next((c.id for c in (c0, c1) if c.ddpc_active), None),
        "deactivated": next((c.id for c in (c0, c1) if not c.ddpc_active), None),
        "start": first.to_pydatetime(),
        "end": pd.Timestamp(end).to_pydatetime(),
        "window_min": window_min,
        "windows": out_windows,
        **figures,
        "avg_hourly_violation_k": figures["avg_hourly_violation_activated_k"],
        "baseline_violation_k": figures["avg_hourly_violation_deactivated_k"],
    }
