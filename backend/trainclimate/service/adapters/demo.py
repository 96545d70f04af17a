"""The demo fleet (``trainclimate serve --fleet demo``): simulated trains on an accelerated clock.

Ten trains, each with coach A (the DDPC layer activated) and coach B (deactivated) — twins that
share place, weather, operation and occupancy, like the paper's pairs — in the situations of the
paper's experiments and of the scenarios (:mod:`trainclimate.sim`: seeded weather, Zurich S-Bahn
operations), on a late-November day that is cold and overcast for all but one of them:

- parked outdoors in Zug (like Experiment 4), in Muelligen and in Wiesendangen;
- in service on the S12, the S8 (all day, and at the peaks only) and the S14 (all day, and a late
  shift), each with its own service day and layovers;
- parked in Winterthur on a mild, sunny day, on which heating and cooling alternate (the HVAC's
  mixed state);
- parked in Zürich, coach A losing its connection from 14:00 to 14:40 local time every day
  (:attr:`DemoTrain.connection_loss`): no setpoint reaches it, so it runs under its rule-based
  T_rule, and its telemetry reports ``connected`` false, as in the paper's experiments.

Four trains run a crossover trial (:attr:`DemoTrain.plan`, :mod:`trainclimate.service.store.plans`)
from the demo's first moment, so their savings cancel the coaches' own difference: D2 (S12), D3
(Muelligen) and D7 (Wiesendangen) ``alternate`` — coach A on the first service day, B on the next,
and so on, switching at 03:00 — and D5 (S14) ``randomized`` (seed 0: A, B, B, A, … day by day).
They are trains whose comparison is clean: no lost link (D9), no mild day of small savings (D8),
no stabling or late shift (D6, D10). The other six keep coach A activated (``fixed``), D1 too,
whose pair figure the operator guide shows.

:class:`DemoFleet` advances the fleet one sampling period at a time, as fast as ``speedup`` allows:
it simulates the period with the setpoints issued at its start, writes the coaches' telemetry (one
row per minute, the minute up to its time), the new clock and the simulator's state in one
transaction, and then issues the tick at the period's end
(:meth:`~trainclimate.service.scheduler.Scheduler.tick_fleet`). After a crash or restart it
carries on from the stored clock and state, so no tick is lost or issued twice: before its first
period it issues the tick at the stored clock, which a crash between storing a period and issuing
its tick left undone. A state stored by a fleet of another size (an earlier version's demo) is
dropped with a warning: the coaches start afresh.
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

from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.coach.setpoint import apply_setpoint
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.store import commands, rollups
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import (
    Coach,
    FleetClock,
    Setpoint,
    Telemetry,
    Train,
    TrainPlan,
)
from trainclimate.service.store.telemetry import rows_from_simulation
from trainclimate.service.store.tokens import Principal
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams
from trainclimate.sim.scenarios import Scenario, Service
from trainclimate.sim.simulator import FleetSimulator
from trainclimate.twin import validity

log = logging.getLogger(__name__)

FLEET = "demo"
LOCAL_TZ = "Europe/Zurich"
#: The demo's first simulated moment (local time).
START_LOCAL = "2024-11-28 04:00"
#: Who sets the demo trains' trial plans, as the audit log records it.
DEMO = Principal("demo", "operator")


@dataclass(frozen=True)
class DemoTrain:
    """One demo train: its id, its name (where it is, in words), the scenario of its day, when
    coach A's connection is lost every day (local ``("HH:MM", "HH:MM")`` (start, end), or None),
    and the trial plan it runs from the demo's first moment (switching at 03:00, seed 0)."""

    id: str
    name: str
    scenario: Scenario
    connection_loss: tuple[str, str] | None = None
    plan: str = "fixed"

    def connection_lost(self, times: pd.DatetimeIndex) -> np.ndarray:
        """Whether coach A's link is down at each of ``times`` (UTC, one local day), shape
        (len(times),) bool."""
        if self.connection_loss is None:
            return np.zeros(len(times), bool)
        start, end = (scenarios.local_clock(times[0], c) for c in self.connection_loss)
        return (times >= start) & (times < end)


