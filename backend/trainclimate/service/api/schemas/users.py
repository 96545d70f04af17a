"""Users, their tokens and roles, and the audit log."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field, model_validator

from trainclimate.service.api.schemas.base import CoachIds, Strict
from trainclimate.service.store.tokens import USER_NAME_MAX

Role = Literal["metrics", "gateway", "viewer", "operator", "admin"]

#: The shortest life of an expiring token (a minute): one that expires before it can be used is
#: a mistake. [days]
MIN_EXPIRES_DAYS = 1 / 1440


class AuditOut(BaseModel):
    id: int
    time: datetime
    user: str
    role: str
    action: str
    target: str
    reason: str
    detail: dict


class TokenIn(Strict):
    role: Role = Field(
        description="a new user's role; for an existing user, its own (another role is 409)"
    )
    name: str | None = Field(
        default=None,
        min_length=1,
        max_length=USER_NAME_MAX,
        description="the token's user, created if new (default: a new user named after the role)",
        examples=["alice"],
    )
    coaches: CoachIds | None = Field(
        default=None,
        min_length=1,
        max_length=1000,
        description="the coaches a gateway token is for: required with gateway, else refused",
        examples=[["124-A", "124-B"]],
    )

    @model_validator(mode="after")
    def _scope(self) -> TokenIn:
        if self.role == "gateway" and not self.coaches:
            raise ValueError("a gateway token needs coaches: the coach ids it is for")
        if self.role != "gateway" and self.coaches is not None:
            raise ValueError("coaches are for gateway tokens only")
        return self

    expires_in_days: float | None = Field(
        default=None,
        ge=MIN_EXPIRES_DAYS,
        le=3650,
        description="the token stops authenticating this many days after its creation, at "
        "least a minute (default: valid until revoked)",
        examples=[90],
    )


class TokenOut(BaseModel):
    token: str = Field(description="shown once; only its hash is stored")
    name: str = Field(description="the token's user")
    role: Role
    coaches: list[str] | None = Field(description="a gateway token's coaches; else null")
    expires_at: datetime | None = Field(description="null: it does not expire")
    mqtt_username: str | None = Field(
        default=None,
        description="with serve --mqtt-dynsec, a gateway token's own broker user (its password "
        "is the token); else null",
    )


class Me(BaseModel):
    name: str = Field(examples=["alice"])
    role: Role


class TokenInfo(BaseModel):
    id: int
    user: str = Field(description="the token's user")
    role: Role = Field(description="the role the token acts with")
    prefix: str
    coaches: list[str] | None = Field(description="a gateway token's coaches; else null")
    created_at: datetime
    expires_at: datetime | None = Field(description="null: it does not expire")
    revoked_at: datetime | None


class RoleChange(Strict):
    """A user's new role, for every token it holds."""

    role: Role = Field(
        examples=["operator"],
        description="viewer, operator or admin: a user neither becomes a gateway nor stops being "
        "one (409)",
    )
    reason: str = Field(min_length=1, max_length=500, examples=["runs the night shift now"])


class UserOut(BaseModel):
    name: str = Field(examples=["alice"])
    role: Role
    tokens: int = Field(description="its tokens not revoked: each acts with this role")
