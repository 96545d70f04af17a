"""Object-level authorization (OWASP API1), on SQLite and on PostgreSQL: a request naming an
object — a coach, a train, a model, a token, a user — is answered 2xx only when the caller's role
allows the route and, for a gateway token, the object is its own. The matrix is generated from
the app's routes: every route that takes an id (in its path, query or body) must have its rule
below, and is requested by each role and by a gateway naming its own objects, another gateway's
coach, and its own coach in another gateway's train. A gateway registers coaches only into its
own trains (checked under concurrent registrations too); a coach never changes train."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest
from fastapi.routing import APIRoute, iter_route_contexts
from sqlalchemy import select

from helpers.service import (
    API,
    at,
    flat_row,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
    to_wire,
)
from trainclimate.service.store import commands
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import AuditLog, Coach
from trainclimate.service.store.tokens import RANK, Principal, create_token

#: Gateway 1's coaches (its token's scope), and gateway 2's, registered as train GW2.
GW1 = ("GW1-A", "GW1-B")
GW2 = ("GW2-A", "GW2-B")
#: What a route's path, query or body names an object by.
ID_FIELDS = {"id", "coach_id", "train_id", "coaches", "name", "version", "token_id", "user"}


@dataclass(frozen=True)
class Rule:
    """Who may call a route: ``role`` or above, and a gateway token about its own coaches if
    ``gateway``; ``body`` the request body about the target (a valid one, so that a caller let
    in gets the route's own answer); ``query`` the query string."""

    role: str
    gateway: bool = False
    body: object = None
    query: str = ""


def _coach(t: dict) -> dict:
    return {"id": t["coach"], "train_id": t["train"], "ddpc_active": True}


def _telemetry(t: dict) -> dict:
    return {"coach_id": t["coach"], "rows": [to_wire(flat_row(at(1)))]}


#: (method, path) → its rule, for every route that takes an id.
RULES = {
    ("POST", "/coaches"): Rule("operator", gateway=True, body=_coach),
    ("POST", "/telemetry"): Rule("operator", gateway=True, body=_telemetry),
    ("GET", "/coaches/{coach_id}/setpoint"): Rule("viewer", gateway=True),
    ("GET", "/coaches/{coach_id}"): Rule("viewer"),
    ("GET", "/coaches/{coach_id}/timeseries"): Rule("viewer"),
    ("GET", "/coaches/{coach_id}/timeseries.csv"): Rule("viewer"),
    ("GET", "/coaches/{coach_id}/setpoints"): Rule("viewer"),
    ("GET", "/coaches/{coach_id}/overrides"): Rule("viewer"),
    ("POST", "/coaches/{coach_id}/override"): Rule(
        "operator", body=lambda t: {"t_ref_c": 22.5, "duration_min": 5, "reason": "probe"}
    ),
    ("DELETE", "/coaches/{coach_id}/override"): Rule("operator"),
    ("PUT", "/coaches/{coach_id}/controller"): Rule(
        "operator", body=lambda t: {"active": True, "reason": "probe"}
    ),
    ("GET", "/trains/{train_id}"): Rule("viewer"),
    ("GET", "/trains/{train_id}/comparison"): Rule("viewer"),
    ("GET", "/trains/{train_id}/comparison.csv"): Rule("viewer"),
    ("GET", "/trains/{train_id}/plan"): Rule("viewer"),
    ("PUT", "/trains/{train_id}/plan"): Rule(
        "operator", body=lambda t: {"plan": "fixed", "reason": "probe"}
    ),
    ("GET", "/trains/{train_id}/guard"): Rule("viewer"),
    ("POST", "/trains/{train_id}/guard/reset"): Rule(
        "operator", body=lambda t: {"reason": "probe"}
    ),
    ("GET", "/models/{version}/health"): Rule("viewer"),
    ("POST", "/models/{version}/activate"): Rule("admin", query="reason=probe"),
    # both days and since: 422 once let in, so that no fit starts in the background
    ("POST", "/models/retrain"): Rule(
        "admin",
        body=lambda t: {"reason": "probe", "coaches": [t["coach"]], "days": 1, "since": "2024"},
    ),
    ("POST", "/tokens"): Rule("admin", body=lambda t: {"role": "viewer", "name": t["user"]}),
    ("DELETE", "/tokens/{token_id}"): Rule("admin"),
    ("PUT", "/users/{name}/role"): Rule("admin", body=lambda t: {"role": "viewer", "reason": "x"}),
}


def id_routes(app) -> set[tuple[str, str]]:
    """Every (method, path) of ``app`` (path without ``/api/v1``) whose path, query or body
    names an object."""
    out = set()
    for route in iter_route_contexts(app.routes):
        if not isinstance(route.original_route, APIRoute) or not route.path.startswith(API):
            continue
        names = {p.name for p in route.dependant.path_params + route.dependant.query_params}
        if route.body_field is not None:
            names |= set(route.body_field.field_info.annotation.model_fields)
        if names & ID_FIELDS:
            out |= {(method, route.path.removeprefix(API)) for method in route.methods}
    return out


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture
def world(client, tokens, settings) -> dict:
    """Gateway 1 (scope GW1-A, GW1-B; GW1-A registered in train GW1), gateway 2 (GW2-A, GW2-B,
    registered as train GW2, with a minute of telemetry each) and a viewer ``victim`` whose
    token the admin may revoke; the headers by principal, and the victim's token id."""
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            gw1, _ = create_token(s, "gateway", "gw-1", list(GW1))
            gw2, _ = create_token(s, "gateway", "gw-2", list(GW2))
            create_token(s, "viewer", "victim")
    finally:
        db.dispose()
    headers = {"gateway": bearer(gw1), "gateway 2": bearer(gw2), "none": {}, **tokens}
    for coach in GW2:
        assert register(client, headers["gateway 2"], coach, "GW2").status_code == 201
        assert post_rows(client, headers["gateway 2"], coach, [flat_row(at(1))]).status_code == 200
    assert register(client, headers["gateway"], GW1[0], "GW1").status_code == 201
    listed = client.get(f"{API}/tokens", headers=tokens["admin"]).json()
    victim = next(t["id"] for t in listed if t["user"] == "victim")
    return {"headers": headers, "victim": victim}


def send(client, headers, method: str, path: str, target: dict):
    """Route (``method``, ``path``) about ``target`` (coach, train, user; the model version and
    the victim's token are fixed), with its rule's body and query."""
    rule = RULES[(method, path)]
    url = API + path.format(
        coach_id=target["coach"],
        train_id=target["train"],
        version=1,
        token_id=target["token_id"],
        name=target["user"],
    )
    if rule.query:
        url += "?" + rule.query
    body = rule.body(target) if rule.body else None
    return client.request(method, url, headers=headers, json=body)


def test_every_route_that_takes_an_id_has_its_rule(client):
    assert id_routes(client.app) == set(RULES), "a route that takes an id needs its rule here"


def test_no_2xx_where_the_role_or_the_scope_does_not_allow_it(client, world):
    headers = world["headers"]
    others = {"coach": GW2[0], "train": "GW2", "user": "victim", "token_id": world["victim"]}
    checked = 0
    # registering first: the gateway's own coach must be new for its allowed registration
    for method, path in sorted(RULES, key=lambda r: r != ("POST", "/coaches")):
        rule = RULES[(method, path)]
        what = (method, path)
        assert send(client, headers["none"], method, path, others).status_code == 401, what
        for role in ("viewer", "operator", "admin"):
            reply = send(client, headers[role], method, path, others)
            if RANK[role] < RANK[rule.role]:
                assert reply.status_code == 403, (*what, role, reply.text)
            else:  # let in: whatever the route then says about the request itself
                assert reply.status_code not in (401, 403, 500), (*what, role, reply.text)
            checked += 1
        # a gateway: another gateway's coach, its own coach in another gateway's train (its own
        # where the route names no train), its own
        own = {**others, "coach": GW1[1], "train": "GW1"}
        for target in (others, {**own, "train": "GW2"}, own):
            reply = send(client, headers["gateway"], method, path, target)
            names_train = "{train_id}" in path or "train_id" in (
                rule.body(target) if rule.body else {}
            )
            mine = target["coach"] in GW1 and (target["train"] == "GW1" or not names_train)
            if rule.gateway and mine:
                assert reply.status_code in (200, 201), (*what, reply.text)
            else:
                assert reply.status_code == 403, (*what, target, reply.text)
            checked += 1
    assert checked == len(RULES) * 6
    # what the gateway's allowed calls did, and did not do
    viewer = headers["viewer"]
    trains = {t["id"]: t["coaches"] for t in client.get(f"{API}/trains", headers=viewer).json()}
    assert trains == {"GW1": list(GW1), "GW2": list(GW2)}


def test_a_gateway_registers_into_its_own_trains_only(client, world, settings):
    headers = world["headers"]
    gw1, viewer = headers["gateway"], headers["viewer"]
    # the other gateway's train: refused, and nothing is stored
    reply = register(client, gw1, GW1[1], "GW2")
    assert reply.status_code == 403
    assert reply.json() == {
        "detail": "train 'GW2' has coaches this gateway token is not for: a gateway registers "
        "its coaches into its own trains only (a new train id, or a train of its coaches)"
    }
    assert client.get(f"{API}/coaches/{GW1[1]}", headers=viewer).status_code == 404
    assert client.get(f"{API}/trains/GW2", headers=viewer).json()["coaches"] == list(GW2)
    # a train of its own coaches, or a new one: fine
    assert register(client, gw1, GW1[1], "GW1").status_code == 201
    assert client.get(f"{API}/trains/GW1", headers=viewer).json()["coaches"] == list(GW1)
    # an existing coach never changes train: 409 for the gateway and for every role
    for who in ("gateway", "operator", "admin"):
        reply = register(client, headers[who], GW1[1], "GW9")
        assert reply.status_code == 409, who
        assert reply.json() == {
            "detail": "coach 'GW1-B' belongs to train 'GW1'; "
            "a coach's train is fixed when it is registered"
        }
    reply = register(client, headers["admin"], GW2[0], "GW1")
    assert reply.status_code == 409
    assert client.get(f"{API}/trains/GW1", headers=viewer).json()["coaches"] == list(GW1)
    assert client.get(f"{API}/trains", headers=viewer).json()[-1]["id"] == "GW2"  # no GW9
    # an operator may add a coach to any train; the gateway then no longer registers into it
    assert register(client, headers["operator"], "SPARE-1", "GW1").status_code == 201
    db = Database(settings.database_url)
    try:
        with db.transaction() as s:
            gw3, _ = create_token(s, "gateway", "gw-3", [*GW1, "GW1-C"])
            registered = s.scalars(
                select(AuditLog.target).where(AuditLog.action == "coach.register")
            ).all()
    finally:
        db.dispose()
    assert register(client, bearer(gw3), "GW1-C", "GW1").status_code == 403
    assert sorted(registered) == sorted([*GW1, *GW2, "SPARE-1"])


@pytest.mark.parametrize("train", ["new", "existing"])
def test_concurrent_registrations_into_one_train(db_url, train):
    """Gateway 1 and gateway 2 register a coach each into one train at once — a new train, or
    one holding a coach both scopes share: the train is locked while the first registration
    checks it, so the second waits, sees the first's coach and is refused."""
    migrate(db_url)
    db = Database(db_url)
    gw1 = Principal("gw-1", "gateway", frozenset([*GW1, "SHARED-A"]))
    gw2 = Principal("gw-2", "gateway", frozenset([*GW2, "SHARED-A"]))
    outcome = {}

    def second():
        try:
            with db.transaction() as s:
                commands.register_coach(s, gw2, GW2[0], "SHARED", True)
            outcome["second"] = "registered"
        except commands.ForbiddenError:
            outcome["second"] = "refused"

    try:
        if train == "existing":
            with db.transaction() as s:
                commands.register_coach(s, gw1, "SHARED-A", "SHARED", True)
        with db.transaction() as s:
            commands.register_coach(s, gw1, GW1[0], "SHARED", True)
            thread = threading.Thread(target=second)
            thread.start()
            thread.join(0.5)
            assert thread.is_alive(), "the second registration must wait for the first"
        thread.join(30)
        assert outcome == {"second": "refused"}
        with db.transaction() as s:
            coaches = s.scalars(select(Coach.id).where(Coach.train_id == "SHARED")).all()
        assert sorted(coaches) == sorted([GW1[0], *(["SHARED-A"] if train == "existing" else [])])
    finally:
        db.dispose()
