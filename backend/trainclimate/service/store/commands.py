"""What the API writes. Each function works inside the caller's transaction (one per request, so
a failed request changes nothing) and records every override, mode change, trial plan change,
model activation, token and role change in the audit log with who, when and why."""

from __future__ import annotations

import threading
from datetime import datetime, timedelta

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from trainclimate.analysis import trial_plan
from trainclimate.coach.setpoint import U_BAND_K
from trainclimate.service.store import guard, liveness, pair_days, plans, rollups
from trainclimate.service.store.models import (
    ApiToken,
    AuditLog,
    Coach,
    CoachFeed,
    Override,
    PredictorModel,
    Telemetry,
    Train,
    TrainPlan,
    User,
    utcnow,
)
from trainclimate.service.store.queries import (
    EARLIEST,
    NotFoundError,
    RequestError,
    coach_or_404,
    fleet_clock,
)
from trainclimate.service.store.records import TelemetryRecord
from trainclimate.service.store.telemetry import insert_rows
from trainclimate.service.store.tokens import (
    GATEWAY,
    Principal,
    RoleConflictError,
    article,
    check_scope,
    create_token,
)
from trainclimate.service.store.upsert import insert_new


class ConflictError(Exception):
    """A request that contradicts the stored state (→ 409)."""


class ForbiddenError(Exception):
    """A request about an object the caller's token does not reach (→ 403)."""


def audit(session: Session, who: Principal, action: str, target: str, reason: str = "", **detail):
    """Record ``action`` on ``target`` by ``who``, with why and any ``detail``, in the audit log."""
    session.add(
        AuditLog(
            user_name=who.name,
            role=who.role,
            action=action,
            target=target,
            reason=reason,
            detail=detail,
        )
    )


def register_coach(session: Session, who: Principal, coach_id: str, train_id: str, active: bool):
    """Create a live coach (and its train) if new; an existing coach is left as it is.

    A coach's train is fixed when it is registered: naming another train for an existing coach
    is a :class:`ConflictError` for every role. A gateway registers its coaches only into its own
    trains: a new train, or one whose coaches are all in its token's scope
    (:func:`check_train_scope`, else :class:`ForbiddenError`).

    Returns
    -------
    tuple of (Coach, bool)
        The coach and whether this call created it.
    """
    coach = session.get(Coach, coach_id)
    created = False
    if coach is None:  # two gateways may register the same train or coach at once
        insert_new(session, Train.__table__, [{"id": train_id, "name": train_id}], ["id"])
        if who.role == GATEWAY:
            check_train_scope(session, who, train_id)
        row = {"id": coach_id, "train_id": train_id, "fleet": "live", "ddpc_active": active}
        created = insert_new(session, Coach.__table__, [row], ["id"]) == 1
        coach = session.get(Coach, coach_id, populate_existing=True)
    if coach.train_id != train_id:
        raise ConflictError(
            f"coach {coach_id!r} belongs to train {coach.train_id!r}; "
            "a coach's train is fixed when it is registered"
        )
    if created:
        audit(session, who, "coach.register", coach_id, "", train_id=train_id, ddpc_active=active)
    return coach, created


def check_train_scope(session: Session, who: Principal, train_id: str) -> None:
    """Refuse (:class:`ForbiddenError`) a gateway's registration into train ``train_id`` if the
    train has a coach outside the gateway token's scope: its data would enter another train's
    comparison. The train's row is locked first (``FOR UPDATE`` on PostgreSQL), so registrations
    into one train run one after the other and each sees the coaches the one before added."""
    session.execute(select(Train.id).where(Train.id == train_id).with_for_update())
    coaches = session.scalars(select(Coach.id).where(Coach.train_id == train_id))
    if any(not who.serves(c) for c in coaches):
        raise ForbiddenError(
            f"train {train_id!r} has coaches this gateway token is not for: a gateway registers "
            "its coaches into its own trains only (a new train id, or a train of its coaches)"
        )


class OutsideHorizonError(RequestError):
    """A batch with rows older than the backfill horizon (→ 422, nothing of it stored)."""


