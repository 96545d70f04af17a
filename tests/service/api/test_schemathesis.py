"""schemathesis over the app's OpenAPI schema, in-process (ASGI), on SQLite and PostgreSQL, as an
admin, an operator and a gateway (scoped to the registered coaches): for every operation, valid
and invalid requests (positive and negative generation) on random ids and on ids that exist (a
registered pair of coaches with telemetry, ticks issued by the live loop, an override, the model,
a token), each answer checked by all of schemathesis's checks (no 5xx, status code, content type,
headers and body as the schema documents them, invalid input refused, authentication enforced, …)
but one: ``positive_data_acceptance``, which expects every request the schema allows to succeed,
while the API refuses with 422 what the schema cannot say — a range before 1970, telemetry
before 2000, coaches with a role other than gateway, a train that is not a pair — and with 404
what does not exist. Hypothesis runs derandomized, so a run is repeatable.

:data:`MAX_EXAMPLES` generated cases per operation keep the six runs within a couple of minutes;
``TRAINCLIMATE_SCHEMATHESIS_EXAMPLES=500`` (say) runs the long version."""

from __future__ import annotations

import os
import re
from datetime import UTC, datetime, timedelta

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.core.failures import FailureGroup
from schemathesis.python import asgi
from schemathesis.specs.openapi.checks import positive_data_acceptance
from sqlalchemy import delete

from trainclimate.service.app import create_app
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import TrainPlan
from trainclimate.service.store.tokens import create_token

#: Generated cases per operation and role (and three of the schema's examples).
MAX_EXAMPLES = int(os.environ.get("TRAINCLIMATE_SCHEMATHESIS_EXAMPLES", "5"))
#: The registered pair, the scope of the gateway's token.
PAIR = ("124-A", "124-B")
START = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
MINUTES = 40


def telemetry(minutes: int, active: bool) -> list[dict]:
    return [
        {
            "time": (START + timedelta(minutes=i + 1)).isoformat(),
            "t_room_c": [21.2, 21.0, 20.8],
            "t_ref_c": 21.5 if active else 22.0,
            "t_rule_c": 22.0,
            "t_amb_c": 1.5,
            "ghi_w_m2": 50.0,
            "q_gt_w_m2": 20.0,
            "q_gs_w_m2": 10.0,
            "occupancy_pct": 0.0,
            "speed_kmh": 0.0,
            "power_kw": 9.0 if active else 9.5,
        }
        for i in range(minutes)
    ]


@pytest.fixture(params=["admin", "operator", "gateway"])
def api(settings, request):
    """The app started by schemathesis (which loads the schema through it), with state; the
    role's headers and the ids that exist. The lifespan is stopped after the test. The throttle
    is set out of reach: the checks send wrong tokens on purpose (``test_hardening.py`` tests
    it)."""
    role = request.param
    app = create_app(settings.model_copy(update={"auth_failures_burst": 1_000_000}))
    try:
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        db = Database(settings.database_url)
        with db.transaction() as s:
            admin, _ = create_token(s, "admin", "schemathesis-admin")
            mine, _ = create_token(
                s, role, "schemathesis", list(PAIR) if role == "gateway" else None
            )
            create_token(s, "viewer", "a-victim")  # a token the fuzzer may revoke
        db.dispose()
        headers = {"Authorization": f"Bearer {admin}"}
        with asgi.get_client(app) as client:

            def post(path: str, body: dict, status: int = 200) -> dict:
                reply = client.post(f"http://{asgi.HOST}/api/v1{path}", json=body, headers=headers)
                assert reply.status_code == status, reply.text
                return reply.json()

            for cid, active in (("124-A", True), ("124-B", False)):
                post("/coaches", {"id": cid, "train_id": "124", "ddpc_active": active}, 201)
                reply = post("/telemetry", {"coach_id": cid, "rows": telemetry(MINUTES, active)})
                assert reply["stored"] == MINUTES
            override = {"t_ref_c": 21.0, "duration_min": 60, "reason": "a test"}
            post("/coaches/124-A/override", override, 201)
            tokens = client.get(f"http://{asgi.HOST}/api/v1/tokens", headers=headers).json()
        ids = {
            "coach_id": "124-A",
            "train_id": "124",
            "version": 1,
            "token_id": next(t["id"] for t in tokens if t["user"] == "a-victim"),
            "name": "a-victim",
        }
        own_ids = [t["id"] for t in tokens if t["user"].startswith("schemathesis")]

        def restore() -> None:
            """The pair as it was: 124-A activated, 124-B not, and no trial plan (the fuzzer
            switches the coaches and sets plans; a plan in force would refuse the switch)."""
            db = Database(settings.database_url)
            with db.transaction() as s:
                s.execute(delete(TrainPlan).where(TrainPlan.train_id == "124"))
            db.dispose()
            with asgi.get_client(app) as client:
                for cid, active in (("124-A", True), ("124-B", False)):
                    url = f"http://{asgi.HOST}/api/v1/coaches/{cid}/controller"
                    body = {"active": active, "reason": "restore the pair"}
                    assert client.put(url, json=body, headers=headers).status_code == 200

        yield schema, {"Authorization": f"Bearer {mine}"}, ids, own_ids, restore
    finally:
        asgi.shutdown_lifespans()


