"""Telemetry: storing what coaches report, and turning it into the controller's samples.

A telemetry row stamped t summarises the minute (t − 1 min, t] — the mean deck temperatures, the
T_ref applied, T_rule, the weather, occupancy, speed and HVAC power over it, the mode, and whether
the link was up — as an onboard logger's 1-minute averages do. So at a tick t everything the
controller needs has arrived, and the samples follow the training data's convention
(:mod:`trainclimate.data.trajectory`): y(t) is the row at t; u(t_k) and d(t_k), acting over
[t_k, t_k + Δ), are the means of the rows in (t_k, t_k + Δ].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Final, cast

import numpy as np
import pandas as pd
from sqlalchemy import Row, Table, case, select
from sqlalchemy.orm import Session

from trainclimate.service.store import binary_rows, rollups
from trainclimate.service.store.models import Telemetry
from trainclimate.service.store.records import TelemetryRecord
from trainclimate.service.store.upsert import insert_new_keys

Y_COLS = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
D_COLS = ("t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh")
VALUE_COLS = (*Y_COLS, "t_ref_c", "t_rule_c", *D_COLS, "ghi_w_m2", "power_kw", "floor_power_kw")


def insert_rows(session: Session, coach_id: str, rows: list[TelemetryRecord]) -> int:
    """Insert telemetry rows of one coach, skipping times already stored (a gateway that resends
    a batch after a lost connection changes nothing, also when both copies arrive at once) and
    repeated in the batch (the first is kept), and add those stored to the coach's window
    rollups (:mod:`.rollups`). Returns how many were new. Inserted in time order, so two writers
    of overlapping batches take the rows' locks in the same order and cannot deadlock."""
    fresh: list[TelemetryRecord] = []
    seen: set[datetime] = set()
    for r in rows:
        if r["time"] not in seen:
            seen.add(r["time"])
            fresh.append(r)
    fresh.sort(key=lambda r: r["time"])
    insert = [{**r, "coach_id": coach_id} for r in fresh]
    table = cast(Table, Telemetry.__table__)
    stored = set(insert_new_keys(session, table, insert, ["coach_id", "time"], "time"))
    rollups.add_rows(session, {coach_id: [r for r in fresh if r["time"] in stored]})
    return len(stored)


FRAME_COLS = ("time", *VALUE_COLS, "mode", "connected")


def _select(
    session: Session, coach_ids: list[str], start: datetime, end: datetime
) -> Sequence[Row]:
    """The rows (coach_id, *FRAME_COLS) of ``coach_ids`` with start < time ≤ end, by coach and
    time."""
    cols = [Telemetry.coach_id, *(getattr(Telemetry, c) for c in FRAME_COLS)]
    return session.execute(
        select(*cols)
        .where(Telemetry.coach_id.in_(coach_ids), Telemetry.time > start, Telemetry.time <= end)
        .order_by(Telemetry.coach_id, Telemetry.time)
    ).all()


def load_frame(session: Session, coach_id: str, start: datetime, end: datetime) -> pd.DataFrame:
    """The coach's rows with start < time ≤ end as a DataFrame indexed by UTC time."""
    frame = pd.DataFrame(
        [r[1:] for r in _select(session, [coach_id], start, end)], columns=list(FRAME_COLS)
    )
    frame["time"] = pd.to_datetime(frame["time"], utc=True)
    return frame.set_index("time")


@dataclass
class CoachRows:
    """One coach's telemetry rows, oldest first, as arrays: ``time_s`` (n,) Unix time of each
    row's end, s; ``values`` (n, len(VALUE_COLS)) in :data:`VALUE_COLS` order (NaN where
    missing); ``regular`` (n,) whether the row's minute was entirely in regular mode."""

    time_s: np.ndarray
    values: np.ndarray
    regular: np.ndarray

    def column(self, name: str) -> np.ndarray:
        """The values (n,) of column ``name`` of :data:`VALUE_COLS`."""
        return self.values[:, VALUE_COLS.index(name)]


