"""The demo fleet (``trainclimate serve --fleet demo``): simulated trains on an accelerated clock.

Three trains, each with coach A (the DDPC layer activated) and coach B (deactivated) — twins that
share place, weather, operation and occupancy, like the paper's pairs: one parked outdoors in Zug
(like Experiment 4), one in service on the S12, one parked in Muelligen, on a cold late-November
day (the scenarios' seeded weather and Zurich S-Bahn operations, :mod:`trainclimate.sim`).

:class:`DemoFleet` advances the fleet one sampling period at a time, as fast as ``speedup`` allows:
it simulates the period with the setpoints issued at its start, writes the coaches' telemetry (one
row per minute, the minute up to its time), the new clock and the simulator's state in one
transaction, and then issues the tick at the period's end
(:meth:`~trainclimate.service.scheduler.Scheduler.tick_fleet`). After a crash or restart it
carries on from the stored clock and state, so no tick is lost or issued twice: before its first
period it issues the tick at the stored clock, which a crash between storing a period and issuing
its tick left undone.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from datetime import datetime, timedelta

import numpy as np
import pandas as pd
from sqlalchemy import select
from sqlalchemy.exc import OperationalError

from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import Coach, FleetClock, Setpoint, Telemetry, Train
from trainclimate.service.store.telemetry import rows_from_simulation
from trainclimate.sim import scenarios
from trainclimate.sim.rule import MODE_REGULAR
from trainclimate.sim.scenarios import Scenario, Service
from trainclimate.sim.setpoint import apply_setpoint
from trainclimate.sim.simulator import Environment, FleetSimulator

log = logging.getLogger(__name__)

FLEET = "demo"
LOCAL_TZ = "Europe/Zurich"
#: The demo's first simulated moment (local time).
START_LOCAL = "2024-11-28 04:00"


@dataclass(frozen=True)
class DemoTrain:
    """One demo train: its id, its name (where it is, in words) and the scenario of its day."""

    id: str
    name: str
    scenario: Scenario


def _day(name: str, site: str, **kw) -> Scenario:
    """A whole local day at ``site`` (the demo builds one day at a time)."""
    return Scenario(
        name=name,
        description=name,
        site=site,
        date="2024-11-28",
        start="00:00",
        hours=24.0,
        t_min_c=-1.0,
        t_max_c=4.0,
        cloud_cover=0.7,
        **kw,
    )


S12_DAY = Service(
    lines=("S12",), first_departure="05:30", last_arrival="23:30", layovers=(("10:10", "11:00"),)
)
TRAINS = (
    DemoTrain(
        "D1",
        "parked outdoors in Zug (like Experiment 4)",
        _day("demo-zug", "zug", seed=1128, parked_heading_deg=160.0),
    ),
    DemoTrain(
        "D2",
        "in service on the S12 Brugg – Winterthur",
        _day("demo-s12", "zurich", seed=2128, service=S12_DAY),
    ),
    DemoTrain(
        "D3",
        "parked outdoors in Muelligen",
        _day("demo-muelligen", "muelligen", seed=3128, parked_heading_deg=75.0),
    ),
)


def coach_ids() -> list[str]:
    """A before B for every train: the simulator's columns in order."""
    return [f"{t.id}-{side}" for t in TRAINS for side in ("A", "B")]


def register(session) -> None:
    """Create the demo trains, coaches and clock if they do not exist yet."""
    for train in TRAINS:
        if session.get(Train, train.id) is None:
            session.add(Train(id=train.id, name=train.name))
            session.flush()
        for side in ("A", "B"):
            cid = f"{train.id}-{side}"
            if session.get(Coach, cid) is None:
                session.add(Coach(id=cid, train_id=train.id, fleet=FLEET, ddpc_active=side == "A"))
    if session.get(FleetClock, FLEET) is None:
        start = pd.Timestamp(START_LOCAL, tz=LOCAL_TZ).tz_convert("UTC").to_pydatetime()
        session.add(FleetClock(name=FLEET, time=start, state=None))