def existing_coach(case):
    if isinstance(case.body, dict) and "coach_id" in case.body:
        case.body["coach_id"] = "124-A"
    return case


def fuzz(strategy, max_examples: int, headers: dict, ids: dict, own_ids: list[int]) -> None:
    """Send ``max_examples`` cases of ``strategy``; fail on any check's failure."""

    @given(case=strategy)
    @settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
        phases=[Phase.explicit, Phase.generate, Phase.shrink],
    )
    def run(case):
        path = case.path_parameters or {}
        if str(path.get("token_id")) in {str(i) for i in own_ids}:
            path["token_id"] = ids["token_id"]  # keep the fuzzer's own tokens
        if str(path.get("name")).startswith("schemath"):
            path["name"] = ids["name"]  # … and their roles
        case.call_and_validate(headers=headers, excluded_checks=[positive_data_acceptance])

    run()


def test_every_check_passes(api):
    schema, headers, ids, own_ids, restore = api
    failures = []
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 20
    for operation in operations:
        names = re.findall(r"{(\w+)}", operation.path)
        known = {name: ids[name] for name in names}
        modes = (GenerationMode.POSITIVE, GenerationMode.NEGATIVE)
        random = st.one_of(
            *(operation.as_strategy(mode) for mode in modes),
            *(operation.as_strategy(mode, path_parameters=known) for mode in modes if known),
            # bodies naming a coach (telemetry) about an existing one
            operation.as_strategy(GenerationMode.POSITIVE).map(existing_coach),
        )
        examples = schema.get_strategies_from_examples(operation, path_parameters=known)
        restore()
        try:
            fuzz(random, MAX_EXAMPLES, headers, ids, own_ids)
            if examples:  # the schema's examples, on the existing ids
                fuzz(st.one_of(examples), 3, headers, ids, own_ids)
        except (Exception, FailureGroup) as exc:
            failures.append(f"{operation.label}: {type(exc).__name__}: {exc}")
    assert not failures, "\n\n".join(failures)


OUT_OF_RANGE = [
    ("delete", "/api/v1/tokens/2147483648"),
    ("delete", "/api/v1/tokens/-2147483649"),
    ("delete", "/api/v1/tokens/99999999999999999999999"),
    ("post", "/api/v1/models/2147483648/activate?reason=x"),
    ("get", "/api/v1/audit?offset=9223372036854775808"),
]


def test_ids_beyond_the_columns_are_refused(client, tokens):
    """What schemathesis found on PostgreSQL: an id beyond the 32-bit columns was a 500."""
    for method, path in OUT_OF_RANGE:
        reply = client.request(method, path, headers=tokens["admin"])
        assert reply.status_code == 422, (path, reply.text)