class AheadOfClockError(RequestError):
    """A batch with rows stamped too far ahead of the server's clock (→ 422, nothing of it
    stored)."""


class Backfill:
    """Which rows of the live feed's telemetry are taken, over HTTP and MQTT alike.

    - A row older than its coach's newest row — stored, or in the same batch — less ``horizon``
      is refused (reason ``outside_horizon``), so that a gateway's wrong clock (a row dated
      2000-01-01) cannot stretch what the queries and the next retraining read.
    - A row more than ``max_ahead`` ahead of the server's clock is refused (reason
      ``ahead_of_clock``): a gateway whose clock runs ahead would move its coaches' clocks, and
      their ticks, into the future. Real gateways report UTC now; emulators replay a past
      scenario, behind the server's clock.

    ``refused`` counts the rows refused since start, by reason; the server's threads share it.
    """

    REASON = "outside_horizon"
    AHEAD = "ahead_of_clock"

    def __init__(self, horizon: timedelta, max_ahead: timedelta = timedelta(minutes=5)) -> None:
        self.horizon = horizon
        self.max_ahead = max_ahead
        self._refused: dict[str, int] = {}
        self._lock = threading.Lock()

    @property
    def refused(self) -> dict[str, int]:
        """A copy of the counts: reason → rows refused since start."""
        with self._lock:
            return dict(self._refused)

    def _count(self, reason: str, rows: int) -> None:
        with self._lock:
            self._refused[reason] = self._refused.get(reason, 0) + rows

    def check(
        self,
        session: Session,
        coach_id: str,
        rows: list[TelemetryRecord],
        now: datetime | None = None,
    ) -> None:
        """:class:`AheadOfClockError` if any of ``rows`` (a batch of ``coach_id``, not empty)
        is stamped more than ``max_ahead`` after ``now`` (the server's clock, default the
        wall clock), else :class:`OutsideHorizonError` if any is older than the horizon
        allows; either counted, naming the first row out and why."""
        limit = (now or utcnow()) + self.max_ahead
        ahead = [i for i, r in enumerate(rows) if r["time"] > limit]
        if ahead:
            self._count(self.AHEAD, len(ahead))
            first = rows[ahead[0]]["time"]
            raise AheadOfClockError(
                f"rows[{ahead[0]}]: time {first.isoformat()} is more than "
                f"{self.max_ahead.total_seconds() / 60:g} min ahead of the server's clock "
                f"({limit - self.max_ahead:%Y-%m-%dT%H:%M:%SZ}); {len(ahead)} row(s) that far "
                "ahead, nothing stored"
            )
        stored = session.scalar(
            select(func.max(Telemetry.time)).where(Telemetry.coach_id == coach_id)
        )
        newest = max(r["time"] for r in rows)
        if stored is not None and stored > newest:
            newest = stored
        floor = newest - self.horizon
        out = [i for i, r in enumerate(rows) if r["time"] < floor]
        if not out:
            return
        self._count(self.REASON, len(out))
        first = rows[out[0]]["time"]
        raise OutsideHorizonError(
            f"rows[{out[0]}]: time {first.isoformat()} is outside the backfill horizon: more "
            f"than {self.horizon.total_seconds() / 86400:g} days before the newest row of coach "
            f"{coach_id!r} ({newest.isoformat()}); {len(out)} row(s) that old, nothing stored"
        )


