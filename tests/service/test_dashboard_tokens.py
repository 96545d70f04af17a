"""The dashboard's Tokens page in a real browser (Playwright driving Debian's Chromium, with the
fixtures and helpers of ``test_dashboard``) against ``trainclimate serve`` as its own process on
SQLite, without a fleet.

An admin sees every token: a gateway token with its coaches and expiry, an expired one marked
expired, a revoked one marked revoked with who revoked it, and no Revoke for the token they are
signed in with; revoking one on the page (once confirmed) makes the API refuse it (401) and its row
say revoked; an API error is shown in the page. A viewer or an operator sees no Tokens page, and
the page never asks ``/api/v1/tokens``. Token names are shown as text, never as markup.
"""

from __future__ import annotations

import re
import time
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace
from zoneinfo import ZoneInfo

import httpx
import pytest

from helpers.processes import sqlite_server
from service import test_dashboard
from service.test_dashboard import Watched
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token

#: test_dashboard's fixture: Chromium, headless, for this module's tests
browser = test_dashboard.browser

MARKUP_NAME = "<img src=x onerror=alert(1)>"
#: A time as the page shows it: Zurich time to the minute.
MINUTE = r"\d{4}-\d{2}-\d{2} \d{2}:\d{2}"


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture(scope="module")
def server(tmp_path_factory, small_predictor_file):
    """The service without a fleet. ``tokens``: a viewer's, an operator's and an admin's
    (``browser-ROLE``), and ``other_admin``: a second admin's (``admin-two``), from the store.
    ``short-lived`` (1 s: shorter than the API issues, so from the store too). Issued by the
    admin through the API, each user with one token: ``gateways-124`` (coaches 124-A and 124-B,
    30 days), ``old-kiosk`` (then revoked by the admin), ``lost-laptop`` and one named like
    markup. ``ids``: each user's token id; ``issued``: the ``POST /tokens`` replies by user (the
    short-lived one's token and expiry)."""
    srv = sqlite_server(tmp_path_factory.mktemp("dashboard-tokens"), small_predictor_file)
    migrate(srv.db_url)
    db = Database(srv.db_url)
    with db.transaction() as s:
        roles = ("viewer", "operator", "admin")
        srv.tokens = {role: create_token(s, role, f"browser-{role}")[0] for role in roles}
        srv.other_admin = create_token(s, "admin", "admin-two")[0]
        short_until = datetime.now(UTC) + timedelta(seconds=1)
        short = create_token(s, "viewer", "short-lived", expires_at=short_until)[0]
    db.dispose()
    admin = bearer(srv.tokens["admin"])
    srv.issued = {"short-lived": {"token": short, "expires_at": short_until.isoformat()}}
    for body in (
        {
            "role": "gateway",
            "name": "gateways-124",
            "coaches": ["124-A", "124-B"],
            "expires_in_days": 30,
        },
        {"role": "viewer", "name": "old-kiosk"},
        {"role": "viewer", "name": "lost-laptop"},
        {"role": "viewer", "name": MARKUP_NAME},
    ):
        reply = httpx.post(f"{srv.url}/api/v1/tokens", json=body, headers=admin)
        assert reply.status_code == 201, reply.text
        srv.issued[body["name"]] = reply.json()
    listed = httpx.get(f"{srv.url}/api/v1/tokens", headers=admin).json()
    srv.ids = {row["user"]: row["id"] for row in listed}
    revoked = httpx.delete(f"{srv.url}/api/v1/tokens/{srv.ids['old-kiosk']}", headers=admin)
    assert revoked.status_code == 200, revoked.text
    yield srv
    srv.stop()


def open_tokens(w: Watched) -> None:
    """The Tokens page, drawn."""
    w.go("#/tokens")
    w.page.wait_for_selector("#tokens tbody tr[data-token]")


