"""Helpers of the service tests.

Telemetry rows in the store's format (:data:`trainclimate.service.store.telemetry.FRAME_COLS`,
one per coach and minute, stamped at the minute's end): realistic ones from a short simulation of
three empty coaches parked outdoors in Zug on a cold November morning (:func:`sim_rows`, the
rule-based HVAC in regular mode throughout), or hand-made constant ones (:func:`flat_row`);
`to_wire` (from the telemetry module) turns a row into the body ``POST /api/v1/telemetry`` takes.
:data:`T0` is a tick (a multiple of the 5-min period) and the simulation's start, so the row
stamped ``T0 + k min`` is the k-th simulated minute.
"""

from __future__ import annotations

import functools
import os
import time
import uuid
from collections.abc import Callable
from datetime import UTC, datetime, timedelta

import numpy as np
import psycopg
import pytest

from trainclimate.control.coach_model import CoachModel
from trainclimate.service import scheduler
from trainclimate.service.store.telemetry import rows_from_simulation, to_wire
from trainclimate.sim import scenarios
from trainclimate.sim.simulator import FleetSimulator

API = "/api/v1"
#: The parked-heating-nov scenario's start (07:00 in Zurich), a tick of the 5-min grid.
T0 = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
SIM_COACHES = 3
SIM_MINUTES = 120


@functools.cache
def _coach_model(dt_s: float) -> CoachModel:
    return CoachModel(dt_s=dt_s)


@pytest.fixture(autouse=True)
def shared_coach_model(monkeypatch):
    """Every scheduler of a test process shares one coach model per period (building it, some
    eighty matrix exponentials, is most of starting a scheduler, 0.1–0.3 s; it is read only).
    Autouse in the modules that import it."""
    monkeypatch.setattr(scheduler, "CoachModel", lambda dt_s=300.0: _coach_model(float(dt_s)))


PG_URL = os.environ.get("TRAINCLIMATE_TEST_PG_URL")
PG_SKIP = "TRAINCLIMATE_TEST_PG_URL is not set: no PostgreSQL server to test against"