def load_rows(
    session: Session, coach_ids: list[str], start: datetime, end: datetime
) -> dict[str, CoachRows]:
    """Every coach's rows with start < time ≤ end (empty arrays for a coach without any), from
    one query, without a DataFrame or an object per row (the tick reads 1 000 coaches at a
    time): on PostgreSQL packed by the server (:mod:`.binary_rows`) with each row's time as
    epoch seconds, a value not reported as NaN and its regular mode as 0/1; elsewhere the driver's
    tuples, column by column."""
    if session.get_bind().dialect.name == "postgresql":
        coach, time_s, values, regular = _packed_rows(session, coach_ids, start, end)
    else:
        coach, time_s, values, regular = _selected_rows(session, coach_ids, start, end)
    # each coach's rows are contiguous and in time order: where each coach's run starts
    edges = np.searchsorted(coach, np.arange(len(coach_ids) + 1))
    return {
        cid: CoachRows(time_s[a:b], values[a:b], regular[a:b])
        for cid, a, b in zip(coach_ids, edges[:-1], edges[1:], strict=True)
    }


def _packed_rows(session: Session, coach_ids: list[str], start: datetime, end: datetime):
    """:func:`load_rows`' columns on PostgreSQL: (coach's position in ``coach_ids``, time [s
    since 1970], values (n, len(VALUE_COLS)), regular) ordered by coach and time."""
    from psycopg import sql

    dtype = np.dtype(
        [("coach", np.int64), ("time", np.float64)]
        + [(c, np.float64) for c in VALUE_COLS]
        + [("regular", np.int64)]
    )
    # coach by coach (LATERAL, kept apart by OFFSET 0): one range scan of the (coach, time)
    # index each, whatever the planner estimates of a table whose statistics lag its inserts
    query = sql.SQL(
        "SELECT k.i - 1, date_part('epoch', t.time), {values}, "
        "(t.mode = 'regular')::int::int8 "
        "FROM unnest({ids}) WITH ORDINALITY AS k(id, i) CROSS JOIN LATERAL "
        "(SELECT * FROM telemetry WHERE coach_id = k.id AND time > {start} AND time <= {end} "
        "OFFSET 0) AS t"
    ).format(
        values=sql.SQL(", ").join(
            sql.SQL("coalesce(t.{}, 'NaN'::float8)").format(sql.Identifier(c)) for c in VALUE_COLS
        ),
        ids=binary_rows.array_of(coach_ids, "text"),
        start=sql.Literal(start),
        end=sql.Literal(end),
    )
    rows = binary_rows.packed_rows(session, query, dtype)
    rows = rows[
        np.lexsort((rows["time"], rows["coach"]))
    ]  # a sort here costs less than the server's
    values = np.stack([rows[c] for c in VALUE_COLS], axis=-1).reshape(len(rows), len(VALUE_COLS))
    return rows["coach"], rows["time"], values, rows["regular"] == 1


def _selected_rows(session: Session, coach_ids: list[str], start: datetime, end: datetime):
    """:func:`_packed_rows` through the driver's tuples (SQLite)."""
    t = Telemetry.__table__
    position = case({c: i for i, c in enumerate(coach_ids)}, value=t.c.coach_id)
    query = (
        select(position, t.c.time, *(t.c[c] for c in VALUE_COLS), t.c.mode == "regular")
        .where(t.c.coach_id.in_(coach_ids), t.c.time > start, t.c.time <= end)
        .order_by(position, t.c.time)
    )
    rows = session.connection().execute(query).all()
    columns = list(zip(*rows, strict=True)) or [()] * (3 + len(VALUE_COLS))
    # the stored time, converted here (SQLite's own epoch has whole seconds only)
    time_s = np.array([x.timestamp() for x in columns[1]], float)
    values = np.array(columns[2 : 2 + len(VALUE_COLS)], float).T.reshape(len(rows), len(VALUE_COLS))
    return np.array(columns[0], np.int64), time_s, values, np.array(columns[-1], bool)


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


