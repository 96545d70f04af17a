"""``docs/api.md`` generated from the app's OpenAPI schema, so the reference cannot drift from
the code: ``python -m trainclimate.service.api.apidoc > docs/api.md`` (a test checks it is current).

Per endpoint: the role it needs (read off the route's token dependency), its description, the
parameters, the request body's fields with an example built from the schema's examples, and the
answers."""

from __future__ import annotations

import json

from fastapi import APIRouter, FastAPI
from fastapi.routing import APIRoute, iter_route_contexts

INTRO = """# HTTP API

Generated from the OpenAPI schema (`python -m trainclimate.service.api.apidoc > docs/api.md`);
a running server serves the same schema at `/openapi.json` and interactive pages at `/docs`
(Swagger UI) and `/redoc` (ReDoc), both served by the service itself.

Every path starts with `/api/v1`. Authenticate with `Authorization: Bearer <token>` (tokens from
`trainclimate token create --role viewer|operator|admin` or `POST /api/v1/tokens`); reads need
viewer, writes operator, users and models admin. A gateway token (`trainclimate token create --role
gateway --coaches 124-A,124-B`) is scoped to its coaches: it may register them, push their telemetry
and pull their setpoints, nothing else. Times are ISO 8601 with an offset (UTC in answers);
temperatures °C, power kW, energy kWh, irradiance W/m². Errors are JSON `{"detail": …}`: 401 no
valid token, 403 too low a role (or a coach or train outside a gateway token's scope), 404 no such
coach, train or record, 409 a conflict with the stored state, 413 a request body over the limit (6
MiB by default: the largest valid telemetry batch fits), 422 a malformed request or a value out of
range (with the reason), 429 too many failed authentications from the client address (with
`Retry-After`), 503 the database does not answer. Input is strict: an id in the path and a number in
the query are digits only (`/tokens/1.0` is 422), a boolean is `true` or `false` (not `"yes"` or
`0`), and a NUL character or a lone surrogate in the path, the query or a JSON string is 422. Every
write is one transaction: a request that fails changes nothing. No answer may be cached
(`Cache-Control: no-store`).

```sh
TOKEN=$(.venv/bin/trainclimate token create --role operator)
curl -s -H "Authorization: Bearer $TOKEN" http://127.0.0.1:8000/api/v1/coaches
curl -s -X POST -H "Authorization: Bearer $TOKEN" -H "Content-Type: application/json" \\
  -d '{"t_ref_c": 21.5, "duration_min": 60, "reason": "passengers report it is cold"}' \\
  http://127.0.0.1:8000/api/v1/coaches/D1-A/override
```
"""


def route_roles(router: APIRouter) -> dict[tuple[str, str], str]:
    """(method, path) → the role a route's token dependency asks for (absent: no token; the
    live feed's routes name the gateway token too); the routes of the routers ``router`` includes
    with their full paths."""
    out = {}
    for route in iter_route_contexts(router.routes):
        if not isinstance(route.original_route, APIRoute):
            continue
        stack = list(route.dependant.dependencies)
        while stack:
            dep = stack.pop()
            role = getattr(dep.call, "role", None)
            if role is not None and getattr(dep.call, "gateway", False):
                role += ", or a gateway token scoped to the coach"
            if role is not None:
                for method in route.methods:
                    out[(method, route.path)] = role
            stack.extend(dep.dependencies)
    return out


def _type(schema: dict) -> str:
    """A short type: ``string``, ``number``, ``[CoachOut]``, ``string | null`` …"""
    if "$ref" in schema:
        return schema["$ref"].rsplit("/", 1)[1]
    if "anyOf" in schema:
        return " or ".join(_type(s) for s in schema["anyOf"])
    if schema.get("type") == "array":
        return f"[{_type(schema.get('items', {}))}]"
    if "enum" in schema:
        return ", ".join(f"`{v}`" for v in schema["enum"])
    if "const" in schema:
        return f"`{schema['const']}`"
    return schema.get("type", "any") + (f" ({schema['format']})" if "format" in schema else "")


def _limits(schema: dict) -> str:
    names = {
        "minimum": "≥",
        "exclusiveMinimum": ">",
        "maximum": "≤",
        "exclusiveMaximum": "<",
        "minLength": "length ≥",
        "maxLength": "length ≤",
        "minItems": "items ≥",
        "maxItems": "items ≤",
    }
    integer = schema.get("type") == "integer"  # FastAPI writes a body's integer limits as 3.0
    parts = [
        f"{label} {int(schema[key]) if integer else schema[key]}"
        for key, label in names.items()
        if key in schema
    ]
    if "default" in schema and schema["default"] is not None:
        parts.append(f"default `{json.dumps(schema['default'])}`")
    return ", ".join(parts)


