"""The API's interactive pages in a real browser (Playwright driving Debian's Chromium, headless)
against ``trainclimate serve`` as its own process: ``/docs`` (Swagger UI) lists the routes and
``/redoc`` (ReDoc) renders them, under the service's Content Security Policy, with every file
from the service itself — any request elsewhere is refused and recorded, and none is made."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from trainclimate.service.api.hardening import CONTENT_SECURITY_POLICY

CHROMIUM = Path("/usr/bin/chromium")
if not CHROMIUM.exists():
    pytest.skip(f"no Chromium at {CHROMIUM} (.ci/run installs Debian's)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api")

ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"]


@pytest.fixture
def page(servers, tmp_path):
    """A page of a fresh browser on a server (SQLite); requests to any other origin are aborted
    and recorded in ``page.elsewhere``, console errors in ``page.errors``."""
    server = servers(f"sqlite:///{tmp_path / 'docs.db'}").start()
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
        context = browser.new_context(viewport={"width": 1366, "height": 900})
        page = context.new_page()
        page.server, page.elsewhere, page.errors = server, [], []

        def route(r):
            if r.request.url.startswith(server.url + "/"):
                r.continue_()
            else:
                page.elsewhere.append(r.request.url)
                r.abort()

        page.route("**/*", route)
        page.on("console", lambda m: m.type == "error" and page.errors.append(m.text))
        page.on("pageerror", lambda e: page.errors.append(str(e)))
        yield page
        browser.close()


def test_swagger_ui_lists_the_routes_under_the_csp(page):
    reply = httpx.get(f"{page.server.url}/docs")
    assert reply.status_code == 200
    assert reply.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
    assert "<script>" not in reply.text  # no inline script: the policy would block it
    page.goto(f"{page.server.url}/docs")
    page.wait_for_selector(".opblock-summary-path", timeout=30_000)
    paths = page.locator(".opblock-summary-path").all_inner_texts()
    schema = httpx.get(f"{page.server.url}/openapi.json").json()
    routes = {p.replace("\u200b", "") for p in paths}
    assert routes == set(schema["paths"]), routes ^ set(schema["paths"])
    assert "/api/v1/trains/{train_id}/comparison" in routes and len(routes) > 20
    assert page.locator(".information-container .title").inner_text().startswith("trainclimate")
    assert page.elsewhere == [] and page.errors == []


def test_redoc_renders_the_api_under_the_csp(page):
    page.goto(f"{page.server.url}/redoc")
    page.wait_for_selector("[data-section-id^='operation/']", timeout=30_000)
    assert page.locator("h1").first.inner_text().startswith("trainclimate")
    operations = page.locator("[data-section-id^='operation/']").count()
    schema = httpx.get(f"{page.server.url}/openapi.json").json()
    assert operations == sum(len(p) for p in schema["paths"].values())
    assert page.elsewhere == [] and page.errors == []