_Y = [VALUE_COLS.index(c) for c in Y_COLS]
_U = VALUE_COLS.index("t_ref_c")
_D = [VALUE_COLS.index(c) for c in D_COLS]


def controller_samples(rows: CoachRows, tick_s: float, period_s: float) -> Samples:
    """Samples at the ticks t, t − Δ, … (t = ``tick_s``, Δ = ``period_s``, s) covered by
    ``rows``, walking back until the first tick without a complete reading (no row in its last
    minute, or a NaN deck temperature) or the first interval with missing rows, a NaN input or
    disturbance, or a minute not in regular mode (the controller's model only knows regular
    mode; its lead-in starts again after anything else)."""
    minutes = round(period_s / 60.0)
    time_s, v = rows.time_s, rows.values
    if len(time_s):
        last = v[-1]
        u_prev, t_rule_now = float(last[_U]), float(last[VALUE_COLS.index("t_rule_c")])
        regular_now, last_time_s = bool(rows.regular[-1]), float(time_s[-1])
    else:
        u_prev = t_rule_now = float("nan")
        regular_now, last_time_s = False, None
    times: np.ndarray = np.zeros(0)
    y, u, d = np.zeros((0, 3)), np.zeros(0), np.zeros((0, len(_D)))
    if last_time_s is not None and last_time_s >= tick_s - 60.0:
        # the ticks t = tick − kΔ that rows can cover, newest first
        times = tick_s - period_s * np.arange(int((tick_s - time_s[0]) // period_s) + 2)
        hi = np.searchsorted(time_s, times, side="right")
        reading = np.searchsorted(time_s, times - 60.0, side="right")  # (t − 1 min, t]
        interval = np.searchsorted(time_s, times - period_s, side="right")  # (t − Δ, t]
        y_bad = np.r_[0, np.cumsum(np.isnan(v[:, _Y]).any(axis=1))]
        block_bad = np.r_[0, np.cumsum(~rows.regular | np.isnan(v[:, [_U, *_D]]).any(axis=1))]
        # a tick's reading: a row in its last minute, every deck temperature known; the
        # interval before it: complete, regular, and with every input
        read = (hi > reading) & (y_bad[hi] == y_bad[reading])
        whole = (hi - interval >= minutes) & (block_bad[hi] == block_bad[interval])
        # walking back: every tick read, and the interval before each but the oldest whole
        walked = np.cumprod(read & np.r_[True, whole[:-1]])
        n = int(walked.sum())
        times, m = times[:n], max(n - 1, 0)
        y = _means(v[:, _Y], reading[:n], hi[:n])
        u = _means(v[:, _U], interval[:m], hi[:m])
        d = _means(v[:, _D], interval[:m], hi[:m])
    # oldest first; the samples are the ticks, u and d the intervals between consecutive ones
    return Samples(
        times_s=times[::-1].astype(float),
        y=y[::-1].reshape(-1, 3),
        u=u[::-1].astype(float),
        d_past=d[::-1].reshape(-1, 5),
        d_now=d[0] if len(d) else None,
        u_prev=u_prev,
        t_rule_now=t_rule_now,
        regular=regular_now,
        last_time_s=last_time_s,
    )


def _means(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The means of ``values`` (n,) or (n, c) over the rows [lo_k, hi_k) of each k, shape
    (k,) or (k, c), equal to the bit to ``values[lo_k:hi_k].mean(axis=0)``: numpy sums fewer
    than 8 rows one after the other, which is done here for every k at once (one addition per
    row of the longest; a finished sum adds 0); longer ranges are left to numpy."""
    length = hi - lo
    if len(lo) == 0 or length.max() >= 8:
        return np.array([values[a:b].mean(axis=0) for a, b in zip(lo, hi, strict=True)]).reshape(
            len(lo), *values.shape[1:]
        )
    total = np.zeros((len(lo), *values.shape[1:]))
    for j in range(int(length.max())):
        row = values[np.minimum(lo + j, len(values) - 1)]
        within = (j < length).reshape(-1, *([1] * (values.ndim - 1)))
        total = total + np.where(within, row, 0.0)
    return total / length.reshape(-1, *([1] * (values.ndim - 1)))


#: The fields of a ``POST /api/v1/telemetry`` row besides ``time`` and ``t_room_c``.
WIRE_FIELDS: Final = (
    "t_ref_c",
    "t_rule_c",
    "t_amb_c",
    "ghi_w_m2",
    "q_gt_w_m2",
    "q_gs_w_m2",
    "occupancy_pct",
    "speed_kmh",
    "power_kw",
    "floor_power_kw",
    "mode",
    "connected",
)


def to_wire(row: TelemetryRecord) -> dict[str, Any]:
    """A stored row (one value per column) as a row of ``POST /api/v1/telemetry``: the time in
    ISO 8601 with its offset and the decks as ``t_room_c`` [up, mid, low]; a field the row does
    not have (a feed without the floor heating's share) is left out."""
    return {
        "time": pd.Timestamp(row["time"]).isoformat(),
        "t_room_c": [row["t_room_up_c"], row["t_room_mid_c"], row["t_room_low_c"]],
        **{k: row[k] for k in WIRE_FIELDS if k in row},
    }


def from_wire(row: Mapping[str, Any]) -> TelemetryRecord:
    """A validated row of ``POST /api/v1/telemetry`` (or of an MQTT telemetry message) as a
    stored row: the inverse of :func:`to_wire`."""
    up, mid, low = row["t_room_c"]
    stored: TelemetryRecord = {
        "time": row["time"],
        "t_room_up_c": up,
        "t_room_mid_c": mid,
        "t_room_low_c": low,
    }
    for k in WIRE_FIELDS:
        stored[k] = row.get(k)
    return stored


def rows_from_simulation(
    sim, k0: int, k1: int, coach_ids: list[str], disconnected: np.ndarray | None = None
) -> dict[str, list[TelemetryRecord]]:
    """Telemetry rows of a :class:`~trainclimate.sim.simulator.FleetSimulator`'s steps [k0, k1),
    one per coach and minute (the minute up to the row's time), as a logger would report them:
    the sensors' mean, the applied T_ref and T_rule, the weather, occupancy, speed, the power and
    the floor and wall heating's share of it,
    and whether the link was up: ``connected`` is false for a coach's minute with a step where
    ``disconnected`` ((steps, coaches) bool on the simulator's grid; default none) is true."""
    from trainclimate.coach.rule import MODE_NAMES, MODE_REGULAR

    r, env = sim.result(), sim.env
    per_min = round(60.0 / sim.dt_s)
    out: dict[str, list[TelemetryRecord]] = {cid: [] for cid in coach_ids}
    for a in range(k0, k1, per_min):
        b = min(a + per_min, k1)
        stamp = (env.time[a] + pd.Timedelta(seconds=(b - a) * sim.dt_s)).to_pydatetime()
        sl = slice(a, b)
        y = r.t_room_meas_c[sl].mean(axis=0)
        # the minute's power only: the total over all steps so far would grow with the day
        power_kw = sum(v[sl] for v in r.power_w.values()).mean(axis=0) / 1e3
        floor_kw = r.power_w["floor_wall"][sl].mean(axis=0) / 1e3
        up = (
            np.ones(len(coach_ids), bool)
            if disconnected is None
            else ~np.any(disconnected[sl], axis=0)
        )
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
                    "power_kw": float(power_kw[c]),
                    "floor_power_kw": float(floor_kw[c]),
                    "mode": mode,
                    "connected": bool(up[c]),
                }
            )
    return out