def _day(
    name: str,
    site: str,
    *,
    t_min_c: float = -1.0,
    t_max_c: float = 4.0,
    cloud_cover: float = 0.7,
    **kw,
) -> Scenario:
    """A whole local day at ``site`` (the demo builds one day at a time), by default cold and
    overcast: daily minimum and maximum ``t_min_c``, ``t_max_c`` (°C), mean ``cloud_cover``
    (0…1)."""
    return Scenario(
        name=name,
        description=name,
        site=site,
        date="2024-11-28",
        start="00:00",
        hours=24.0,
        t_min_c=t_min_c,
        t_max_c=t_max_c,
        cloud_cover=cloud_cover,
        **kw,
    )


S12_DAY = Service(
    lines=("S12",), first_departure="05:30", last_arrival="23:30", layovers=(("10:10", "11:00"),)
)
S8_DAY = Service(
    lines=("S8",), first_departure="05:00", last_arrival="23:00", layovers=(("12:00", "12:45"),)
)
#: Morning and evening peaks only, stabled (slumber mode) in between.
S8_PEAKS = Service(
    lines=("S8",), first_departure="06:15", last_arrival="19:30", layovers=(("09:30", "15:30"),)
)
S14_DAY = Service(
    lines=("S14",), first_departure="06:00", last_arrival="22:30", layovers=(("09:00", "10:30"),)
)
S14_LATE = Service(lines=("S14",), first_departure="13:00", last_arrival="23:30")
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
        plan="alternate",
    ),
    DemoTrain(
        "D3",
        "parked outdoors in Muelligen",
        _day("demo-muelligen", "muelligen", seed=3128, parked_heading_deg=75.0),
        plan="alternate",
    ),
    DemoTrain(
        "D4",
        "in service on the S8 Winterthur – Pfäffikon SZ",
        _day("demo-s8", "zurich", seed=4128, service=S8_DAY),
    ),
    DemoTrain(
        "D5",
        "in service on the S14 Zürich HB – Wetzikon",
        _day("demo-s14", "zurich", seed=5128, service=S14_DAY),
        plan="randomized",
    ),
    DemoTrain(
        "D6",
        "in service on the S8 at the peaks only, stabled 09:30–15:30",
        _day("demo-s8-peaks", "zurich", seed=6128, service=S8_PEAKS),
    ),
    DemoTrain(
        "D7",
        "parked outdoors in Wiesendangen",
        _day("demo-wiesendangen", "wiesendangen", seed=7128, parked_heading_deg=120.0),
        plan="alternate",
    ),
    DemoTrain(
        "D8",
        "parked outdoors in Winterthur on a mild, sunny day (heating and cooling alternate)",
        _day(
            "demo-winterthur-mild",
            "winterthur",
            t_min_c=10.0,
            t_max_c=20.0,
            cloud_cover=0.15,
            seed=8128,
        ),
    ),
    DemoTrain(
        "D9",
        "parked outdoors in Zürich; D9-A loses its connection 14:00–14:40 daily",
        _day("demo-zurich-lost", "zurich", seed=9128, parked_heading_deg=45.0),
        connection_loss=("14:00", "14:40"),
    ),
    DemoTrain(
        "D10",
        "in service on the S14 Zürich HB – Wetzikon from 13:00 (late shift)",
        _day("demo-s14-late", "zurich", seed=10128, service=S14_LATE),
    ),
)


def coach_ids() -> list[str]:
    """A before B for every train: the simulator's columns in order."""
    return [f"{t.id}-{side}" for t in TRAINS for side in ("A", "B")]


