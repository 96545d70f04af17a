"""The ``gateway`` role, on SQLite and on PostgreSQL: a token scoped to coaches may register them,
push their telemetry and pull their setpoints — and nothing else. The scope matrix is generated
from the app's routes (a new route is checked without being listed); tokens are created with
``trainclimate token create --role gateway --coaches …`` and ``POST /tokens``, audited with their
scope; the migration adding the scope goes up and down."""

from __future__ import annotations

import json

import pytest
from fastapi.routing import APIRoute, iter_route_contexts
from sqlalchemy import inspect, select

from helpers.service import (
    API,
    at,
    flat_row,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
    to_wire,
)
from trainclimate import cli
from trainclimate.service import api
from trainclimate.service.store.db import Database, downgrade, make_engine, migrate
from trainclimate.service.store.models import ApiToken, AuditLog, User
from trainclimate.service.store.tokens import RANK, authenticate, create_token

MINE, MINE_TOO, OTHER = "G1-A", "G1-B", "X1-A"
#: What a gateway token may do, for the coaches of its scope only.
ALLOWED = {("POST", "/coaches"), ("POST", "/telemetry"), ("GET", "/coaches/{coach_id}/setpoint")}


def routes() -> list[tuple[str, str]]:
    """Every (method, path) the API serves (path without the ``/api/v1`` prefix)."""
    return sorted(
        (method, route.path.removeprefix(API))
        for route in iter_route_contexts(api.router.routes)
        if isinstance(route.original_route, APIRoute)
        for method in route.methods
    )


def gateway_headers(settings, coaches=(MINE, MINE_TOO), name="gw-test") -> dict[str, str]:
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            token, _ = create_token(s, "gateway", name, list(coaches))
    finally:
        db.dispose()
    return {"Authorization": f"Bearer {token}"}


def request(client, headers, method: str, path: str, coach: str):
    """The request for route (``method``, ``path``) about ``coach``, with a valid body where the
    route takes one (an allowed route must succeed)."""
    train = coach.split("-")[0]
    url = API + path.format(coach_id=coach, train_id=train, version=1, token_id=1, name="gw-test")
    body = None
    if (method, path) == ("POST", "/coaches"):
        body = {"id": coach, "train_id": coach.split("-")[0], "ddpc_active": True}
    elif (method, path) == ("POST", "/telemetry"):
        body = {"coach_id": coach, "rows": [to_wire(flat_row(at(0)))]}
    elif method in ("POST", "PUT"):
        body = {}
    return client.request(method, url, headers=headers, json=body)


def test_gateway_ranks_below_viewer():
    assert RANK["gateway"] < RANK["viewer"] < RANK["operator"] < RANK["admin"]


def test_the_scope_matrix_over_every_route(client, tokens, settings):
    gw = gateway_headers(settings)
    op = tokens["operator"]
    assert register(client, op, OTHER, "X1").status_code == 201
    served = routes()
    assert set(served) >= ALLOWED
    protected = [r for r in served if r not in {("GET", "/health"), ("GET", "/ready")}]
    protected.sort(key=lambda r: r != ("POST", "/coaches"))  # registering first
    checked = 0
    for method, path in protected:
        if (method, path) in ALLOWED:
            mine = request(client, gw, method, path, MINE)
            assert mine.status_code in (200, 201), (method, path, mine.text)
            other = request(client, gw, method, path, OTHER)
            assert other.status_code == 403, (method, path, other.text)
            assert other.json() == {"detail": f"this gateway token is not for coach '{OTHER}'"}
        else:
            for coach in (MINE, OTHER):  # even about its own coach
                reply = request(client, gw, method, path, coach)
                assert reply.status_code == 403, (method, path, coach, reply.text)
                assert "the token is gateway" in reply.json()["detail"], (method, path)
        checked += 1
    assert checked == len(protected) >= 20
    # what the allowed calls did, seen by a viewer; the other coach has no telemetry
    viewer = tokens["viewer"]
    coach = client.get(f"{API}/coaches/{MINE}", headers=viewer).json()
    assert coach["fleet"] == "live" and coach["train_id"] == "G1"
    assert len(client.get(f"{API}/coaches/{MINE}/timeseries", headers=viewer).json()["time"]) == 1
    assert client.get(f"{API}/coaches/{OTHER}/timeseries", headers=viewer).json()["time"] == []
    audit = client.get(f"{API}/audit", headers=viewer).json()
    registered = [(a["user"], a["role"]) for a in audit if a["action"] == "coach.register"]
    assert registered == [("gw-test", "gateway"), ("test-operator", "operator")]


