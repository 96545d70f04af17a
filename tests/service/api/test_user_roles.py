"""Users keep their role, on SQLite and on PostgreSQL: creating a token — ``POST /tokens`` or
``trainclimate token create`` — never changes another token's role or scope (another role for an
existing user is 409, or a one-line error); ``GET /tokens`` names each token's user and role;
only an admin changes a user's role, with ``PUT /users/{name}/role``, audited as ``user.role``
with the role before and after, and never to or from gateway."""

from __future__ import annotations

import json

from sqlalchemy import select

from helpers.service import (
    API,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate import cli
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import AuditLog


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def new_token(client, admin, role: str, name: str, **extra):
    return client.post(f"{API}/tokens", json={"role": role, "name": name, **extra}, headers=admin)


def listed(client, admin) -> list[tuple[str, str, str]]:
    """``GET /tokens`` as (user, role, prefix), oldest first."""
    rows = client.get(f"{API}/tokens", headers=admin).json()
    return [(t["user"], t["role"], t["prefix"]) for t in rows]


def audit(settings, action: str) -> list[AuditLog]:
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            return s.scalars(select(AuditLog).where(AuditLog.action == action)).all()
    finally:
        db.dispose()


def test_a_new_token_never_changes_another(client, tokens, settings):
    admin = tokens["admin"]
    first = new_token(client, admin, "viewer", "role-probe").json()
    probe = bearer(first["token"])
    # another role for the same user: refused, and the user's token keeps its role
    reply = new_token(client, admin, "admin", "role-probe")
    assert reply.status_code == 409
    assert reply.json() == {
        "detail": "user 'role-probe' is a viewer, not an admin: its tokens have its role (an "
        "admin changes it with PUT /api/v1/users/role-probe/role); or give another name"
    }
    assert client.get(f"{API}/me", headers=probe).json() == {"name": "role-probe", "role": "viewer"}
    assert client.get(f"{API}/tokens", headers=probe).status_code == 403
    # a gateway token for an operator's name: refused; the operator's tokens stay operators'
    reply = new_token(client, admin, "gateway", "test-operator", coaches=["G-A"])
    assert reply.status_code == 409
    assert "user 'test-operator' is an operator, not a gateway" in reply.json()["detail"]
    assert register(client, tokens["operator"], "O-A", "O").status_code == 201
    # and the other way round: an operator token for a gateway's name
    gateway = new_token(client, admin, "gateway", "gw-9", coaches=["G-A"]).json()
    assert new_token(client, admin, "operator", "gw-9").status_code == 409
    assert register(client, bearer(gateway["token"]), "G-A", "G").status_code == 201
    assert client.get(f"{API}/coaches", headers=bearer(gateway["token"])).status_code == 403
    # the user's own role: a second token, each listed with its user and role
    second = new_token(client, admin, "viewer", "role-probe")
    assert second.status_code == 201
    assert (second.json()["name"], second.json()["role"]) == ("role-probe", "viewer")
    another_scope = new_token(client, admin, "gateway", "gw-9", coaches=["G-B"])
    assert another_scope.json()["coaches"] == ["G-B"]
    assert listed(client, admin) == [
        ("test-viewer", "viewer", tokens["viewer"]["Authorization"][7:17]),
        ("test-operator", "operator", tokens["operator"]["Authorization"][7:17]),
        ("test-admin", "admin", tokens["admin"]["Authorization"][7:17]),
        ("role-probe", "viewer", first["token"][:10]),
        ("gw-9", "gateway", gateway["token"][:10]),
        ("role-probe", "viewer", second.json()["token"][:10]),
        ("gw-9", "gateway", another_scope.json()["token"][:10]),
    ]
    # the first gateway token keeps its own scope
    assert register(client, bearer(gateway["token"]), "G-B", "G").status_code == 403
    assert [(a.target, a.detail["role"]) for a in audit(settings, "token.create")] == [
        ("user:role-probe", "viewer"),
        ("user:gw-9", "gateway"),
        ("user:role-probe", "viewer"),
        ("user:gw-9", "gateway"),
    ]


def test_an_admin_changes_a_users_role(client, tokens, settings):
    admin = tokens["admin"]
    url = f"{API}/users/role-probe/role"
    tokens_of_probe = [bearer(new_token(client, admin, "viewer", "role-probe").json()["token"])]
    tokens_of_probe.append(bearer(new_token(client, admin, "viewer", "role-probe").json()["token"]))
    body = {"role": "operator", "reason": "runs the night shift now"}
    # only an admin; a reason is required
    for who in ("viewer", "operator"):
        reply = client.put(url, json=body, headers=tokens[who])
        assert reply.status_code == 403, who
    assert client.put(url, json={"role": "operator"}, headers=admin).status_code == 422
    reply = client.put(url, json=body, headers=admin)
    assert reply.status_code == 200
    assert reply.json() == {"name": "role-probe", "role": "operator", "tokens": 2}
    for headers in tokens_of_probe:  # every token of the user, at once
        assert client.get(f"{API}/me", headers=headers).json()["role"] == "operator"
    assert register(client, tokens_of_probe[0], "P-A", "P").status_code == 201
    [entry] = audit(settings, "user.role")
    assert (entry.user_name, entry.role, entry.target, entry.reason) == (
        "test-admin",
        "admin",
        "user:role-probe",
        "runs the night shift now",
    )
    assert entry.detail == {"before": "viewer", "after": "operator"}
    # a token of the new role may now be created; the role it has already changes nothing
    assert new_token(client, admin, "operator", "role-probe").status_code == 201
    assert client.put(url, json=body, headers=admin).json()["tokens"] == 3
    assert len(audit(settings, "user.role")) == 1
    # unknown users; to or from gateway: refused
    missing = client.put(f"{API}/users/nobody/role", json=body, headers=admin)
    assert missing.status_code == 404 and missing.json() == {"detail": "no user 'nobody'"}
    new_token(client, admin, "gateway", "gw-9", coaches=["G-A"])
    for name, role in (("role-probe", "gateway"), ("gw-9", "admin")):
        reply = client.put(
            f"{API}/users/{name}/role", json={"role": role, "reason": "x"}, headers=admin
        )
        assert reply.status_code == 409, (name, role)
        assert "a user neither becomes a gateway nor stops being one" in reply.json()["detail"]
    assert listed(client, admin)[-1][:2] == ("gw-9", "gateway")
    # a demoted admin's token loses the role from its next request
    demote = {"role": "viewer", "reason": "left the team"}
    assert client.put(f"{API}/users/test-admin/role", json=demote, headers=admin).status_code == 200
    assert client.get(f"{API}/tokens", headers=admin).status_code == 403


def test_token_create_command_keeps_the_users_role(client, tokens, settings, capsys):
    base = ["token", "create", "--db", settings.database_url, "--json"]
    for args in (
        ["--role", "admin", "--name", "test-viewer"],
        ["--role", "gateway", "--coaches", "G-A", "--name", "test-operator"],
    ):
        assert cli.main([*base, *args]) == 2, args
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.count("\n") == 1, captured.err
        assert "--name: user 'test-" in captured.err and "its tokens have its role" in captured.err
    assert client.get(f"{API}/tokens", headers=tokens["viewer"]).status_code == 403
    assert register(client, tokens["operator"], "O-A", "O").status_code == 201
    assert len(listed(client, tokens["admin"])) == 3  # nothing created
    # the user's own role: another token
    assert cli.main([*base, "--role", "viewer", "--name", "test-viewer"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["name"], out["role"]) == ("test-viewer", "viewer")
    assert client.get(f"{API}/me", headers=bearer(out["token"])).json()["role"] == "viewer"


def test_a_user_name_fits_its_audit_target(client, tokens, settings):
    """A name is at most 48 characters: its audit target ``user:<name>`` fits the 64-character
    column (a 60-character name was a 500 on PostgreSQL). Longer: 422, nothing created."""
    admin = tokens["admin"]
    longest = "n" * 48
    reply = new_token(client, admin, "viewer", longest)
    assert reply.status_code == 201, reply.text
    change = {"role": "operator", "reason": "a test"}
    reply = client.put(f"{API}/users/{longest}/role", json=change, headers=admin)
    assert reply.status_code == 200, reply.text
    assert [a.target for a in audit(settings, "user.role")] == [f"user:{longest}"]
    before = listed(client, admin)
    for length in (49, 59, 60, 100):
        reply = new_token(client, admin, "viewer", "n" * length)
        assert reply.status_code == 422, (length, reply.text)
        reply = client.put(f"{API}/users/{'n' * length}/role", json=change, headers=admin)
        assert reply.status_code == 422, (length, reply.text)
    assert listed(client, admin) == before