class DemoFleet:
    """Runs the demo fleet (see the module docstring)."""

    def __init__(self, db: Database, scheduler: Scheduler, speedup: float):
        self.db = db
        self.scheduler = scheduler
        self.speedup = float(speedup)
        self.period = scheduler.period
        self.ids = coach_ids()
        self.sim: FleetSimulator | None = None
        self.day: pd.Timestamp | None = None
        self.caught_up = False

    def _catch_up(self) -> None:
        """Issue the tick at the stored clock if a crash came between storing its period and
        issuing it (a no-op otherwise: the tick is claimed per coach). Not at the very start:
        there is no data before the first period."""
        with self.db.transaction() as session:
            clock = session.get(FleetClock, FLEET)
            t0, started = clock.time, clock.state is not None
        if started:
            self.scheduler.tick_fleet(FLEET, t0)
        self.caught_up = True

    # --- the simulator, one local day at a time ------------------------------------------
    def _build_day(self, day: pd.Timestamp) -> FleetSimulator:
        envs, params = [], []
        for train in TRAINS:
            seed = train.scenario.seed + day.dayofyear
            sc = replace(train.scenario, date=f"{day:%Y-%m-%d}", seed=seed)
            env, p = scenarios.build(sc, n_coaches=1)
            envs += [env, env]  # coaches A and B: twins in one train
            params += [p[0], p[0]]
        return FleetSimulator(params, Environment.side_by_side(envs), seed=int(day.dayofyear))

    def _ensure_simulator(self, at: datetime, state: dict | None) -> None:
        local_day = pd.Timestamp(at).tz_convert(LOCAL_TZ).normalize()
        if self.sim is None or self.day != local_day:
            carried = self.sim.snapshot() if self.sim is not None else state
            self.sim = self._build_day(local_day)
            self.day = local_day
            if carried is not None:
                self.sim.restore(carried)
        index = np.searchsorted(self.sim.env.time, pd.Timestamp(at))
        self.sim.k = int(index)

    # --- one period ------------------------------------------------------------------------
    def advance(self) -> datetime:
        """Simulate one period from the stored clock, store it, and issue the tick at its end."""
        if not self.caught_up:
            self._catch_up()
        with self.db.transaction() as session:
            clock = session.get(FleetClock, FLEET)
            t0, state = clock.time, clock.state
            setpoints = dict(
                session.execute(
                    select(Setpoint.coach_id, Setpoint.t_ref_c).where(
                        Setpoint.coach_id.in_(self.ids), Setpoint.tick == t0
                    )
                ).all()
            )
        self._ensure_simulator(t0, state)
        t_ref = np.array([np.nan if setpoints.get(c) is None else setpoints[c] for c in self.ids])
        steps = round(self.period.total_seconds() / self.sim.dt_s)
        start_k = self.sim.k

        def policy(k: int, sim: FleetSimulator) -> np.ndarray:
            return apply_setpoint(t_ref, sim.t_rule(k), sim.env.mode[k] == MODE_REGULAR)

        self.sim.run(policy, steps=steps)
        rows = rows_from_simulation(self.sim, start_k, self.sim.k, self.ids)
        t1 = t0 + self.period
        with self.db.transaction() as session:
            session.execute(
                Telemetry.__table__.insert(),
                [{**r, "coach_id": cid} for cid, coach_rows in rows.items() for r in coach_rows],
            )
            clock = session.get(FleetClock, FLEET)
            clock.time = t1
            clock.state = self.sim.snapshot()
        self.scheduler.tick_fleet(FLEET, t1)
        return t1

    # --- pacing ----------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> None:
        """Advance the fleet ``speedup`` times faster than real time until ``stop``."""
        with self.db.transaction() as session:
            sim_anchor = session.get(FleetClock, FLEET).time
        wall_anchor = time.monotonic()
        while not stop.is_set():
            target = sim_anchor + timedelta(seconds=(time.monotonic() - wall_anchor) * self.speedup)
            try:
                with self.db.transaction() as session:
                    now = session.get(FleetClock, FLEET).time
                if now + self.period <= target:
                    self.advance()
                    self.scheduler.beat(FLEET, self.period.total_seconds() / self.speedup)
                    continue
                self.scheduler.beat(FLEET, self.period.total_seconds() / self.speedup)
            except OperationalError as exc:
                log.warning("database unavailable, retrying: %s", str(exc).splitlines()[0])
            except Exception:
                log.exception("demo fleet step failed; retrying")
            stop.wait(min(0.25, self.period.total_seconds() / self.speedup))