def test_a_gateway_body_and_path_edge_cases(client, tokens, settings):
    gw = gateway_headers(settings)
    # a malformed body is the route's 422, never a pass for another coach
    assert client.post(f"{API}/coaches", json={"id": MINE}, headers=gw).status_code == 422
    assert client.post(f"{API}/telemetry", json={"coach_id": MINE}, headers=gw).status_code == 422
    bad = client.post(f"{API}/coaches", content=b"{", headers=gw)
    assert bad.status_code == 422
    # its own coach, before it is registered: the route's 404
    assert client.get(f"{API}/coaches/{MINE}/setpoint", headers=gw).status_code == 404
    # registered coach of the scope, telemetry for another coach in the same batch shape: 403
    assert register(client, gw, MINE, "G1").status_code == 201
    assert register(client, gw, MINE, "G1").status_code == 200
    rows = [flat_row(at(0))]
    assert post_rows(client, gw, MINE, rows).status_code == 200
    assert post_rows(client, gw, OTHER, rows).status_code == 403
    assert register(client, gw, "g1-a", "G1").status_code == 403  # ids are case-sensitive
    # operators and viewers keep what they could do
    assert post_rows(client, tokens["operator"], MINE, rows).json()["duplicates"] == 1
    assert register(client, tokens["operator"], OTHER, "X1").status_code == 201
    assert (
        client.get(f"{API}/coaches/{OTHER}/setpoint", headers=tokens["viewer"]).status_code == 200
    )
    assert register(client, tokens["viewer"], "V-1", "V").status_code == 403


