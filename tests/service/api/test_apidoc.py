"""docs/api.md is the reference generated from the app's OpenAPI schema, and it is current."""

from __future__ import annotations

from pathlib import Path

from trainclimate.service import api
from trainclimate.service.api.apidoc import markdown, route_roles
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings

DOC = Path(__file__).resolve().parents[3] / "docs" / "api.md"


def test_docs_api_md_is_current():
    generated = markdown(create_app(Settings(database_url="sqlite://")), api.router)
    assert DOC.read_text() == generated, (
        "docs/api.md is stale: python -m trainclimate.service.api.apidoc > docs/api.md"
    )


def test_every_route_is_described_and_has_its_role():
    app = create_app(Settings(database_url="sqlite://"))
    roles = route_roles(api.router)
    assert roles[("GET", "/api/v1/me")] == "viewer"
    assert roles[("POST", "/api/v1/coaches/{coach_id}/override")] == "operator"
    assert roles[("POST", "/api/v1/models/{version}/activate")] == "admin"
    for path, operations in app.openapi()["paths"].items():
        for method, op in operations.items():
            assert op.get("description"), (method, path)
            if path not in ("/api/v1/health", "/api/v1/ready"):
                assert (method.upper(), path) in roles, (method, path)
    text = DOC.read_text()
    assert "Role: operator. Set T_ref for ``duration_min``" in text
    assert '"t_ref_c": 21.5' in text  # the body's example, from the schema's examples


def test_the_document_states_every_answer():
    """What the middleware and the handlers answer is documented on each operation it applies
    to, and a 422's detail may be a sentence (RefuseNul's, a value the store refuses)."""
    spec = create_app(Settings(database_url="sqlite://")).openapi()
    detail = spec["components"]["schemas"]["HTTPValidationError"]["properties"]["detail"]
    assert {"type": "string"} in detail["anyOf"]
    for path, operations in spec["paths"].items():
        for method, op in operations.items():
            answers = set(op["responses"])
            assert "422" in answers, (method, path)
            assert ("503" in answers) == (path != "/api/v1/health"), (method, path)
            if op.get("security"):
                assert {"401", "403", "429"} <= answers, (method, path)
                assert "Retry-After" in op["responses"]["429"]["headers"]
            if "requestBody" in op:
                assert {"400", "413"} <= answers, (method, path)
    assert "security" in spec["paths"]["/api/v1/me"]["get"]
    assert "requestBody" in spec["paths"]["/api/v1/telemetry"]["post"]
