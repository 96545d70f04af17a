"""What the API writes. Each function works inside the caller's transaction (one per request, so
a failed request changes nothing) and records every override, mode change, model activation and
token change in the audit log with who, when and why."""

from __future__ import annotations

import threading
from datetime import datetime, timedelta

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from trainclimate.service.store import liveness
from trainclimate.service.store.models import (
    ApiToken,
    AuditLog,
    Coach,
    FleetClock,
    Override,
    PredictorModel,
    Telemetry,
    Train,
    User,
    utcnow,
)
from trainclimate.service.store.queries import (
    NotFoundError,
    RequestError,
    coach_or_404,
    fleet_clock,
)
from trainclimate.service.store.telemetry import insert_rows
from trainclimate.service.store.tokens import Principal, check_scope, create_token
from trainclimate.service.store.upsert import advance, insert_new
from trainclimate.sim.setpoint import U_BAND_K


class ConflictError(Exception):
    """A request that contradicts the stored state (→ 409)."""


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
    Returns (coach, created)."""
    coach = session.get(Coach, coach_id)
    created = False
    if coach is None:  # two gateways may register the same train or coach at once
        insert_new(session, Train.__table__, [{"id": train_id, "name": train_id}], ["id"])
        row = {"id": coach_id, "train_id": train_id, "fleet": "live", "ddpc_active": active}
        created = insert_new(session, Coach.__table__, [row], ["id"]) == 1
        coach = session.get(Coach, coach_id, populate_existing=True)
    if coach.train_id != train_id:
        raise ConflictError(f"coach {coach_id!r} belongs to train {coach.train_id!r}")
    if created:
        audit(session, who, "coach.register", coach_id, "", train_id=train_id, ddpc_active=active)
    return coach, created


class OutsideHorizonError(RequestError):
    """A batch with rows older than the backfill horizon (→ 422, nothing of it stored)."""


class Backfill:
    """How far back the live feed's telemetry is taken, over HTTP and MQTT alike: a row older
    than its coach's newest row — stored, or in the same batch — less ``horizon`` is refused, so
    that a gateway's wrong clock (a row dated 2000-01-01) cannot stretch what the queries and the
    next retraining read. ``refused`` counts the rows refused since start, by reason (one
    reason: ``outside_horizon``); the server's threads share it."""

    REASON = "outside_horizon"

    def __init__(self, horizon: timedelta) -> None:
        self.horizon = horizon
        self._refused: dict[str, int] = {}
        self._lock = threading.Lock()

    @property
    def refused(self) -> dict[str, int]:
        """A copy of the counts: reason → rows refused since start."""
        with self._lock:
            return dict(self._refused)

    def check(self, session: Session, coach_id: str, rows: list[dict]) -> None:
        """:class:`OutsideHorizonError` (counted), naming the first row out and why, if any of
        ``rows`` (a batch of ``coach_id``, not empty) is older than the horizon allows."""
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
        with self._lock:
            self._refused[self.REASON] = self._refused.get(self.REASON, 0) + len(out)
        first = rows[out[0]]["time"]
        raise OutsideHorizonError(
            f"rows[{out[0]}]: time {first.isoformat()} is outside the backfill horizon: more "
            f"than {self.horizon.total_seconds() / 86400:g} days before the newest row of coach "
            f"{coach_id!r} ({newest.isoformat()}); {len(out)} row(s) that old, nothing stored"
        )


def ingest(
    session: Session, coach_id: str, rows: list[dict], backfill: Backfill | None = None
) -> tuple[int, int]:
    """Store a batch of telemetry, advance the live fleet's clock and note the arrival
    (:mod:`.liveness`). Returns (stored, duplicates). With ``backfill``, a batch with a row
    older than its horizon is refused whole (:class:`OutsideHorizonError`)."""
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
    stored = insert_rows(session, coach.id, rows)
    # the clock is created by the first post ever, concurrent ones included
    advance(session, FleetClock.__table__, {"name": liveness.LIVE}, "time", newest)
    liveness.note_arrival(session, coach, utcnow())
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
    """Switch the DDPC layer on or off for a coach."""
    coach = coach_or_404(session, coach_id)
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
    until ``expires_at``, :func:`.tokens.create_token`), audited with its scope and expiry."""
    try:
        token, user = create_token(session, role, name, coaches, expires_at)
    except ValueError as exc:
        raise RequestError(str(exc)) from None
    scope = {} if coaches is None else {"coaches": check_scope(role, coaches)}
    if expires_at is not None:
        scope["expires_at"] = expires_at.isoformat()
    audit(session, who, "token.create", f"user:{user.name}", "", role=role, **scope)
    return token, user


def revoke_token(session: Session, who: Principal, token_id: int) -> ApiToken:
    """Revoke token ``token_id`` (audited the first time; revoking it again changes nothing)."""
    token = session.get(ApiToken, token_id)
    if token is None:
        raise NotFoundError(f"no token {token_id}")
    if token.revoked_at is None:
        token.revoked_at = utcnow()
        audit(session, who, "token.revoke", f"token:{token_id}", "")
    return token
