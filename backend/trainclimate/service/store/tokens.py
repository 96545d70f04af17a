"""Bearer tokens and roles as stored: issuing a token, and finding whose a token is.

A token is 32 random bytes (``secrets.token_urlsafe``) prefixed ``tc_``, shown once when created
(``trainclimate token create`` or ``POST /api/v1/tokens``); only its SHA-256 is stored. A fast hash
is right here: the token is high-entropy random, not a password, so there is nothing to
brute-force, and every request can check it in microseconds. Roles are ordered
``gateway < viewer < operator < admin``: reads need viewer, writes operator, user and model
management admin. A ``gateway`` token is scoped to coaches (stored with the token): it passes no
role check, and may only register its coaches, push their telemetry and pull their setpoints
(the API's :func:`~trainclimate.service.api.security.require_coach`). A token with a scope is a
gateway's whatever its user's role, and a gateway user's token without one is for no coach. A
token past its ``expires_at`` no longer authenticates. Reading the token off an HTTP request is
the API's part (:mod:`trainclimate.service.api.security`).
"""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate.service.store.models import ROLES, ApiToken, User, utcnow

RANK = {role: i for i, role in enumerate(ROLES)}
PREFIX = "tc_"
GATEWAY = "gateway"
#: A coach id as the API takes it (``POST /coaches``).
COACH_ID = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")


def hash_token(token: str) -> str:
    """The token's SHA-256, hex: what is stored and looked up."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Principal:
    """Who is calling: the user's name and role, and for a gateway the coaches its token is for."""

    name: str
    role: str
    coaches: frozenset[str] = frozenset()

    def can(self, role: str) -> bool:
        """Whether this principal's role is ``role`` or above it (a gateway never is: it ranks
        below viewer, and the generic role checks ask at least viewer)."""
        return RANK[self.role] >= RANK[role]

    def serves(self, coach_id: str) -> bool:
        """Whether this is a gateway token scoped to ``coach_id``."""
        return self.role == GATEWAY and coach_id in self.coaches


def check_scope(role: str, coaches: list[str] | None) -> list[str] | None:
    """The coach scope for a token of ``role``: required (non-empty, valid ids, no repeats
    kept) for a gateway, refused for any other role (ValueError)."""
    if role != GATEWAY:
        if coaches is not None:
            raise ValueError(f"a coach scope is for gateway tokens only, not {role}")
        return None
    if not coaches:
        raise ValueError("a gateway token needs the coaches it is for")
    bad = [c for c in coaches if not isinstance(c, str) or not COACH_ID.match(c)]
    if bad:
        raise ValueError(f"not a coach id: {bad[0]!r}")
    return list(dict.fromkeys(coaches))


def create_token(
    session: Session,
    role: str,
    name: str | None = None,
    coaches: list[str] | None = None,
    expires_at: datetime | None = None,
) -> tuple[str, User]:
    """A new token for user ``name`` (created with ``role`` if new; an existing user keeps its
    name and gets the role asked for), scoped to ``coaches`` for a gateway (:func:`check_scope`),
    valid until ``expires_at`` (UTC; None: until revoked; ValueError if not in the future).
    Returns the token — the only time it is seen — and the user.
    """
    if expires_at is not None and expires_at <= utcnow():
        raise ValueError("the expiry must lie in the future")
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r} (gateway, viewer, operator, admin)")
    coaches = check_scope(role, coaches)
    name = name or f"{role}-{secrets.token_hex(3)}"
    user = session.scalar(select(User).where(User.name == name))
    if user is None:
        user = User(name=name, role=role)
        session.add(user)
        session.flush()
    else:
        user.role = role
    token = PREFIX + secrets.token_urlsafe(32)
    session.add(
        ApiToken(
            user_id=user.id,
            token_hash=hash_token(token),
            prefix=token[:10],
            coaches=coaches,
            expires_at=expires_at,
        )
    )
    return token, user


def authenticate(session: Session, token: str) -> Principal | None:
    """The principal a token belongs to, or None (unknown, revoked or expired)."""
    if not token.startswith(PREFIX):
        return None
    digest = hash_token(token)
    row = session.execute(
        select(ApiToken, User).join(User).where(ApiToken.token_hash == digest)
    ).first()
    if row is None:
        return None
    api_token, user = row
    if api_token.revoked_at is not None or not hmac.compare_digest(api_token.token_hash, digest):
        return None
    if api_token.expires_at is not None and api_token.expires_at <= utcnow():
        return None
    if api_token.coaches is not None or user.role == GATEWAY:
        return Principal(user.name, GATEWAY, frozenset(api_token.coaches or ()))
    return Principal(user.name, user.role)
