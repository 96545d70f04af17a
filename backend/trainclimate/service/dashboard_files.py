"""How the dashboard's files are served: Plotly.js (:func:`plotly_js`: the basic bundle, scatter
and bar, when npm installed it, else the plotly Python package's full one), and ``index.html``
with versioned URLs for its script, style and Plotly.js (``?v=`` a hash of the file's content),
so that those can
be kept by the browser for a year (``Cache-Control: public, max-age=31536000, immutable``) while
``index.html`` and anything unversioned is revalidated on every load (``no-cache``: a 304 when
unchanged, through the ETag StaticFiles sends). The API's own ``Cache-Control: no-store`` is
set by :class:`.api.hardening.SecurityHeaders` and left alone here.
"""

from __future__ import annotations

import hashlib
from functools import cache
from pathlib import Path

import plotly
from starlette.datastructures import MutableHeaders
from starlette.responses import HTMLResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: A year, the longest a versioned file is kept. [s]
IMMUTABLE = "public, max-age=31536000, immutable"
#: Unversioned files: kept, but asked again (a conditional request) before each use.
REVALIDATE = "no-cache"
#: The files index.html names that are given a version, as index.html names them (relative to
#: the frontend directory; ``vendor/plotly.min.js`` is :func:`plotly_js`).
VERSIONED = ("app.js", "style.css", "favicon.svg", "vendor/plotly.min.js")
#: Plotly.js as the plotly Python package ships it: every trace type (4.8 MB, 1.47 MB gzipped).
PLOTLY_FULL = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
#: The basic bundle (scatter, bar, pie: what the charts use; 1.2 MB, 0.39 MB gzipped), from
#: npm (``npm ci --prefix npm``, as ``make install`` runs it), beside the frontend directory.
PLOTLY_BASIC = Path("npm") / "node_modules" / "plotly.js-basic-dist-min" / "plotly-basic.min.js"


def plotly_js(frontend_dir: Path) -> Path:
    """The Plotly.js the dashboard loads: :data:`PLOTLY_BASIC` beside ``frontend_dir`` (the
    checkout's, which the package's ``resources/frontend`` links to) when installed, else
    :data:`PLOTLY_FULL`."""
    basic = frontend_dir.resolve().parent / PLOTLY_BASIC
    return basic if basic.exists() else PLOTLY_FULL


def content_version(path: Path) -> str:
    """The first 12 hex digits of the SHA-256 of the file at ``path``."""
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


@cache
def _index(frontend_dir: Path, mtime_ns: int) -> str:
    text = (frontend_dir / "index.html").read_text(encoding="utf-8")
    for name in VERSIONED:
        path = plotly_js(frontend_dir) if name.startswith("vendor/") else frontend_dir / name
        version = content_version(path)
        text = text.replace(f'"{name}"', f'"{name}?v={version}"')
    return text


def index_html(frontend_dir: Path) -> str:
    """``index.html`` with ``?v=…`` on the files of :data:`VERSIONED` (remade when it
    changes)."""
    index = frontend_dir / "index.html"
    return _index(frontend_dir, index.stat().st_mtime_ns)


def index_response(frontend_dir: Path) -> HTMLResponse:
    """The dashboard's page (:func:`index_html`)."""
    return HTMLResponse(index_html(frontend_dir))


class DashboardCaching:
    """``Cache-Control`` on the dashboard's files (every path outside ``/api/`` and the docs'
    pages): :data:`IMMUTABLE` for a request with ``?v=`` (a versioned URL), else
    :data:`REVALIDATE`. A header the app set itself is kept."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "") if scope["type"] == "http" else ""
        if scope["type"] != "http" or path.startswith("/api/"):
            await self.app(scope, receive, send)
            return
        versioned = b"v=" in scope.get("query_string", b"")

        async def send_with_caching(message: Message) -> None:
            if message["type"] == "http.response.start" and message.get("status", 200) < 400:
                headers = MutableHeaders(scope=message)
                if "cache-control" not in headers:
                    headers["Cache-Control"] = IMMUTABLE if versioned else REVALIDATE
            await send(message)

        await self.app(scope, receive, send_with_caching)
