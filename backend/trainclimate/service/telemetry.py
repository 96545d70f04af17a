"""Telemetry: storing what coaches report, and turning it into the controller's samples.

A telemetry row stamped t summarises the minute (t − 1 min, t] — the mean deck temperatures, the
T_ref applied, T_rule, the weather, occupancy, speed and HVAC power over it, the mode, and whether
the link was up — as an onboard logger's 1-minute averages do. So at a tick t everything the
controller needs has arrived, and the samples follow the training data's convention
(:mod:`trainclimate.data.trajectory`): y(t) is the row at t; u(t_k) and d(t_k), acting over
[t_k, t_k + Δ), are the means of the rows in (t_k, t_k + Δ].
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

import numpy as np
import pandas as pd
from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate.service.models import Telemetry

Y_COLS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
D_COLS = ("t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh")
VALUE_COLS = (*Y_COLS, "t_ref_c", "t_rule_c", *D_COLS, "ghi_w_m2", "power_kw")


def insert_rows(session: Session, coach_id: str, rows: list[dict]) -> int:
    """Insert telemetry rows of one coach, skipping times already stored (a gateway that resends
    a batch after a lost connection changes nothing). Returns how many were new."""
    if not rows:
        return 0
    times = [r["time"] for r in rows]
    existing = set(
        session.scalars(
            select(Telemetry.time).where(
                Telemetry.coach_id == coach_id,
                Telemetry.time >= min(times),
                Telemetry.time <= max(times),
            )
        )
    )
    fresh, seen = [], set()
    for r in rows:
        if r["time"] in existing or r["time"] in seen:
            continue
        seen.add(r["time"])
        fresh.append({**r, "coach_id": coach_id})
    if fresh:
        session.execute(Telemetry.__table__.insert(), fresh)
    return len(fresh)


FRAME_COLS = ("time", *VALUE_COLS, "mode", "connected")


def _frame(rows) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=list(FRAME_COLS))
    frame["time"] = pd.to_datetime(frame["time"], utc=True)
    return frame.set_index("time")


def load_frame(session: Session, coach_id: str, start: datetime, end: datetime) -> pd.DataFrame:
    """The coach's rows with start < time ≤ end as a DataFrame indexed by UTC time."""
    return load_frames(session, [coach_id], start, end)[coach_id]


def load_frames(
    session: Session, coach_ids: list[str], start: datetime, end: datetime
) -> dict[str, pd.DataFrame]:
    """:func:`load_frame` for many coaches in one query."""
    cols = [Telemetry.coach_id, *(getattr(Telemetry, c) for c in FRAME_COLS)]
    rows = session.execute(
        select(*cols)
        .where(Telemetry.coach_id.in_(coach_ids), Telemetry.time > start, Telemetry.time <= end)
        .order_by(Telemetry.coach_id, Telemetry.time)
    ).all()
    grouped: dict[str, list] = {cid: [] for cid in coach_ids}
    for row in rows:
        grouped[row[0]].append(row[1:])
    return {cid: _frame(r) for cid, r in grouped.items()}


@dataclass
class Samples:
    """The controller's samples at the ticks up to t (oldest first): ``times_s`` (m,), ``y``
    (m, 3), ``u`` (m − 1,) and ``d_past`` (m − 1, 5) over the intervals between them; ``d_now``
    the newest interval's d (the persistence forecast's base); ``u_prev`` the T_ref applied last;
    ``t_rule_now`` the coach's T_rule at t; ``regular`` whether the coach is in regular mode;
    ``last_time_s`` the newest row's time (None without any)."""

    times_s: np.ndarray
    y: np.ndarray
    u: np.ndarray
    d_past: np.ndarray
    d_now: np.ndarray | None
    u_prev: float
    t_rule_now: float
    regular: bool
    last_time_s: float | None = None


