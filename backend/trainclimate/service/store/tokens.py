"""Bearer tokens and roles as stored: issuing a token, and finding whose a token is.

A token is 32 random bytes (``secrets.token_urlsafe``) prefixed ``tc_``, shown once when created
(``trainclimate token create`` or ``POST /api/v1/tokens``); only its SHA-256 is stored. A fast hash
is right here: the token is high-entropy random, not a password, so there is nothing to
brute-force, and every request can check it in microseconds. Roles are ordered
``viewer < operator < admin``: reads need viewer, writes operator, user and model management
admin. Reading the token off an HTTP request is the API's part
(:mod:`trainclimate.service.api.security`).
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from trainclimate.service.store.models import ROLES, ApiToken, User

RANK = {role: i for i, role in enumerate(ROLES)}
PREFIX = "tc_"


def hash_token(token: str) -> str:
    """The token's SHA-256, hex: what is stored and looked up."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Principal:
    """Who is calling: the user's name and role."""

    name: str
    role: str

    def can(self, role: str) -> bool:
        """Whether this principal's role is ``role`` or above it."""
        return RANK[self.role] >= RANK[role]


def create_token(session: Session, role: str, name: str | None = None) -> tuple[str, User]:
    """A new token for user ``name`` (created with ``role`` if new; an existing user keeps its
    name and gets the role asked for). Returns the token — the only time it is seen — and the user.
    """
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r} (viewer, operator, admin)")
    name = name or f"{role}-{secrets.token_hex(3)}"
    user = session.scalar(select(User).where(User.name == name))
    if user is None:
        user = User(name=name, role=role)
        session.add(user)
        session.flush()
    else:
        user.role = role
    token = PREFIX + secrets.token_urlsafe(32)
    session.add(ApiToken(user_id=user.id, token_hash=hash_token(token), prefix=token[:10]))
    return token, user


def authenticate(session: Session, token: str) -> Principal | None:
    """The principal a token belongs to, or None (unknown or revoked)."""
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
    return Principal(user.name, user.role)
