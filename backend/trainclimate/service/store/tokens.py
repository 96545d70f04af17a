"""Bearer tokens, users and roles as stored: creating a token, and finding whose a token is.

A token is 32 random bytes (``secrets.token_urlsafe``) prefixed ``tc_``, shown once when created
(``trainclimate token create`` or ``POST /api/v1/tokens``); only its SHA-256 is stored. A fast hash
is right here: the token is high-entropy random, not a password, so there is nothing to
brute-force, and every request can check it in microseconds. Roles are ordered
``metrics < gateway < viewer < operator < admin``: reads need viewer, writes operator, user and
model management admin; a ``metrics`` token (a Prometheus scraper's) reads the metrics only.

Every token is a user's, and a user has one role, which all its tokens act with. Creating a token
never changes another one: a new name becomes a user with the role asked for, an existing user's
new token has the user's role (asking another is a :class:`RoleConflictError`), and only an
admin's explicit, audited change (:func:`~trainclimate.service.store.commands.set_user_role`,
``PUT /api/v1/users/{name}/role``) changes a user's role, for all its tokens at once. A
``gateway`` user's tokens are each scoped to coaches (stored with the token): such a token passes
no role check, and may only register its coaches, push their telemetry and pull their setpoints
(the API's :func:`~trainclimate.service.api.security.require_coach`). Since a gateway's identity
is its scope, no user becomes a gateway or stops being one. Tokens stored before these rules keep
working as they did: a token with a scope is a gateway's whatever its user's role, and a gateway
user's token without one is for no coach. A token past its ``expires_at`` no longer
authenticates. Reading the token off an HTTP request is the API's part
(:mod:`trainclimate.service.api.security`).
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
from trainclimate.service.store.upsert import insert_new

RANK = {role: i for i, role in enumerate(ROLES)}
PREFIX = "tc_"
GATEWAY = "gateway"
#: The role of a metrics scraper's token: ``GET /api/v1/metrics`` only.
METRICS = "metrics"
#: The longest user name the API and the CLI take: its audit target ``user:<name>`` fits the
#: audit log's 64-character ``target`` column (the ``users.name`` column holds 100).
USER_NAME_MAX = 48
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


class RoleConflictError(Exception):
    """A token asked for an existing user with a role other than the user's."""


def create_token(
    session: Session,
    role: str,
    name: str | None = None,
    coaches: list[str] | None = None,
    expires_at: datetime | None = None,
) -> tuple[str, User]:
    """A new token for user ``name``, created with ``role`` if new.

    Parameters
    ----------
    session
        The transaction to write in.
    role
        The token's role: a new user's role, or the existing user's own (else
        :class:`RoleConflictError`; only an admin changes a user's role, through
        :func:`~trainclimate.service.store.commands.set_user_role`).
    name
        The user; None: a new user named after the role.
    coaches
        A gateway token's scope (:func:`check_scope`).
    expires_at
        When the token stops authenticating (UTC; None: when revoked; ValueError if not in the
        future).

    Returns
    -------
    tuple of (str, User)
        The token — the only time it is seen — and its user.
    """
    if expires_at is not None and expires_at <= utcnow():
        raise ValueError("the expiry must lie in the future")
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r} ({', '.join(ROLES)})")
    coaches = check_scope(role, coaches)
    name = name or f"{role}-{secrets.token_hex(3)}"
    # a new name becomes a user, also when two requests create it at once
    insert_new(session, User.__table__, [{"name": name, "role": role}], ["name"])
    user = session.scalar(select(User).where(User.name == name))
    if user.role != role:
        raise RoleConflictError(
            f"user {name!r} is {article(user.role)}, not {article(role)}: its tokens have its role "
            f"(an admin changes it with PUT /api/v1/users/{name}/role); or give another name"
        )
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


def article(role: str) -> str:
    """``role`` with its article: ``an admin``, ``a viewer``."""
    return f"{'an' if role[0] in 'aeiou' else 'a'} {role}"


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