def pg_database(template: str | None = None) -> tuple[str, str]:
    """A fresh database on the test server, or a copy of the database ``template`` (which no
    one may be connected to): (its URL, its name)."""
    name = f"tc_test_{uuid.uuid4().hex[:12]}"
    copy = f' TEMPLATE "{template}"' if template else ""
    with psycopg.connect(PG_URL, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"{copy}')
    base = PG_URL.rsplit("/", 1)[0]
    return f"{base}/{name}", name


def drop_pg_database(name: str) -> None:
    with psycopg.connect(PG_URL, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def at(minutes: float) -> datetime:
    """``T0`` plus ``minutes``."""
    return T0 + timedelta(minutes=minutes)


@functools.cache
def _simulation() -> tuple[tuple[dict, ...], ...]:
    """Two hours of three coaches (≈ 0.5 s, once per process)."""
    scenario = scenarios.get("parked-heating-nov")
    env, params = scenarios.build(scenario, n_coaches=SIM_COACHES, hours=SIM_MINUTES / 60)
    assert env.time[0] == T0
    sim = FleetSimulator(params, env, seed=7)
    sim.run()
    ids = [str(i) for i in range(SIM_COACHES)]
    rows = rows_from_simulation(sim, 0, sim.k, ids)
    return tuple(tuple(rows[i]) for i in ids)


def sim_rows(coach: int, first: int, last: int) -> list[dict]:
    """The simulated coach ``coach``'s rows stamped ``T0 + first`` … ``T0 + last`` minutes
    (1 ≤ first ≤ last ≤ 120), copies."""
    rows = _simulation()[coach]
    assert 1 <= first <= last <= len(rows)
    out = [dict(r) for r in rows[first - 1 : last]]
    assert out[0]["time"] == at(first) and out[-1]["time"] == at(last)
    return out


def flat_row(time: datetime, **values) -> dict:
    """A hand-made row: decks at 21.5 °C, T_ref = T_rule = 22 °C, 0 °C outside, dark, parked,
    10 kW (its floor heating's share not reported), regular mode, connected — ``values`` replace
    any of them."""
    row = {
        "time": time,
        "t_room_up_c": 21.5,
        "t_room_mid_c": 21.5,
        "t_room_low_c": 21.5,
        "t_ref_c": 22.0,
        "t_rule_c": 22.0,
        "t_amb_c": 0.0,
        "ghi_w_m2": 0.0,
        "q_gt_w_m2": 0.0,
        "q_gs_w_m2": 0.0,
        "occupancy_pct": 0.0,
        "speed_kmh": 0.0,
        "power_kw": 10.0,
        "floor_power_kw": None,
        "mode": "regular",
        "connected": True,
    }
    unknown = set(values) - set(row)
    assert not unknown, unknown
    row.update(values)
    return row


def flat_rows(first: int, last: int, **values) -> list[dict]:
    """:func:`flat_row` stamped ``T0 + first`` … ``T0 + last`` minutes."""
    return [flat_row(at(m), **values) for m in range(first, last + 1)]


def registered(db_url: str, coaches: list[tuple[str, bool]]):
    """A migrated :class:`~trainclimate.service.store.db.Database` at ``db_url`` with live coaches
    (id ``{train}-…``, layer activated or not) and their trains."""
    from trainclimate.service.store.db import Database, migrate
    from trainclimate.service.store.models import Coach, Train

    migrate(db_url)
    database = Database(db_url)
    with database.transaction() as s:
        trains = sorted({cid.rsplit("-", 1)[0] for cid, _ in coaches})
        s.add_all([Train(id=t, name=t) for t in trains])
        s.flush()
        for cid, active in coaches:
            s.add(Coach(id=cid, train_id=cid.rsplit("-", 1)[0], fleet="live", ddpc_active=active))
    return database


def wait_for(condition: Callable[[], object], timeout_s: float = 15.0, what: str = ""):
    """Poll ``condition`` until it returns something truthy (returned); fail after the time."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what or condition}")
        time.sleep(0.02)


# --- the HTTP API ----------------------------------------------------------------------------
def register(client, headers, coach_id: str, train_id: str = "T", active: bool = True):
    """``POST /coaches``."""
    body = {"id": coach_id, "train_id": train_id, "ddpc_active": active}
    return client.post(f"{API}/coaches", json=body, headers=headers)


def post_rows(client, headers, coach_id: str, rows: list[dict]):
    """``POST /telemetry`` with stored-format rows."""
    body = {"coach_id": coach_id, "rows": [to_wire(r) for r in rows]}
    return client.post(f"{API}/telemetry", json=body, headers=headers)


def wait_for_tick(client, headers, coach_id: str, tick: datetime) -> dict:
    """The coach's setpoint once the live loop (the app's thread) has issued ``tick``."""

    def issued():
        sp = client.get(f"{API}/coaches/{coach_id}/setpoint", headers=headers).json()
        return sp if sp["tick"] and datetime.fromisoformat(sp["tick"]) >= tick else None

    sp = wait_for(issued, what=f"the tick {tick:%H:%M} of coach {coach_id}")
    assert datetime.fromisoformat(sp["tick"]) == tick
    return sp


def count(url: str, model, **where) -> int:
    """How many rows of ``model`` (matching ``where``) the database at ``url`` holds."""
    from sqlalchemy import func, select

    from trainclimate.service.store.db import Database

    db = Database(url)
    try:
        with db.transaction() as s:
            q = select(func.count()).select_from(model)
            for key, value in where.items():
                q = q.where(getattr(model, key) == value)
            return s.scalar(q)
    finally:
        db.dispose()


def rows_per_minute(url: str) -> dict[tuple[str, datetime], int]:
    """How many telemetry rows each (coach, time) has in the database at ``url``."""
    from sqlalchemy import func, select

    from trainclimate.service.store.db import Database
    from trainclimate.service.store.models import Telemetry

    db = Database(url)
    try:
        with db.transaction() as s:
            q = select(Telemetry.coach_id, Telemetry.time, func.count())
            q = q.group_by(Telemetry.coach_id, Telemetry.time)
            return {(coach, t): n for coach, t, n in s.execute(q)}
    finally:
        db.dispose()


def decided(
    client, coach_id: str, first: int, last: int, source: str = "ddpc", reason: str = "ok"
) -> None:
    """Setpoints of ``coach_id`` at the ticks at(first), at(first + 5), … ≤ at(last), as the
    scheduler stores them (``ddpc``/``ok``; the layer off: ``rule``/``inactive``) and counts them
    (:mod:`.setpoint_rollups`), where the coach has none; the coach's last tick moved up to the
    newest, so the live loop does not issue them again."""
    from sqlalchemy import select

    from trainclimate.service.store import setpoint_rollups
    from trainclimate.service.store.models import Coach, Setpoint

    ticks = [at(m) for m in range(first, last + 1, 5)]
    with client.app.state.db.transaction() as s:
        have = set(
            s.scalars(
                select(Setpoint.tick).where(Setpoint.coach_id == coach_id, Setpoint.tick.in_(ticks))
            )
        )
        rows = [
            {"coach_id": coach_id, "tick": tick, "t_rule_c": 22.0, "t_ref_c": 22.0}
            | {"source": source, "reason": reason}
            for tick in ticks
            if tick not in have
        ]
        if rows:
            s.execute(Setpoint.__table__.insert(), rows)
            setpoint_rollups.add(s, rows)
        coach = s.get(Coach, coach_id)
        if coach.last_tick is None or coach.last_tick < ticks[-1]:
            coach.last_tick = ticks[-1]


#: A day in minutes (the unit of :func:`at`).
DAY = 24 * 60
#: Each service day of :func:`crossover_train`, the pair's rows from 06:00 to 09:00 UTC (T0 is
#: 06:00 UTC): six windows.
HOURS = 180


def crossover_train(client, op, train: str, ratio: float, saving: float, days: int, seed: int):
    """Train ``train`` over ``days`` service days from T0: coach A draws ``ratio`` times B's
    power; the layer, on A on even days and on B on odd ones (an alternate trial), saves
    ``saving`` (negative: costs); each day's level varies (weather). A is registered with the
    layer on, B off."""
    rng = np.random.default_rng(seed)
    register(client, op, f"{train}-A", train, active=True)
    register(client, op, f"{train}-B", train, active=False)
    for d in range(days):
        first = d * DAY
        on, off = (f"{train}-A", f"{train}-B") if d % 2 == 0 else (f"{train}-B", f"{train}-A")
        # through the day's last row's tick: else the live loop may issue it between two days,
        # on the coach activated in the database, and move that day's switch
        decided(client, on, first, first + HOURS)
        decided(client, off, first, first + HOURS, "rule", "inactive")
        level = 10.0 * np.exp(rng.normal(0, 0.2))
        b = level * (1 - saving if d % 2 else 1.0) * np.exp(rng.normal(0, 0.01))
        a = level * ratio * (1 - saving if d % 2 == 0 else 1.0) * np.exp(rng.normal(0, 0.01))
        post_rows(client, op, f"{train}-A", flat_rows(first + 1, first + HOURS, power_kw=a))
        post_rows(client, op, f"{train}-B", flat_rows(first + 1, first + HOURS, power_kw=b))


def no_setpoint(coach_id: str) -> dict:
    """``GET /coaches/{id}/setpoint`` of a coach without a valid setpoint: every field null."""
    fields = ("tick", "t_ref_c", "t_rule_c", "source", "reason", "valid_until")
    return {"coach_id": coach_id, **dict.fromkeys(fields)}