def cells(w: Watched, token_id: int) -> list[str]:
    """The texts of a token's row: name, token, role, coaches, created, expires, revoked, status,
    action."""
    return w.page.locator(f"#tokens tr[data-token='{token_id}'] td").all_inner_texts()


def zurich_minute(iso: str) -> str:
    """An API time as the page shows it."""
    return (
        datetime.fromisoformat(iso).astimezone(ZoneInfo("Europe/Zurich")).strftime("%Y-%m-%d %H:%M")
    )


def answer(accept: bool, questions: list[str]):
    """A dialog handler: note the question, then accept or dismiss."""

    def handle(dialog) -> None:
        questions.append(dialog.message)
        if accept:
            dialog.accept()
        else:
            dialog.dismiss()

    return handle


def test_admin_sees_scope_expiry_and_state_of_every_token(browser, server):
    # the 1-second token has expired (the API refuses it)
    expires = datetime.fromisoformat(server.issued["short-lived"]["expires_at"])
    time.sleep(max(0.0, (expires - datetime.now(UTC)).total_seconds()))
    expired = bearer(server.issued["short-lived"]["token"])
    assert httpx.get(f"{server.url}/api/v1/me", headers=expired).status_code == 401
    w = Watched(browser, server, "admin")
    assert w.page.locator("[data-nav='tokens']").is_visible()
    w.page.click("[data-nav='tokens']")
    w.page.wait_for_selector("#tokens tbody tr[data-token]")
    names = w.page.locator("#tokens tbody tr td:first-child").all_inner_texts()
    assert set(names) >= set(server.ids), names

    gateway = cells(w, server.ids["gateways-124"])
    issued = server.issued["gateways-124"]
    assert gateway[:4] == ["gateways-124", issued["token"][:10] + "…", "gateway", "124-A, 124-B"]
    assert re.fullmatch(MINUTE, gateway[4]), gateway
    assert gateway[5] == zurich_minute(issued["expires_at"])  # 30 days on
    assert gateway[6:9] == ["–", "active", "Revoke"]

    short = cells(w, server.ids["short-lived"])
    assert re.fullmatch(f"{MINUTE} \\(expired\\)", short[5]), short
    assert short[3] == "–" and short[6:9] == ["–", "expired", ""]

    kiosk = cells(w, server.ids["old-kiosk"])
    assert re.fullmatch(f"{MINUTE} by browser-admin", kiosk[6]), kiosk
    assert kiosk[5] == "never" and kiosk[7:9] == ["revoked", ""]

    # the token this page is signed in with: no Revoke, said why
    mine = cells(w, server.ids["browser-admin"])
    assert mine[2] == "admin" and mine[7:9] == ["active", "your session"]
    assert w.page.locator(f"tr[data-token='{server.ids['browser-admin']}'] button").count() == 0
    assert w.page.locator("#tokens-error").inner_text() == ""
    assert w.errors == []
    w.close()


def test_revoking_a_token_on_the_page_makes_the_api_refuse_it(browser, server):
    victim = bearer(server.issued["lost-laptop"]["token"])
    assert httpx.get(f"{server.url}/api/v1/me", headers=victim).status_code == 200
    w = Watched(browser, server, "admin")
    open_tokens(w)
    page = w.page
    row = f"#tokens tr[data-token='{server.ids['lost-laptop']}']"
    deletes: list[str] = []
    page.on("request", lambda r: r.method == "DELETE" and deletes.append(r.url))

    # dismissing the confirmation changes nothing
    questions: list[str] = []
    page.once("dialog", answer(False, questions))
    page.click(f"{row} button:has-text('Revoke')")
    assert "lost-laptop" in questions[0] and "cannot be undone" in questions[0]
    assert page.locator(f"{row}[data-status='active']").count() == 1
    assert httpx.get(f"{server.url}/api/v1/me", headers=victim).status_code == 200

    # confirmed: DELETE /tokens/{id}, the table reloaded, the token refused from then on
    page.once("dialog", answer(True, questions))
    with page.expect_response(lambda r: r.request.method == "DELETE" and r.ok):
        page.click(f"{row} button:has-text('Revoke')")
    page.wait_for_selector(f"{row}[data-status='revoked']")
    assert deletes == [f"{server.url}/api/v1/tokens/{server.ids['lost-laptop']}"]
    assert re.fullmatch(f"{MINUTE} by browser-admin", cells(w, server.ids["lost-laptop"])[6])
    assert page.locator(f"{row} button").count() == 0
    assert httpx.get(f"{server.url}/api/v1/me", headers=victim).status_code == 401
    assert page.locator("#tokens-error").inner_text() == ""
    assert w.errors == []
    w.close()


