"""The statuses on the dashboard, in a real browser (Playwright driving Debian's Chromium, with the
fixtures and helpers of ``test_dashboard``) against ``trainclimate serve`` as its own process on
SQLite, without a fleet: a live coach whose newest row says its link is down shows the
``disconnected`` badge (in words, with its reason) in the coaches list, on its page (its T_ref
marked as not applied) and in the overview's attention list, and the status filter finds it; a
coach with a deck outside the comfort band is flagged in words in the list and on its page.
"""

from __future__ import annotations

import httpx
import pytest

from helpers.processes import sqlite_server
from helpers.service import at, flat_row, flat_rows, to_wire, wait_for
from service import test_dashboard
from service.test_dashboard import Watched
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token

#: test_dashboard's fixture: Chromium, headless, for this module's tests
browser = test_dashboard.browser


@pytest.fixture(scope="module")
def server(tmp_path_factory, small_predictor_file):
    """The service without a fleet, a viewer's and an operator's token, and train S: S-A
    (activated) whose newest row (T0 + 30 min) says the link is down, once its tick at T0 + 30
    is issued; S-B (deactivated) with its up deck 0.3 K above T_rule + 1 K in its newest row."""
    srv = sqlite_server(tmp_path_factory.mktemp("dashboard-status"), small_predictor_file)
    migrate(srv.db_url)
    db = Database(srv.db_url)
    with db.transaction() as s:
        srv.tokens = {
            role: create_token(s, role, f"browser-{role}")[0] for role in ("viewer", "operator")
        }
    db.dispose()
    op = {"Authorization": f"Bearer {srv.tokens['operator']}"}
    rows = {
        "S-A": [*flat_rows(1, 29), flat_row(at(30), connected=False)],
        "S-B": [*flat_rows(1, 29), flat_row(at(30), t_room_up_c=23.3)],
    }
    for coach, coach_rows in rows.items():
        body = {"id": coach, "train_id": "S", "ddpc_active": coach == "S-A"}
        assert httpx.post(f"{srv.url}/api/v1/coaches", json=body, headers=op).status_code == 201
        body = {"coach_id": coach, "rows": [to_wire(r) for r in coach_rows]}
        reply = httpx.post(f"{srv.url}/api/v1/telemetry", json=body, headers=op)
        assert reply.status_code == 200, reply.text

    def ticked() -> bool:
        coach = httpx.get(f"{srv.url}/api/v1/coaches/S-A", headers=op).json()
        return coach["t_ref_c"] is not None

    wait_for(ticked, 30, "the tick at T0 + 30 min of S-A")
    yield srv
    srv.stop()


def test_a_lost_link_and_a_deck_outside_the_band_show_in_words(browser, server):
    w = Watched(browser, server, "viewer")
    page = w.page
    w.go("#/coaches")
    lost = page.locator("tr[data-coach='S-A']")
    lost.locator(".badge.disconnected").wait_for(timeout=20_000)
    cells = lost.locator("td")
    assert cells.nth(3).inner_text().split() == ["disconnected", "connection_lost"]
    assert "not applied: holds T_rule" in cells.nth(7).inner_text()
    warm = page.locator("tr[data-coach='S-B'] td")
    assert warm.nth(6).inner_text() == "outside +0.30 K (up)"
    assert cells.nth(6).inner_text() == "in band"
    # the status filter lists the status and finds the coach
    page.select_option("#status-filter", "disconnected")
    assert page.locator("#coaches tbody tr").count() == 1
    assert page.locator("#coaches tbody tr").first.get_attribute("data-coach") == "S-A"

    # the coach pages: the badge, T_ref not applied, the comfort flag
    w.go("#/coach/S-A")
    page.wait_for_selector("#kpi-status .badge.disconnected")
    assert page.locator("#kpi-status .badge").inner_text() == "disconnected"
    label = page.locator("#kpi-t-ref .label").inner_text()
    assert label == "T_ref issued, not applied: the HVAC holds T_rule"
    w.go("#/coach/S-B")
    page.wait_for_selector("#kpi-comfort .badge.comfort-out")
    assert page.locator("#kpi-comfort .value").inner_text() == "outside +0.30 K (up)"

    # the overview: the attention list names it in words
    w.go("#/")
    row = page.locator("#attention tr[data-coach='S-A'][data-kind='disconnected']")
    row.wait_for(timeout=20_000)
    assert "link to the HVAC lost: it holds T_rule 22.0 °C" in row.inner_text()
    assert page.locator("#by-status [data-status='disconnected']").inner_text().split() == [
        "disconnected",
        "1",
    ]
    assert w.errors == []
    w.close()