def _example(schema: dict, components: dict) -> object:
    """An example value: the schema's own example, else one built from its fields'."""
    if "$ref" in schema:
        return _example(components[schema["$ref"].rsplit("/", 1)[1]], components)
    if schema.get("examples"):
        return schema["examples"][0]
    if "default" in schema:
        return schema["default"]
    if "enum" in schema:
        return schema["enum"][0]
    if "properties" in schema:
        required = set(schema.get("required", []))
        return {
            name: _example(prop, components)
            for name, prop in schema["properties"].items()
            if name in required or prop.get("examples")
        }
    if "anyOf" in schema:
        return _example(next(s for s in schema["anyOf"] if s.get("type") != "null"), components)
    if schema.get("type") == "array":
        return [_example(schema.get("items", {}), components)]
    return {"string": "…", "number": 0.0, "integer": 0, "boolean": True}.get(schema.get("type"))


def _fields(name: str, components: dict) -> list[str]:
    schema = components[name]
    required = set(schema.get("required", []))
    lines = ["| field | type | required | notes |", "| --- | --- | --- | --- |"]
    for field, prop in schema.get("properties", {}).items():
        notes = "; ".join(x for x in (prop.get("description", ""), _limits(prop)) if x)
        mark = "yes" if field in required else ""
        lines.append(f"| `{field}` | {_type(prop)} | {mark} | {notes} |")
    return lines


def markdown(app: FastAPI, router: APIRouter) -> str:
    """The API reference of ``app`` as Markdown; the roles from ``router``'s routes."""
    spec = app.openapi()
    components = spec.get("components", {}).get("schemas", {})
    roles = route_roles(router)
    by_tag: dict[str, list[tuple[str, str, dict]]] = {}
    for path, operations in spec["paths"].items():
        for method, op in operations.items():
            by_tag.setdefault(op.get("tags", ["other"])[0], []).append((method, path, op))
    out = [INTRO]
    for tag, ops in by_tag.items():
        out.append(f"## {tag[0].upper()}{tag[1:]}\n")
        for method, path, op in ops:
            role = roles.get((method.upper(), path))
            out.append(f"### `{method.upper()} {path}`\n")
            about = " ".join(op.get("description", "").split())
            out.append(f"Role: {role or 'none (no token)'}. {about}\n")
            params = op.get("parameters", [])
            if params:
                out.append("| parameter | in | type | required | notes |")
                out.append("| --- | --- | --- | --- | --- |")
                for p in params:
                    notes = "; ".join(
                        x for x in (p.get("description", ""), _limits(p["schema"])) if x
                    )
                    mark = "yes" if p.get("required") else ""
                    out.append(
                        f"| `{p['name']}` | {p['in']} | {_type(p['schema'])} | {mark} | {notes} |"
                    )
                out.append("")
            body = op.get("requestBody", {}).get("content", {}).get("application/json")
            if body:
                name = body["schema"]["$ref"].rsplit("/", 1)[1]
                out.append(f"Body: `{name}`\n")
                out.extend(_fields(name, components))
                example = json.dumps(_example(body["schema"], components), ensure_ascii=False)
                out.append(f"\nExample: `{example}`\n")
            answers = []
            for code, reply in op.get("responses", {}).items():
                schema = reply.get("content", {}).get("application/json", {}).get("schema", {})
                what = _type(schema) if schema else reply.get("description", "")
                if code.startswith("2"):
                    answers.append(f"**{code}** {what}")
                else:
                    answers.append(code)
            out.append("Answers: " + ", ".join(answers) + ".\n")
    out.append("## Schemas\n")
    for name in sorted(components):
        if name in ("HTTPValidationError", "ValidationError"):
            continue
        doc = components[name].get("description", "").strip()
        out.append(f"### `{name}`\n")
        if doc:
            out.append(" ".join(doc.split()) + "\n")
        out.extend(_fields(name, components))
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def main() -> None:
    """Print the reference of the assembled API (what ``docs/api.md`` holds)."""
    from trainclimate.service.api import router
    from trainclimate.service.app import create_app
    from trainclimate.service.settings import Settings

    print(markdown(create_app(Settings(database_url="sqlite://")), router), end="")


if __name__ == "__main__":
    main()