def test_token_create_command_for_a_gateway(client, settings, capsys):
    base = ["token", "create", "--db", settings.database_url, "--json"]
    code = cli.main([*base, "--role", "gateway", "--coaches", f"{MINE},{MINE_TOO}", "--name", "gw"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["name"], out["role"], out["coaches"]) == ("gw", "gateway", [MINE, MINE_TOO])
    gw = {"Authorization": f"Bearer {out['token']}"}
    assert register(client, gw, MINE_TOO, "G1").status_code == 201
    assert register(client, gw, OTHER, "X1").status_code == 403
    assert client.get(f"{API}/coaches", headers=gw).status_code == 403
    # --coaches is required with gateway, refused with any other role: exit 2, one line
    for args in (
        ["--role", "gateway"],
        ["--role", "gateway", "--coaches", ","],
        ["--role", "gateway", "--coaches", "a b"],
        ["--role", "operator", "--coaches", MINE],
        ["--role", "viewer", "--coaches", MINE],
    ):
        assert cli.main([*base, *args]) == 2, args
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.count("\n") == 1, (args, captured.err)
        assert "--coaches" in captured.err, args


def test_tokens_through_the_api_for_a_gateway(client, tokens, settings):
    admin = tokens["admin"]
    body = {"role": "gateway", "name": "gw-api", "coaches": [MINE, MINE_TOO]}
    reply = client.post(f"{API}/tokens", json=body, headers=admin)
    assert reply.status_code == 201, reply.text
    created = reply.json()
    assert (created["role"], created["coaches"]) == ("gateway", [MINE, MINE_TOO])
    gw = {"Authorization": f"Bearer {created['token']}"}
    assert register(client, gw, MINE, "G1").status_code == 201
    assert client.get(f"{API}/me", headers=gw).status_code == 403
    # coaches are required with gateway, refused otherwise; lower roles cannot create one
    for bad in (
        {"role": "gateway"},
        {"role": "gateway", "coaches": []},
        {"role": "gateway", "coaches": ["a b"]},
        {"role": "operator", "coaches": [MINE]},
    ):
        assert client.post(f"{API}/tokens", json=bad, headers=admin).status_code == 422, bad
    assert client.post(f"{API}/tokens", json=body, headers=tokens["operator"]).status_code == 403
    assert client.post(f"{API}/tokens", json=body, headers=gw).status_code == 403
    listed = client.get(f"{API}/tokens", headers=admin).json()
    assert [(t["user"], t["role"], t["coaches"]) for t in listed][-1] == (
        "gw-api",
        "gateway",
        [MINE, MINE_TOO],
    )
    assert all(t["coaches"] is None for t in listed[:-1])
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            entry = s.scalar(select(AuditLog).where(AuditLog.action == "token.create"))
            assert entry.target == "user:gw-api"
            assert entry.detail == {"role": "gateway", "coaches": [MINE, MINE_TOO]}
    finally:
        db.dispose()
    # revoking it works as for any token
    assert client.delete(f"{API}/tokens/{listed[-1]['id']}", headers=admin).status_code == 200
    assert register(client, gw, MINE, "G1").status_code == 401


def test_a_scoped_token_stays_a_gateway_and_expires(client, tokens, settings):
    """Tokens stored before users kept their role: a token with a scope is a gateway's even if
    its user's role is another; a gateway user's token without a scope is for no coach. An
    expired token is refused."""
    gw = gateway_headers(settings, name="shared")
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            user = s.scalar(select(User).where(User.name == "shared"))
            user.role = "operator"  # as creating an operator's token for the name once did
        assert client.get(f"{API}/coaches", headers=gw).status_code == 403
        assert register(client, gw, OTHER, "X1").status_code == 403
        with db.transaction() as s:
            user = s.scalar(select(User).where(User.name == "shared"))
            user.role = "gateway"
            s.flush()
            s.add(ApiToken(user_id=user.id, token_hash="0" * 64, prefix="tc_x"))
        with db.transaction() as s:
            token = s.scalar(select(ApiToken).where(ApiToken.token_hash == "0" * 64))
            assert token.coaches is None  # stored as SQL NULL
            token.expires_at = at(0)
        token_text = gw["Authorization"].removeprefix("Bearer ")
        with db.transaction() as s:
            who = authenticate(s, token_text)
            assert who.role == "gateway" and who.coaches == frozenset({MINE, MINE_TOO})
            scoped = s.scalar(select(ApiToken).where(ApiToken.coaches.is_not(None)))
            scoped.expires_at = at(0)  # long past
        assert register(client, gw, MINE, "G1").status_code == 401
    finally:
        db.dispose()


@pytest.fixture
def migrated(db_url):
    migrate(db_url)
    return db_url


def _columns(url: str) -> set[str]:
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            return {c["name"] for c in inspect(conn).get_columns("api_tokens")}
    finally:
        engine.dispose()


def test_the_migration_up_and_down(migrated):
    url = migrated
    assert {"coaches", "expires_at"} <= _columns(url)
    db = Database(url)
    try:
        with db.transaction() as s:
            create_token(s, "gateway", "gw", [MINE])
            create_token(s, "admin", "alice")
    finally:
        db.dispose()
    downgrade(url, "0001")
    assert not {"coaches", "expires_at"} & _columns(url)
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            rows = conn.execute(
                select(User.name, ApiToken.__table__.c.revoked_at)
                .select_from(ApiToken.__table__.join(User.__table__))
                .order_by(User.name)
            ).all()
    finally:
        engine.dispose()
    # the gateway's token is revoked on the way down: without its scope it would mean nothing
    assert [(name, revoked is not None) for name, revoked in rows] == [
        ("alice", False),
        ("gw", True),
    ]
    migrate(url)
    assert {"coaches", "expires_at"} <= _columns(url)
