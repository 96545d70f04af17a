"""The OpenAPI document as the service answers, not only as the routes declare: FastAPI's own,
completed with the answers that the middleware (:mod:`trainclimate.service.api.hardening`) and
the exception handlers give to any operation, so that a client — or a checker such as
Schemathesis — finds every status it can meet documented with its body:

- a 422's ``detail`` is a list of validation errors (pydantic's) *or* a string (a value the
  store refuses, a NUL in the path or query);
- 400 to a JSON body that is not text (FastAPI: "There was an error parsing the body") and 413 to
  a body over the limit, on the operations taking a body;
- on the operations taking a token: 401 without a valid one, 403 to a role too low (a gateway
  token passes no role check), and 429 (``Retry-After``) to a failed authentication from a
  blocked address;
- 503 (``Retry-After``) when the database does not answer or the service is overloaded, on
  every operation but ``/health``.
"""

from __future__ import annotations

from collections.abc import Callable

from fastapi import FastAPI

MESSAGE = {"$ref": "#/components/schemas/Message"}
RETRY_AFTER = {
    "Retry-After": {
        "description": "seconds to wait before trying again",
        "schema": {"type": "integer", "minimum": 1},
    }
}
#: Status → (description, headers) added to the operations they apply to (see :func:`complete`).
ANSWERS = {
    "400": ("the body could not be read as JSON text", None),
    "401": ("no valid token", None),
    "403": ("the token's role is too low, or a gateway token is not for this", None),
    "413": ("the request body is larger than the limit", None),
    "422": ("a malformed request or a value out of range, with the reason", None),
    "429": ("too many failed authentications from this client address", RETRY_AFTER),
    "503": ("the database does not answer, or the service is overloaded", RETRY_AFTER),
}
#: The operations that answer without the database or a slot (never 503 of their own).
ALWAYS_ANSWERS = ("/api/v1/health",)


def _validation_error(schemas: dict) -> None:
    """A 422's ``detail``: pydantic's list of errors, or one sentence."""
    errors = schemas["HTTPValidationError"]["properties"]["detail"]
    schemas["HTTPValidationError"]["properties"]["detail"] = {
        "anyOf": [
            {"type": "array", "items": errors["items"]},
            {"type": "string"},
        ],
        "title": "Detail",
    }
    schemas["HTTPValidationError"]["required"] = ["detail"]


def _answer(op: dict, status: str, body: dict) -> None:
    """Document ``status`` with ``body`` on ``op`` unless the route documents it itself."""
    if status in op["responses"]:
        return
    description, headers = ANSWERS[status]
    reply = {"description": description, "content": {"application/json": {"schema": body}}}
    if headers:
        reply["headers"] = headers
    op["responses"][status] = reply


def complete(spec: dict) -> dict:
    """``spec`` (FastAPI's document) with :data:`ANSWERS` added to the operations under
    ``/api/`` they apply to, and 422 documented as above; changed in place and returned."""
    schemas = spec.setdefault("components", {}).setdefault("schemas", {})
    _validation_error(schemas)
    invalid = {"$ref": "#/components/schemas/HTTPValidationError"}
    for path, operations in spec["paths"].items():
        if not path.startswith("/api/"):
            continue
        for op in operations.values():
            _answer(op, "422", invalid)
            if "requestBody" in op:
                _answer(op, "400", MESSAGE)
                _answer(op, "413", MESSAGE)
            if op.get("security"):
                for status in ("401", "403", "429"):
                    _answer(op, status, MESSAGE)
            if path not in ALWAYS_ANSWERS:
                _answer(op, "503", MESSAGE)
    return spec


def install(app: FastAPI) -> None:
    """Serve :func:`complete` of FastAPI's document as ``app``'s (built once, at first ask)."""
    build: Callable[[], dict] = app.openapi

    def openapi() -> dict:
        if app.openapi_schema is None:
            app.openapi_schema = complete(build())
        return app.openapi_schema

    app.openapi = openapi