def ingest(
    session: Session, coach_id: str, rows: list[TelemetryRecord], backfill: Backfill | None = None
) -> tuple[int, int]:
    """Store a batch of telemetry, drop the pair days it changes (:func:`.pair_days.forget`),
    advance the coach's own clock and note the arrival (:mod:`.liveness`). Returns (stored,
    duplicates). With ``backfill``, a batch with a row ahead of the server's clock or older
    than its horizon is refused whole (:class:`AheadOfClockError`, :class:`OutsideHorizonError`).

    Nothing here locks a row a tick holds: the telemetry's foreign key takes a key-share lock
    on the coach, which the tick's ``FOR NO KEY UPDATE`` lets through, and the arrival is
    stamped in the coach's own ``coach_liveness`` row, not in ``coaches``."""
    coach = coach_or_404(session, coach_id)
    if coach.fleet != "live":
        # the demo fleet writes its coaches' rows itself, without skipping any: a row posted
        # here would make its next write conflict, every time, and stop the demo
        raise ConflictError(f"coach {coach_id!r} is simulated by the {coach.fleet} fleet")
    if not rows:
        return 0, 0
    if backfill is not None:
        backfill.check(session, coach.id, rows)
    newest = max(r["time"] for r in rows)
    before = session.scalar(select(CoachFeed.newest).where(CoachFeed.coach_id == coach.id))
    stored = insert_rows(session, coach.id, rows)
    first = min(r["time"] for r in rows)
    if before is not None and first <= before:
        # a row arriving late, for a day maybe summed already, makes its pair days stale
        pair_days.forget(session, {coach.id: rollups.window_of(first)})
    liveness.note_arrival(session, coach.id, newest, utcnow())
    return stored, len(rows) - stored


def create_override(
    session: Session, who: Principal, coach_id: str, t_ref_c: float, minutes: float, reason: str
) -> Override:
    """An override from now (the coach's clock) for ``minutes``, within T_rule ± 2 K; it
    replaces any override in force."""
    coach = coach_or_404(session, coach_id)
    now = fleet_clock(session, coach)
    if now is None:
        raise ConflictError(
            f"coach {coach_id!r} has reported nothing yet: no T_rule to check against"
        )
    t_rule = current_rule(session, coach, now)
    if t_rule is None:
        raise ConflictError(f"coach {coach_id!r} has no T_rule yet")
    if abs(t_ref_c - t_rule) > U_BAND_K + 1e-9:
        raise RequestError(
            f"t_ref_c {t_ref_c:g} °C is outside T_rule ± {U_BAND_K:g} K "
            f"({t_rule - U_BAND_K:.1f} … {t_rule + U_BAND_K:.1f} °C)"
        )
    for old in active_for(session, coach.id, now):
        old.cancelled_at, old.cancelled_by = now, who.name
    override = Override(
        coach_id=coach.id,
        t_ref_c=t_ref_c,
        starts_at=now,
        ends_at=now + timedelta(minutes=minutes),
        reason=reason,
        created_by=who.name,
    )
    session.add(override)
    session.flush()
    pair_days.forget(session, {coach.id: rollups.window_of(now)})
    audit(
        session,
        who,
        "override.create",
        coach.id,
        reason,
        override_id=override.id,
        t_ref_c=t_ref_c,
        duration_min=minutes,
        t_rule_c=t_rule,
    )
    return override


def cancel_override(session: Session, who: Principal, coach_id: str, reason: str) -> Override:
    """End the override in force now."""
    coach = coach_or_404(session, coach_id)
    now = fleet_clock(session, coach) or utcnow()
    current = active_for(session, coach.id, now)
    if not current:
        raise NotFoundError(f"coach {coach_id!r} has no override in force")
    for o in current:
        o.cancelled_at, o.cancelled_by = now, who.name
        audit(session, who, "override.cancel", coach.id, reason, override_id=o.id)
    pair_days.forget(session, {coach.id: rollups.window_of(now)})
    return current[-1]


def active_for(session: Session, coach_id: str, at: datetime) -> list[Override]:
    """The coach's overrides in force at ``at`` (not cancelled), oldest first."""
    return list(
        session.scalars(
            select(Override)
            .where(Override.coach_id == coach_id, Override.cancelled_at.is_(None))
            .where(Override.starts_at <= at, Override.ends_at > at)
            .order_by(Override.created_at)
        )
    )


def current_rule(session: Session, coach: Coach, at: datetime) -> float | None:
    """The coach's newest reported T_rule at or before ``at``."""
    return session.scalar(
        select(Telemetry.t_rule_c)
        .where(Telemetry.coach_id == coach.id, Telemetry.time <= at)
        .order_by(Telemetry.time.desc())
        .limit(1)
    )


