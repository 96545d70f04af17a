"""The scheduler: one tick per coach per sampling period, each issued exactly once.

A clock drives the ticks: the demo fleet's simulated clock (advanced by
:class:`~trainclimate.service.adapters.demo.DemoFleet`, which calls :meth:`Scheduler.tick_fleet`
after each period it simulates), and for each live coach its own clock, the newest time of its
own telemetry (:mod:`~trainclimate.service.store.liveness`) — real time in service
(:meth:`Scheduler.run_live`). A live coach gets the tick its newest row has reached, as soon as
that row is stored; one gateway's clock, ahead or behind or jumping, moves no other coach's
ticks.

A tick for coach c at time t is *claimed* in the database: the coach's row is locked
(``SELECT … FOR UPDATE SKIP LOCKED`` on PostgreSQL, so replicas sharing the database take
different coaches) where its ``last_tick`` is before t, and the setpoint is inserted under the
unique constraint (coach, tick) in the same transaction that advances ``last_tick`` and counts
it in its coach's window (:mod:`~trainclimate.service.store.setpoint_rollups`). So a tick is
issued at most once, whatever crashes or replicas do; and since the lead-in comes from stored
telemetry, a restarted loop carries on where it stopped.

Per tick and coach the decision is the policy's (:func:`trainclimate.service.policy.decide`:
override, stale, inactive, not in regular mode, no model, else the DDPC step); the scheduler
supplies its inputs — the samples from the stored telemetry, the override in force, the coach's
controller, kept here between ticks — and stores what it decides. One coach's failure never stops
the others: its decision becomes a fallback.

Trial plans (:mod:`trainclimate.service.store.plans`) set the layer before the decision: each coach
whose train runs a plan other than ``fixed`` gets its layer on or off as the plan has it on the
tick's service day (logged when that switches it), and each train's service day is recorded in
``trial_days`` the first time a tick applies it — in the tick's transaction, with the plans of a
whole batch read in one query. Under ``fixed`` the layer stays as operators set it.

The guard (:mod:`trainclimate.service.store.guard`) is evaluated at the first tick of each
service day per train, in the tick's transaction; every tick reads which of the batch's trains
it has handed back to T_rule (one statement) and the policy decides accordingly.

Candidate models run in the active model's shadow: for every DDPC setpoint, each candidate
predicts from the same samples and the setpoints the active model planned
(:func:`~trainclimate.service.policy.shadow_prediction`), and its prediction is stored beside the
setpoint (``shadow_predictions``) in the same transaction. A candidate never decides a setpoint;
its failure is logged and costs only its prediction.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from datetime import datetime, timedelta

import pandas as pd
from sqlalchemy import case, func, or_, select
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.orm import Session

from trainclimate.control import DDPCController, OCPSettings
from trainclimate.control.coach_model import CoachModel
from trainclimate.control.ocp import DEFAULT_OBJECTIVE
from trainclimate.predict.artifact import load_predictor_bytes
from trainclimate.predict.base import MultistepPredictor
from trainclimate.predict.setting import RHO
from trainclimate.service import logs, policy
from trainclimate.service.metrics import Metrics
from trainclimate.service.policy import Decision
from trainclimate.service.settings import LOOP_READY_MIN_S, Settings
from trainclimate.service.store import fleet_days, guard, pair_days, plans, setpoint_rollups
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import (
    Coach,
    CoachLiveness,
    Override,
    PredictorModel,
    Setpoint,
    ShadowPrediction,
    Telemetry,
    utcnow,
)
from trainclimate.service.store.telemetry import Samples, controller_samples, load_rows

log = logging.getLogger(__name__)
#: Pair days made at a time at most (a few milliseconds of work each, in one transaction).
PAIR_DAYS_PER_LOOP = 16
#: Wall time between two rounds of making pair days: a day is over once a day, and each round
#: reads every train's state (on SQLite its writes wait for the telemetry's). [s]
PAIR_DAYS_EVERY_S = 60.0


def floor_tick(time: datetime, period: timedelta) -> datetime:
    """The last tick at or before ``time`` (ticks at multiples of the period since the epoch)."""
    ts = pd.Timestamp(time)
    return ts.floor(period).to_pydatetime()


class Scheduler:
    """Issues the ticks of every fleet (see the module docstring)."""

    def __init__(self, db: Database, settings: Settings, metrics: Metrics | None = None):
        self.db = db
        #: the ticks' counts and durations, the coaches' latest decisions (:mod:`..metrics`)
        self.metrics = metrics if metrics is not None else Metrics(settings.replica_name)
        self.settings = settings
        self.period = timedelta(minutes=settings.sampling_min)
        self.period_s = self.period.total_seconds()
        self.coach_model = CoachModel(dt_s=self.period_s)
        self.ocp = OCPSettings(objective=DEFAULT_OBJECTIVE)
        self._controllers: dict[str, DDPCController] = {}
        self._predictor: MultistepPredictor | None = None
        self._model_id: int | None = None
        #: the candidate models predicting in the shadow, by id
        self._candidates: dict[int, MultistepPredictor | None] = {}
        self._lock = threading.Lock()
        #: called as ``listener(fleet, rows)`` with the setpoint rows of each batch of ticks once
        #: they are committed (the MQTT feed publishes them); a listener's failure is logged
        self.listeners: list[Callable[[str, list[dict]], None]] = []
        #: this process, as recorded with each setpoint it decides
        self.replica = settings.replica_name
        #: loop name → (monotonic time of its last completed iteration [s], how long it may
        #: stay silent and still count as running [s]); see :meth:`beat`
        self.heartbeats: dict[str, tuple[float, float]] = {}
        #: train → the newest service day stored for it (``trial_days``), once committed: a
        #: tick of a day already stored needs no statement to record it
        self._days: dict[str, plans.PlanDay] = {}
        #: when :meth:`keep_pair_days` last ran (monotonic [s]; −∞: never)
        self._pair_days_at = float("-inf")

    # --- the model -------------------------------------------------------------------------
    def refresh_model(self, session: Session) -> None:
        """Use the active predictor model (rebuilding the controllers once when it changed) and
        the current candidates (each loaded once)."""
        self._refresh_candidates(session)
        active_id = session.scalar(
            select(PredictorModel.id).where(PredictorModel.state == "active")
        )
        if active_id == self._model_id:
            return
        model = session.get(PredictorModel, active_id) if active_id is not None else None
        with self._lock:
            self._predictor = load_predictor_bytes(model.artifact) if model is not None else None
            self._model_id = active_id
            self._controllers.clear()
        log.info("controller model: %s", f"version {model.version}" if model else "none")

    def _refresh_candidates(self, session: Session) -> None:
        ids = set(
            session.scalars(select(PredictorModel.id).where(PredictorModel.state == "candidate"))
        )
        if ids == set(self._candidates):
            return
        candidates = {i: p for i, p in self._candidates.items() if i in ids}
        for new in ids - set(candidates):
            model = session.get(PredictorModel, new)
            try:
                candidates[new] = load_predictor_bytes(model.artifact)
            except Exception:  # an unreadable candidate predicts nothing; the layer runs on
                log.exception("candidate model version %s cannot be loaded", model.version)
                candidates[new] = None
            log.info("candidate model version %s predicts in the shadow", model.version)
        self._candidates = candidates  # replaced whole: a tick in another thread reads either

    def shadow_rows(self, coach_id: str, tick: datetime, samples, decision: Decision) -> list:
        """The candidates' predictions beside a DDPC decision, as ``shadow_predictions`` rows."""
        if decision.source != "ddpc":
            return []
        rows = []
        for model_id, predictor in self._candidates.items():
            if predictor is None:
                continue
            try:
                y = policy.shadow_prediction(predictor, samples, decision.predicted)
            except Exception:  # a candidate's failure never touches the setpoint
                log.exception("candidate %s failed at %s for %s", model_id, tick, coach_id)
                continue
            if y is not None:
                rows.append(
                    {"model_id": model_id, "coach_id": coach_id, "tick": tick,
                     "y_pred_c": y.tolist()}
                )  # fmt: skip
        return rows

    def controller(self, coach_id: str) -> DDPCController:
        """The coach's controller, built on first use for the active model (kept between ticks:
        it holds the coach's state estimate and the solver's warm start)."""
        with self._lock:
            ctl = self._controllers.get(coach_id)
            if ctl is None:
                ctl = DDPCController(
                    self._predictor,
                    self.ocp,
                    sampling_min=self.settings.sampling_min,
                    model=self.coach_model,
                    stale_periods=self.settings.stale_periods,
                )
                self._controllers[coach_id] = ctl
            return ctl

    def forget(self, coach_id: str) -> None:
        """Drop a coach's controller state (after its layer was switched off and on)."""
        with self._lock:
            self._controllers.pop(coach_id, None)

    # --- one tick ----------------------------------------------------------------------------
    def decide(
        self,
        coach: Coach,
        samples: Samples,
        override: Override | None,
        tick: datetime,
        tripped: dict | None = None,
    ) -> Decision:
        """The setpoint for one coach at one tick: :func:`.policy.decide` with this scheduler's
        settings, the coach's controller (none before a model is active) and its train's tripped
        guard's figures (None: not tripped)."""
        controller = None
        if self._predictor is not None:
            controller = functools.partial(self.controller, coach.id)
        return policy.decide(coach, samples, override, tick, self.settings, controller, tripped)

    def tick_fleet(
        self,
        fleet: str,
        tick: datetime,
        batch: int = 250,
        *,
        reported_only: bool = False,
        coaches: list[str] | None = None,
    ) -> int:
        """Issue tick ``tick`` to every coach of ``fleet`` (only of ``coaches``, if given) that
        has not had it — with ``reported_only``, only to those whose telemetry has reached the
        tick; returns how many were issued here (0 if another replica or an earlier run did
        them)."""
        issued, left, started = 0, None, time.perf_counter()
        while True:
            try:
                with logs.context(tick=tick.isoformat()):
                    n = self._tick_batch(fleet, tick, batch, reported_only, coaches)
            except IntegrityError:
                # another scheduler issued some of these ticks first: on SQLite, which has no
                # SKIP LOCKED, both may claim a coach and the unique (coach, tick) lets one
                # win; this batch was rolled back, and the coaches still without the tick are
                # taken again — unless nobody made progress since the last conflict: then it
                # is no race, and it is raised
                before, left = left, self._pending(fleet, tick, reported_only, coaches)
                if before is not None and left >= before:
                    raise
                log.info("tick %s: another scheduler issued part of it first", tick)
                continue
            if n == 0:
                if issued:
                    self.metrics.tick(fleet, time.perf_counter() - started, tick.timestamp())
                    self._drop_others()
                return issued
            issued += n

    def _drop_others(self) -> None:
        """Drop the controllers of coaches another replica holds now (their state estimate
        and warm start are that replica's to keep)."""
        with self._lock:
            mine = list(self._controllers)
        if not mine:
            return
        with self.db.transaction() as session:
            others = session.scalars(
                select(Coach.id).where(
                    Coach.id.in_(mine), Coach.held_by.is_not(None), Coach.held_by != self.replica
                )
            ).all()
        with self._lock:
            for coach_id in others:
                self._controllers.pop(coach_id, None)

    @staticmethod
    def _due(fleet: str, tick: datetime, reported_only: bool, coaches: list[str] | None) -> list:
        """The conditions of a coach of ``fleet`` (of ``coaches``) still due ``tick``."""
        due = [Coach.fleet == fleet, or_(Coach.last_tick.is_(None), Coach.last_tick < tick)]
        if coaches is not None:
            due.append(Coach.id.in_(coaches))
        if reported_only:
            reported = select(Telemetry.id).where(
                Telemetry.coach_id == Coach.id, Telemetry.time >= tick
            )
            due.append(reported.exists())
        return due

    def _pending(
        self, fleet: str, tick: datetime, reported_only: bool, coaches: list[str] | None
    ) -> int:
        """How many coaches of ``fleet`` (of ``coaches``) are still due ``tick``."""
        with self.db.transaction() as session:
            due = self._due(fleet, tick, reported_only, coaches)
            return session.scalar(select(func.count()).select_from(Coach).where(*due))

    def _tick_batch(
        self,
        fleet: str,
        tick: datetime,
        batch: int,
        reported_only: bool,
        only: list[str] | None = None,
    ) -> int:
        """Claim and issue ``tick`` for up to ``batch`` coaches (of ``only``) in one
        transaction; returns how many (0: none left)."""
        window = (self._rho() + 2) * self.period + timedelta(minutes=1)
        with self.db.transaction() as session:
            self.refresh_model(session)
            coaches = session.scalars(
                select(Coach)
                .where(*self._due(fleet, tick, reported_only, only))
                # its own coaches first: each replica keeps its coaches (and their controllers)
                # from tick to tick, and takes the others' only when it is done with its own
                .order_by(case((Coach.held_by == self.replica, 0), else_=1), Coach.id)
                .limit(batch)
                # FOR NO KEY UPDATE: telemetry of a coach being ticked (its foreign key takes
                # a KEY SHARE lock on the coach) is stored without waiting for the tick
                .with_for_update(skip_locked=True, key_share=True)
            ).all()
            if not coaches:
                return 0
            ids = [c.id for c in coaches]
            recorded, days, pairs = self._apply_plans(session, coaches, tick)
            guards = guard.check(session, days, pairs, tick, self.settings.guard_days)
            telemetry = load_rows(session, ids, tick - window, tick)
            overrides = active_overrides(session, ids, tick)
            rows, shadows = [], []
            late = [
                c for c in coaches if c.last_tick is not None and c.last_tick < tick - self.period
            ]
            behind = [c.id for c in late]
            # the periods the coaches behind missed (each its last tick, none until this one)
            skipped = sum(round((tick - c.last_tick) / self.period) - 1 for c in late)
            if behind and fleet == "live":
                # the ticks between are not issued late (they can no longer be applied): the
                # record shows the gap, and this says why
                log.warning(
                    "tick %s: %s skipped at least one tick (the service was down or behind "
                    "its clock)",
                    tick,
                    ", ".join(behind),
                )
            for coach in coaches:
                with logs.context(coach=coach.id):  # on the log lines of its decision
                    try:
                        samples = controller_samples(
                            telemetry[coach.id], tick.timestamp(), self.period_s
                        )
                        decision = self.decide(
                            coach,
                            samples,
                            overrides.get(coach.id),
                            tick,
                            guards.get(coach.train_id),
                        )
                    except Exception as exc:  # one coach's failure never stops the others
                        log.exception("tick %s for coach %s failed", tick, coach.id)
                        decision = Decision(None, None, "fallback", "error", repr(exc)[:500])
                    else:
                        shadows += self.shadow_rows(coach.id, tick, samples, decision)
                    rows.append(_row(coach.id, tick, decision, self._model_id, self.replica))
                    coach.last_tick, coach.held_by = tick, self.replica
            session.execute(Setpoint.__table__.insert(), rows)
            setpoint_rollups.add(session, rows)
            if shadows:
                session.execute(ShadowPrediction.__table__.insert(), shadows)
        self._days.update(recorded)
        self.metrics.decided(fleet, rows)
        self.metrics.skipped(fleet, "behind", skipped)
        for listener in self.listeners:
            try:
                listener(fleet, rows)
            except Exception:
                log.exception("a setpoint listener failed (the setpoints are stored)")
        return len(rows)

    def _apply_plans(self, session: Session, coaches: Sequence[Coach], tick: datetime) -> tuple:
        """Set the layer of the (locked) ``coaches`` as their trains' plans in force at ``tick``
        have it, recording each train's service day unless it is stored already; returns the
        stored days (train → :class:`~.plans.PlanDay`) for :attr:`_days` once committed, the
        trains' service days at the tick and their coaches (:func:`.plans.coaches_of`)."""
        trains = sorted({c.train_id for c in coaches})
        pairs = plans.coaches_of(session, trains)
        days = plans.plan_days(plans.plans_at(session, trains, tick), pairs, tick)
        stored = {t: self._days[t] for t, d in days.items() if plans.same_day(d, self._days.get(t))}
        new = [
            d for t, d in days.items() if t not in stored and len(pairs[t]) == 2 and not d.partial
        ]
        if new:
            stored |= plans.record(session, new)
        states = plans.layer_states(days, stored, pairs)
        for coach in coaches:
            active = states.get(coach.id, coach.ddpc_active)
            if active != coach.ddpc_active:
                coach.ddpc_active = active
                self.forget(coach.id)
                day = days[coach.train_id]
                log.info(
                    "tick %s: the %s plan of train %s %s coach %s (service day %s)",
                    tick,
                    day.plan,
                    coach.train_id,
                    "activates" if active else "deactivates",
                    coach.id,
                    day.day,
                    extra={"coach": coach.id},  # the line's coach (--log-format json)
                )
        return stored, days, pairs

    def _rho(self) -> int:
        """ρ of the active model (the default ρ without one): a tick reads ρ + 2 periods."""
        return self._predictor.rho if self._predictor is not None else RHO

    # --- the live fleet ----------------------------------------------------------------------
    def live_ticks(self, session: Session) -> tuple[dict[datetime, list[str]], datetime | None]:
        """The tick each live coach is due now, by tick: its own clock's (the newest time of its
        telemetry, :mod:`~trainclimate.service.store.liveness`), floored to the period, for the
        coaches whose last tick is before it; and the newest of the clocks (None: no live coach
        has reported)."""
        rows = session.execute(
            select(CoachLiveness.coach_id, CoachLiveness.time, Coach.last_tick)
            .join(Coach, Coach.id == CoachLiveness.coach_id)
            .where(Coach.fleet == "live")
        ).all()
        due: dict[datetime, list[str]] = {}
        for coach_id, clock, last_tick in rows:
            tick = floor_tick(clock, self.period)
            if last_tick is None or last_tick < tick:
                due.setdefault(tick, []).append(coach_id)
        return due, max((clock for _, clock, _ in rows), default=None)

    def run_live_once(self) -> int:
        """Issue each live coach the tick its own clock has reached (its newest row is at or
        after the tick, so the tick decides on that row). Ticks older than a coach's current
        one can no longer be applied and are not issued late; a coach whose gateway is silent
        gets no tick (its last setpoint's validity runs out, and its gateway falls back to
        T_rule)."""
        with self.db.transaction() as session:
            due, newest = self.live_ticks(session)
        if newest is not None:
            self.metrics.clock["live"] = newest.timestamp()
        issued = 0
        for tick in sorted(due, reverse=True):
            issued += self.tick_fleet("live", tick, reported_only=True, coaches=due[tick])
        return issued

    # --- the pair days --------------------------------------------------------------------
    def keep_pair_days(self, max_days: int = PAIR_DAYS_PER_LOOP) -> int:
        """Make up to ``max_days`` of the pair days now due (:func:`.pair_days.build`: service
        days over for both coaches of a train), then up to as many fleet days missing
        (:func:`.fleet_days.build`), in their own transaction; how many pair days were made.
        A failure is logged and left for the next round (the summary reads the days without
        pair days from the rollups meanwhile, and pools the charts of those without a fleet
        day itself)."""
        self._pair_days_at = time.monotonic()
        try:
            with self.db.transaction() as session:
                pairs = pair_days.fleet_pairs(session, utcnow())
                made = pair_days.build(session, pairs, max_days)
                fleet_days.build(session, max_days)
                return made
        except Exception:
            log.exception("making the pair days failed; retrying in the next loop")
            return 0

    def pair_days_due(self) -> bool:
        """Whether :data:`PAIR_DAYS_EVERY_S` have passed since :meth:`keep_pair_days` last ran
        (the loops call it then)."""
        return time.monotonic() - self._pair_days_at >= PAIR_DAYS_EVERY_S

    # --- the loops' heartbeats ---------------------------------------------------------------
    def beat(self, loop: str, period_wall_s: float) -> None:
        """Record that ``loop`` completed an iteration now. It counts as running for two of its
        fleet's periods, ``period_wall_s`` each in wall time (s), at least
        :data:`~trainclimate.service.settings.LOOP_READY_MIN_S` (``loop_ready_s`` of the
        settings, if set, instead)."""
        allowed = self.settings.loop_ready_s or max(2 * period_wall_s, LOOP_READY_MIN_S)
        self.heartbeats[loop] = (time.monotonic(), allowed)

    def loop_ages(self) -> dict[str, float]:
        """Seconds since each loop's last completed iteration."""
        now = time.monotonic()
        return {loop: now - at for loop, (at, _) in sorted(self.heartbeats.items())}

    def stalled_loops(self) -> list[str]:
        """A sentence per loop whose last completed iteration is older than it may be."""
        now = time.monotonic()
        return [
            f"the {loop} loop completed no iteration for {now - at:.0f} s (limit {allowed:g} s)"
            for loop, (at, allowed) in sorted(self.heartbeats.items())
            if now - at > allowed
        ]

    def run_live(self, stop: threading.Event) -> None:
        """The live fleet's loop, until ``stop``; a database that is briefly unavailable leaves
        the last setpoints standing (the gateways keep them) and is retried. Its clock is real
        time: it beats with a period of ``sampling_min`` (see :meth:`beat`)."""
        while not stop.is_set():
            try:
                self.run_live_once()
                if self.pair_days_due():
                    self.keep_pair_days()
                self.beat("live", self.period_s)
                self.metrics.database_up = True
            except OperationalError as exc:
                log.warning("database unavailable, retrying: %s", str(exc).splitlines()[0])
                self.metrics.database_up = False
                self.metrics.skipped("live", "database_unavailable")
            except Exception:
                log.exception("live loop iteration failed; retrying")
                self.metrics.skipped("live", "error")
            stop.wait(self.settings.scheduler_interval_s)


def active_overrides(session: Session, coach_ids: list[str], at: datetime) -> dict[str, Override]:
    """The override in force at ``at`` for each coach (the newest if several)."""
    rows = session.scalars(
        select(Override)
        .where(
            Override.coach_id.in_(coach_ids),
            Override.starts_at <= at,
            Override.ends_at > at,
            Override.cancelled_at.is_(None),
        )
        .order_by(Override.created_at)
    ).all()
    return {o.coach_id: o for o in rows}


def _row(coach_id: str, tick: datetime, d: Decision, model_id: int | None, replica: str) -> dict:
    """The setpoint row of decision ``d`` (the model only for a DDPC setpoint) decided by
    ``replica``."""
    return {
        "coach_id": coach_id,
        "tick": tick,
        "t_rule_c": d.t_rule_c,
        "t_ref_c": d.t_ref_c,
        "source": d.source,
        "reason": d.reason,
        "detail": d.detail,
        "solve_time_ms": d.solve_time_ms,
        "step_time_ms": d.step_time_ms,
        "predicted": d.predicted,
        "model_id": model_id if d.source == "ddpc" else None,
        "created_at": pd.Timestamp.now(tz="UTC").to_pydatetime(),
        "replica": replica,
    }