def register(session) -> None:
    """Create the demo trains, coaches and clock if they do not exist yet, and set the trial plan
    of a train that runs one and never had a plan: in force from the demo's first moment on a new
    demo (no telemetry yet), else from the next switch hour (audited as ``demo``)."""
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
    session.flush()
    for train in TRAINS:
        planned = select(TrainPlan.id).where(TrainPlan.train_id == train.id).limit(1)
        if train.plan != "fixed" and session.scalar(planned) is None:
            why = f"the demo's {train.plan} crossover trial"
            commands.set_plan(session, DEMO, train.id, train.plan, reason=why)


class DemoFleet:
    """Runs the demo fleet (see the module docstring)."""

    def __init__(
        self,
        db: Database,
        scheduler: Scheduler,
        speedup: float,
        coach_params: CoachParams | None = None,
        validated_t_amb_c: list[float] | None = None,
    ):
        self.db = db
        self.coach_params = coach_params  # every coach's, instead of its scenario's
        #: the ambient range a calibrated ``coach_params`` was validated for (twin.validity)
        self.validated_t_amb_c = validated_t_amb_c
        self.scheduler = scheduler
        self.speedup = float(speedup)
        self.period = scheduler.period
        self.ids = coach_ids()
        self.sim: FleetSimulator | None = None
        #: (steps, coaches) bool on the simulator's grid: where a coach's link is down
        self.lost: np.ndarray | None = None
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
    def _build_day(self, day: pd.Timestamp) -> tuple[FleetSimulator, np.ndarray]:
        """The simulator of the local ``day`` and where each coach's link is down on its grid,
        (steps, coaches) bool."""
        envs, params, lost = [], [], []
        for train in TRAINS:
            seed = train.scenario.seed + day.day_of_year
            sc = replace(train.scenario, date=f"{day:%Y-%m-%d}", seed=seed)
            env, p = scenarios.build(sc, n_coaches=1)
            coach = self.coach_params or p[0]
            where = f"demo train {train.id} on {day:%Y-%m-%d}"
            warning = validity.range_warning(self.validated_t_amb_c, env.t_amb_c, where)
            if warning:
                log.warning("%s", warning)
            envs += [env, env]  # coaches A and B: twins in one train
            params += [coach, coach]
            lost += [train.connection_lost(env.time), np.zeros(len(env.time), bool)]
        sim = FleetSimulator(params, Environment.side_by_side(envs), seed=int(day.day_of_year))
        return sim, np.column_stack(lost)

    def _ensure_simulator(self, at: datetime, state: dict | None) -> None:
        local_day = pd.Timestamp(at).tz_convert(LOCAL_TZ).normalize()
        if self.sim is None or self.day != local_day:
            carried = self.sim.snapshot() if self.sim is not None else state
            if carried is not None and len(carried["T"]) != len(self.ids):
                log.warning(
                    "the stored demo state is of %d coaches, the fleet has %d: they start afresh",
                    len(carried["T"]),
                    len(self.ids),
                )
                carried = None
            self.sim, self.lost = self._build_day(local_day)
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
            # a coach whose link is down runs under T_rule: no setpoint reaches it
            use = (sim.env.mode[k] == MODE_REGULAR) & ~self.lost[k]
            return apply_setpoint(t_ref, sim.t_rule(k), use)

        self.sim.run(policy, steps=steps)
        rows = rows_from_simulation(self.sim, start_k, self.sim.k, self.ids, self.lost)
        t1 = t0 + self.period
        with self.db.transaction() as session:
            session.execute(
                Telemetry.__table__.insert(),
                [{**r, "coach_id": cid} for cid, coach_rows in rows.items() for r in coach_rows],
            )
            rollups.add_rows(session, rows)
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
                if self.scheduler.pair_days_due():  # while caught up with the clock
                    self.scheduler.keep_pair_days()
                self.scheduler.beat(FLEET, self.period.total_seconds() / self.speedup)
            except OperationalError as exc:
                log.warning("database unavailable, retrying: %s", str(exc).splitlines()[0])
            except Exception:
                log.exception("demo fleet step failed; retrying")
            stop.wait(min(0.25, self.period.total_seconds() / self.speedup))