def set_controller(session: Session, who: Principal, coach_id: str, active: bool, reason: str):
    """Switch the DDPC layer on or off for a coach; :class:`ConflictError` while its train runs a
    plan other than ``fixed`` (the plan switches the layer)."""
    coach = coach_or_404(session, coach_id)
    now = fleet_clock(session, coach) or utcnow()
    current = plans.plans_at(session, [coach.train_id], now).get(coach.train_id, (None, None))[0]
    if current is not None and current.plan != plans.FIXED:
        raise ConflictError(
            f"train {coach.train_id} runs {plans.named(current.plan)}, which switches the layer "
            "of its coaches; set the plan to fixed first"
        )
    before = coach.ddpc_active
    coach.ddpc_active = active
    audit(
        session,
        who,
        "controller.activate" if active else "controller.deactivate",
        coach.id,
        reason,
        before=before,
        after=active,
    )
    return coach


def set_plan(
    session: Session,
    who: Principal,
    train_id: str,
    plan: str,
    switch_hour: int = trial_plan.DEFAULT_SWITCH_HOUR,
    seed: int = 0,
    reason: str = "",
) -> dict:
    """Change a train's trial plan (:mod:`.plans`); audited as ``train.plan`` with the plan in
    force before and the change after.

    A train that has reported telemetry gets the change at a switch hour (``switch_hour`` local)
    of its fleet clock, the start of the new plan's next service day
    (:func:`.plans.effective_from`), never mid-day; one that has reported nothing, at once (its
    recorded days from the new plan's first on are dropped: they hold no measurement). A change
    still pending is replaced. :class:`RequestError` for an unknown plan, an hour outside 0–23 or
    a negative seed; :class:`ConflictError` for a plan other than ``fixed`` on a train without
    two coaches (no pair). Returns the plan view (:func:`.plans.view`) with the change in words.
    """
    train = session.scalar(select(Train).where(Train.id == train_id).with_for_update())
    if train is None:
        raise NotFoundError(f"no train {train_id!r}")
    if plan not in trial_plan.PLANS:
        raise RequestError(f"unknown plan {plan!r}: expected one of {', '.join(trial_plan.PLANS)}")
    if not 0 <= switch_hour <= 23 or seed < 0:
        raise RequestError("the switch hour is 0–23 and the seed ≥ 0")
    if plan != plans.FIXED and len(train.coaches) != 2:
        raise ConflictError(
            f"train {train.id} has {len(train.coaches)} coach(es): {plans.named(plan)} needs a "
            "pair of two; only fixed is possible"
        )
    # before anything of its fleet reported, the train has no clock: a plan set then is in force
    # from the first moment of whatever clock its data brings (an emulator's may be in the past)
    now = plans.clock(session, train) or EARLIEST
    current = plans.plans_at(session, [train.id], now).get(train.id, (None, None))[0]
    waiting = plans.pending(session, train.id, now)
    at_once = not plans.reported(session, train)
    row = TrainPlan(
        train_id=train.id,
        plan=plan,
        switch_hour=switch_hour,
        seed=seed,
        reason=reason,
        effective_from=now if at_once else plans.effective_from(now, current, switch_hour),
        created_by=who.name,
    )
    if at_once:
        plans.forget_days(session, train.id, plans.first_day(row))
    for old in waiting:  # one change pending at most: the newest decision stands
        session.delete(old)
    session.add(row)
    session.flush()
    replaced = waiting[-1] if waiting else None
    extra = {"replaced": plans.change(replaced)} if replaced is not None else {}
    before, after = plans.change(current), plans.change(row)
    audit(session, who, "train.plan", train.id, reason, before=before, after=after, **extra)
    message = plans.change_message(train.id, row, at_once, before["plan"], replaced)
    return plans.view(session, train, message)


