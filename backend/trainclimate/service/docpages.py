"""The API's interactive pages, ``/docs`` (Swagger UI) and ``/redoc`` (ReDoc), served with their
scripts and styles from the service itself.

FastAPI's own pages load Swagger UI and ReDoc from a CDN and start Swagger UI with an inline
script: under the service's Content Security Policy (``script-src 'self'``,
:mod:`trainclimate.service.api.hardening`) both stay blank, and without a network they would too.
Here the files come from the installed ``fastapi-offline`` package (Swagger UI 5 and ReDoc 2, as
it ships them) under :data:`ASSETS`, and Swagger UI is started by a script of the same origin,
:data:`SWAGGER_INIT`. ReDoc runs without its search box (its index is built in a ``blob:``
worker, which the policy blocks) and shows the service's icon where it would load its maker's
logo from cdn.redoc.ly (:data:`REDOC_LOGO`): nothing is fetched, or tried, elsewhere.
"""

from __future__ import annotations

import json
from pathlib import Path

import fastapi_offline
from fastapi import FastAPI, HTTPException
from fastapi.responses import FileResponse, HTMLResponse, Response

#: Where the pages' files are served.
ASSETS = "/docs-assets"
#: The files of the installed fastapi-offline package, by name, with their media types.
FILES = {
    "swagger-ui-bundle.js": "text/javascript",
    "swagger-ui.css": "text/css",
    "favicon.png": "image/png",
}
#: The one remote file ReDoc's bundle would load (the logo beside "API docs by Redocly").
REDOC_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"
STATIC = Path(fastapi_offline.__file__).parent / "static"
#: Starts Swagger UI on ``#swagger-ui`` with the schema at ``{openapi_url}``; no validator badge
#: (it would send the schema to validator.swagger.io).
SWAGGER_INIT = """window.ui = SwaggerUIBundle({{
  url: {openapi_url},
  dom_id: "#swagger-ui",
  layout: "BaseLayout",
  deepLinking: true,
  validatorUrl: null,
  presets: [SwaggerUIBundle.presets.apis],
}});
"""
SWAGGER_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<link rel="icon" href="{assets}/favicon.png">
<link rel="stylesheet" href="{assets}/swagger-ui.css">
</head>
<body>
<div id="swagger-ui"></div>
<script src="{assets}/swagger-ui-bundle.js"></script>
<script src="{assets}/swagger-init.js"></script>
</body>
</html>
"""
REDOC_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<link rel="icon" href="{assets}/favicon.png">
<style>body {{ margin: 0; padding: 0; }}</style>
</head>
<body>
<redoc spec-url="{openapi_url}" disable-search></redoc>
<script src="{assets}/redoc.standalone.js"></script>
</body>
</html>
"""


def install(app: FastAPI) -> None:
    """Serve ``/docs``, ``/redoc`` and their files (:data:`ASSETS`) from ``app``, whose own
    pages must be off (``docs_url=None, redoc_url=None``); none is in the schema."""
    init = SWAGGER_INIT.format(openapi_url=json.dumps(app.openapi_url))
    swagger = SWAGGER_PAGE.format(title=f"{app.title} – API (Swagger UI)", assets=ASSETS)
    redoc = REDOC_PAGE.format(
        title=f"{app.title} – API (ReDoc)", assets=ASSETS, openapi_url=app.openapi_url
    )
    redoc_js = (STATIC / "redoc.standalone.js").read_text(encoding="utf-8")
    redoc_js = redoc_js.replace(REDOC_LOGO, f"{ASSETS}/favicon.png")

    def asset(name: str) -> Response:
        if name == "swagger-init.js":
            return Response(init, media_type="text/javascript")
        if name == "redoc.standalone.js":
            return Response(redoc_js, media_type="text/javascript")
        if name not in FILES:
            raise HTTPException(404, f"no file {name!r}")
        return FileResponse(STATIC / name, media_type=FILES[name])

    app.add_api_route("/docs", lambda: HTMLResponse(swagger), include_in_schema=False)
    app.add_api_route("/redoc", lambda: HTMLResponse(redoc), include_in_schema=False)
    app.add_api_route(f"{ASSETS}/{{name}}", asset, include_in_schema=False)