def test_an_api_error_is_shown_in_the_page(browser, server):
    """The signed-in admin loses the role (another admin makes the user a viewer) while the page
    is open: revoking answers 403, and the page says so; nothing is revoked."""
    signed_in = SimpleNamespace(url=server.url, tokens={"admin": server.other_admin})
    w = Watched(browser, signed_in, "admin")
    open_tokens(w)
    demote = {"role": "viewer", "reason": "a test"}
    admin = bearer(server.tokens["admin"])
    reply = httpx.put(f"{server.url}/api/v1/users/admin-two/role", json=demote, headers=admin)
    assert reply.status_code == 200, reply.text
    row = f"#tokens tr[data-token='{server.ids['gateways-124']}']"
    w.page.once("dialog", answer(True, []))
    w.page.click(f"{row} button:has-text('Revoke')")
    error = w.page.wait_for_selector("#tokens-error:has-text('failed')").inner_text()
    said = "this needs the admin role; the token is viewer"  # the API's detail
    assert re.fullmatch(f"Revoking tc_\\S+… of gateways-124 failed: {said}", error), error
    assert w.page.locator(f"{row}[data-status='active']").count() == 1
    listed = httpx.get(f"{server.url}/api/v1/tokens", headers=admin).json()
    assert [t["revoked_at"] for t in listed if t["user"] == "gateways-124"] == [None]
    # the browser logs the refused request itself; nothing else went wrong
    assert len(w.errors) == 1 and "status of 403" in w.errors[0], w.errors
    w.close()


def test_token_names_are_shown_as_text(browser, server):
    w = Watched(browser, server, "admin")
    dialogs: list[str] = []
    w.page.on("dialog", answer(False, dialogs))
    open_tokens(w)
    assert cells(w, server.ids[MARKUP_NAME])[0] == MARKUP_NAME
    assert w.page.locator("#tokens img").count() == 0
    assert dialogs == [] and w.errors == []
    w.close()


@pytest.mark.parametrize("role", ["viewer", "operator"])
def test_no_tokens_page_below_admin(browser, server, role):
    w = Watched(browser, server, role)
    page = w.page
    fetches = "performance.getEntriesByType('resource').map((e) => e.name)"
    page.wait_for_selector("#fleet-kpis .kpi")
    page.wait_for_load_state("networkidle")
    # what the page fetched while signing in, and every request from here on
    asked: list[str] = page.evaluate(fetches)
    assert any(u.endswith("/api/v1/me") for u in asked), asked
    page.on("request", lambda r: asked.append(r.url))
    assert page.locator("[data-nav='tokens']").count() == 1  # in the page, not shown
    assert not page.locator("[data-nav='tokens']").is_visible()
    # asked for directly, also on a fresh load: the overview instead (it never asks /tokens)
    w.go("#/tokens")
    page.reload()
    page.wait_for_selector(f"#who:has-text('({role})')")
    page.wait_for_load_state("networkidle")
    assert page.locator("#tokens").count() == 0
    assert page.locator("#fleet-kpis").count() == 1
    assert [u for u in asked if "/api/v1/tokens" in u] == []
    assert w.errors == []
    w.close()