def reset_guard(session: Session, who: Principal, train_id: str, reason: str) -> dict:
    """Re-enable the layer on a train whose guard handed it back to T_rule (:mod:`.guard`): the
    guard watches again, its estimate counting only windows from the train's clock now on.
    Audited as ``guard.reset`` with the figures it had tripped on. :class:`ConflictError` when
    the guard has not tripped. Returns the guard's view (:func:`.guard.view`)."""
    train = session.scalar(select(Train).where(Train.id == train_id).with_for_update())
    if train is None:
        raise NotFoundError(f"no train {train_id!r}")
    now = plans.clock(session, train) or utcnow()
    row = guard.reset(session, train.id, now, who.name)
    if row is None:
        raise ConflictError(f"the guard of train {train.id} has not handed the layer back")
    audit(session, who, "guard.reset", train.id, reason, figures=row.figures)
    session.flush()
    return guard.view(session, train.id)


def activate_model(session: Session, who: Principal, version: int, reason: str) -> PredictorModel:
    """Make model ``version`` the one every controller uses (from the next tick) and retire the
    one it replaces, in one transaction; audited with both versions. Activating the active
    version changes nothing but the record; a retired one is how to roll back."""
    model = session.scalar(
        select(PredictorModel).where(PredictorModel.version == version).with_for_update()
    )
    if model is None:
        raise NotFoundError(f"no model version {version}")
    previous = session.scalar(
        select(PredictorModel.version).where(PredictorModel.state == "active")
    )
    if previous != version:
        session.execute(
            update(PredictorModel).where(PredictorModel.state == "active").values(state="retired")
        )
        session.flush()  # the one-active index: the old version leaves before the new arrives
        model.state = "active"
    audit(session, who, "model.activate", f"model:{version}", reason, previous=previous)
    return model


def issue_token(
    session: Session,
    who: Principal,
    role: str,
    name: str | None,
    coaches: list[str] | None = None,
    expires_at: datetime | None = None,
) -> tuple[str, User]:
    """A new token for user ``name`` with ``role`` (a gateway's scoped to ``coaches``, valid
    until ``expires_at``, :func:`.tokens.create_token`), audited with its scope and expiry. An
    existing user's token has the user's role: another role is a :class:`ConflictError`."""
    try:
        token, user = create_token(session, role, name, coaches, expires_at)
    except RoleConflictError as exc:
        raise ConflictError(str(exc)) from None
    except ValueError as exc:
        raise RequestError(str(exc)) from None
    scope = {} if coaches is None else {"coaches": check_scope(role, coaches)}
    if expires_at is not None:
        scope["expires_at"] = expires_at.isoformat()
    audit(session, who, "token.create", f"user:{user.name}", "", role=role, **scope)
    return token, user


def set_user_role(session: Session, who: Principal, name: str, role: str, reason: str) -> User:
    """Give user ``name`` the role ``role``: every token it holds acts with it from the next
    request. Audited as ``user.role`` with the role before and after (a change to the role the
    user has changes nothing and is not audited). A change to or from ``gateway`` is a
    :class:`ConflictError`: a gateway's tokens are defined by their coaches, so a gateway is
    given tokens under a name of its own."""
    user = session.scalar(select(User).where(User.name == name).with_for_update())
    if user is None:
        raise NotFoundError(f"no user {name!r}")
    before = user.role
    if before == role:
        return user
    if GATEWAY in (before, role):
        raise ConflictError(
            f"user {name!r} is {article(before)}: a user neither becomes a gateway nor stops "
            "being one (a gateway's tokens are scoped to its coaches); use another name"
        )
    user.role = role
    audit(session, who, "user.role", f"user:{name}", reason, before=before, after=role)
    return user


def revoke_token(session: Session, who: Principal, token_id: int) -> ApiToken:
    """Revoke token ``token_id`` (audited the first time; revoking it again changes nothing)."""
    token = session.get(ApiToken, token_id)
    if token is None:
        raise NotFoundError(f"no token {token_id}")
    if token.revoked_at is None:
        token.revoked_at = utcnow()
        audit(session, who, "token.revoke", f"token:{token_id}", "")
    return token