def controller_samples(frame: pd.DataFrame, tick: pd.Timestamp, period_s: float) -> Samples:
    """Samples at the ticks t, t − Δ, … covered by ``frame``, cut at the first gap, interval
    with missing rows, or interval not entirely in regular mode (the controller's model only
    knows regular mode; its lead-in starts again after anything else)."""
    step = pd.Timedelta(seconds=period_s)
    minutes = round(period_s / 60.0)
    last = frame.iloc[-1] if len(frame) else None
    u_prev = float(last["t_ref_c"]) if last is not None else float("nan")
    t_rule_now = float(last["t_rule_c"]) if last is not None else float("nan")
    regular_now = bool(last is not None and last["mode"] == "regular")
    last_time_s = frame.index[-1].timestamp() if last is not None else None
    if last is None or frame.index[-1] < tick - pd.Timedelta(minutes=1):
        return Samples(
            times_s=np.empty(0),
            y=np.empty((0, 3)),
            u=np.empty(0),
            d_past=np.empty((0, 5)),
            d_now=None,
            u_prev=u_prev,
            t_rule_now=t_rule_now,
            regular=regular_now,
            last_time_s=last_time_s,
        )
    times, ys, us, ds = [], [], [], []
    t = tick
    while True:
        y = frame.loc[(frame.index > t - pd.Timedelta(minutes=1)) & (frame.index <= t)]
        if y.empty or y[list(Y_COLS)].isna().any().any():
            break
        times.append(t)
        ys.append(y[list(Y_COLS)].to_numpy(float).mean(axis=0))
        previous = t - step
        block = frame.loc[(frame.index > previous) & (frame.index <= t)]
        complete = (
            len(block) >= minutes
            and (block["mode"] == "regular").all()
            and not block[["t_ref_c", *D_COLS]].isna().any().any()
        )
        if not complete:
            break
        us.append(float(block["t_ref_c"].mean()))
        ds.append(block[list(D_COLS)].to_numpy(float).mean(axis=0))
        t = previous
    times, ys = times[::-1], ys[::-1]
    us, ds = us[::-1], ds[::-1]
    # the samples are the ticks; u and d are the intervals between consecutive ones
    n = len(times)
    us, ds = us[len(us) - (n - 1) :] if n > 1 else [], ds[len(ds) - (n - 1) :] if n > 1 else []
    return Samples(
        times_s=np.array([x.timestamp() for x in times]),
        y=np.array(ys).reshape(-1, 3),
        u=np.array(us),
        d_past=np.array(ds).reshape(-1, 5),
        d_now=ds[-1] if ds else None,
        u_prev=u_prev,
        t_rule_now=t_rule_now,
        regular=regular_now,
        last_time_s=last_time_s,
    )


def rows_from_simulation(sim, k0: int, k1: int, coach_ids: list[str]) -> dict[str, list[dict]]:
    """Telemetry rows of a :class:`~trainclimate.sim.simulator.FleetSimulator`'s steps [k0, k1),
    one per coach and minute (the minute up to the row's time), as a logger would report them:
    the sensors' mean, the applied T_ref and T_rule, the weather, occupancy, speed and power."""
    from trainclimate.sim.rule import MODE_NAMES, MODE_REGULAR

    r, env = sim.result(), sim.env
    per_min = round(60.0 / sim.dt_s)
    out: dict[str, list[dict]] = {cid: [] for cid in coach_ids}
    for a in range(k0, k1, per_min):
        b = min(a + per_min, k1)
        stamp = (env.time[a] + pd.Timedelta(seconds=(b - a) * sim.dt_s)).to_pydatetime()
        sl = slice(a, b)
        y = r.t_room_meas_c[sl].mean(axis=0)
        for c, cid in enumerate(coach_ids):
            modes = env.mode[sl, c]
            mode = "regular" if np.all(modes == MODE_REGULAR) else MODE_NAMES[int(modes[-1])]
            out[cid].append(
                {
                    "time": stamp,
                    "t_room_up_c": float(y[c, 0]),
                    "t_room_mid_c": float(y[c, 1]),
                    "t_room_low_c": float(y[c, 2]),
                    "t_ref_c": float(r.t_ref_c[sl, c].mean()),
                    "t_rule_c": float(r.t_rule_c[sl, c].mean()),
                    "t_amb_c": float(env.t_amb_c[sl, c].mean()),
                    "ghi_w_m2": float(env.ghi_w_m2[sl, c].mean()),
                    "q_gt_w_m2": float(env.q_roof_w_m2[sl, c].mean()),
                    "q_gs_w_m2": float(env.q_side_w_m2[sl, c].mean()),
                    "occupancy_pct": float(env.occupancy_pct[sl, c].mean()),
                    "speed_kmh": float(env.speed_kmh[sl, c].mean()),
                    "power_kw": float(r.total_power_w[sl, c].mean() / 1e3),
                    "mode": mode,
                    "connected": True,
                }
            )
    return out
