"""The dashboard in a real browser: Playwright driving Debian's Chromium (headless) against
``trainclimate serve --fleet demo`` running as its own process on SQLite.

Pages load without console errors and their charts have data: the fleet overview (the first
screen: fleet savings, per-train bars that click through to the pair, attention, model health),
the coaches, the pair, the coach, the model's health; a viewer sees no write controls;
an operator's override is applied (the next tick issues it) and audited, an invalid one shows the
API's message, and cancelling ends it; the pair view shows a train's trial plan, and an
operator's change of it is pending until the next service day.
On a seeded fleet (``trainclimate serve`` without the demo):
while every window waits for the model the savings read "no comparable windows yet", never
0.0 %; a train on a crossover plan shows its savings with their 95 % interval (error bars, the
estimate in words, the days to ±2 points, the excluded minutes by reason, the windows shaded by
the coach under the layer), one on a fixed plan why it has none (a hatched bar). With
``TRAINCLIMATE_SCREENSHOT_DIR`` set, the screenshots of the operator guide are written there
(``docs/img``).
"""

from __future__ import annotations

import os
import re
from datetime import datetime
from pathlib import Path
from types import SimpleNamespace
from zoneinfo import ZoneInfo

import httpx
import pytest

from helpers.processes import (
    Server,
    child_env,
    demo_server,
    free_port,
    serve_args,
    sqlite_server,
    wait_for_ddpc,
)
from helpers.service import decided, flat_rows, post_rows, register, wait_for
from trainclimate.service.adapters import demo
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token

CHROMIUM = Path("/usr/bin/chromium")


def natural(text: str) -> list:
    """A sort key: the digits in ``text`` by value ("D2" before "D10")."""
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text)]


if not CHROMIUM.exists():
    pytest.skip(f"no Chromium at {CHROMIUM} (.ci/run installs Debian's)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api")

ZURICH = ZoneInfo("Europe/Zurich")
LAPTOP = {"width": 1366, "height": 768}
WALL = {"width": 1920, "height": 1080}
#: Chromium flags for a headless run in a container without a session bus or GPU.
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"]


@pytest.fixture(scope="module")
def server(tmp_path_factory, small_predictor_file):
    """The demo fleet at 600× on SQLite (a 5-min tick every 0.5 s), with a viewer and an
    operator token; running until its activated coaches have a completed prediction (the layer's
    first hour) and 20 DDPC setpoints."""
    # as `make demo` runs it: the operator token and the dashboard's URL printed at start
    srv = demo_server(
        tmp_path_factory.mktemp("dashboard"), small_predictor_file, "--new-token", "operator"
    )
    printed = srv.printed(r"dashboard: (\S+)\noperator token: (tc_\S+)")
    assert printed.group(1) == f"{srv.url}/#token={printed.group(2)}", srv.output()
    srv.signin_url = printed.group(1)
    migrate(srv.db_url)
    db = Database(srv.db_url)
    with db.transaction() as s:
        srv.tokens = {"viewer": create_token(s, "viewer", "browser-viewer")[0]}
    db.dispose()
    srv.tokens["operator"] = printed.group(2)
    wait_for_ddpc(srv, srv.tokens["viewer"])
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
        yield b
        b.close()


class Watched:
    """A page with its console errors and uncaught exceptions collected, signed in as ``role``
    (``context`` more options of the browser context)."""

    def __init__(self, browser, server: Server, role: str, viewport=LAPTOP, **context):
        self.context = browser.new_context(viewport=viewport, **context)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.page.on("console", lambda m: m.type == "error" and self.errors.append(m.text))
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.server = server
        self.page.goto(server.url + "/")
        self.page.fill("#token", server.tokens[role])
        self.page.click("#signin-form button[type=submit]")
        self.page.wait_for_selector(f"#who:has-text('({role})')")

    def go(self, hash_: str) -> None:
        self.page.goto(f"{self.server.url}/{hash_}")

    def traces(self, figure: str) -> list[dict]:
        """The figure's traces with how many finite points each has."""
        return self.page.evaluate(
            """(sel) => (document.querySelector(sel).data || []).map((t) => ({
                name: t.name, type: t.type || 'scatter',
                points: (t.y || []).filter((v) => v !== null && Number.isFinite(v)).length }))""",
            figure,
        )

    def shot(self, name: str) -> None:
        out = os.environ.get("TRAINCLIMATE_SCREENSHOT_DIR")
        if out:
            Path(out).mkdir(parents=True, exist_ok=True)
            self.page.screenshot(path=str(Path(out) / f"{name}.png"), full_page=True)

    def close(self) -> None:
        self.context.close()


def test_the_overview_answers_with_fleet_figures_and_clicks_through(browser, server):
    w = Watched(browser, server, "viewer", WALL)
    page = w.page
    # the first screen: the overview with its charts, no table
    page.wait_for_function(
        "() => (document.querySelector('#savings-figure') || {}).data", timeout=20_000
    )
    assert page.locator("#coaches").count() == 0
    w.shot("dashboard-overview")
    # another window: the API is asked for it, and the tiles show what it answered
    with page.expect_response(lambda r: "/fleet/summary?hours=6" in r.url and r.ok) as info:
        page.select_option("#hours", "6")
    summary = info.value.json()
    # the headline figure (its interval beside it, or why it has none), never 0.0 % for a fleet
    # in which nothing counted
    expected = "no comparable windows yet"
    if summary["counted_windows"] and summary["savings_pct"] is not None:
        expected = f"{summary['savings_pct']:.1f} %"
    page.wait_for_function(
        "(v) => document.querySelector('#kpi-fleet-savings .value .main').textContent === v",
        arg=expected,
    )
    # the demo's coaches split the floor heating off: the headline is the HVAC units' meter,
    # and the tile says so, the whole coach's beside it
    assert summary["meter"] == "hvac"
    label = page.locator("#kpi-fleet-savings .label").inner_text()
    assert label == "Fleet energy savings (HVAC units)"
    other = page.locator("#kpi-fleet-savings-other-meter .label").inner_text()
    assert other == "… HVAC + floor heating"
    assert page.locator("#kpi-trains .value").inner_text() == str(len(demo.TRAINS))
    energy = {t["name"]: t["points"] for t in w.traces("#energy-figure")}
    assert energy["activated coaches"] == energy["deactivated coaches"] == len(summary["windows"])
    assert len(summary["windows"]) >= 2
    # a bar per train, solid with a 95 % interval, hatched without; none where its deactivated
    # coach used no energy (HVAC off) yet
    bars = w.traces("#savings-figure")
    assert [b["name"] for b in bars] == [
        "with a 95 % interval (error bars)",
        "no interval (confounded or too few days)",
    ]
    with_savings = [t for t in summary["trains"] if t["savings_pct"] is not None]
    assert {b["type"] for b in bars} == {"bar"}
    assert sum(b["points"] for b in bars) == len(with_savings) >= 1
    x = page.evaluate("() => document.querySelector('#savings-figure').data[0].x")
    assert len(x) == len(demo.TRAINS)
    assert {t["name"] for t in w.traces("#violation-figure")} == {"activated", "deactivated"}
    assert page.locator("#savings-figure .main-svg").count() > 0  # drawn, not only data
    # sorted by savings, largest first; by train on request
    order = page.evaluate("() => document.querySelector('#savings-figure').data[0].x")
    by_savings = sorted(summary["trains"], key=lambda t: -(t["savings_pct"] or -1e9))
    assert order == [t["id"] for t in by_savings]
    page.select_option("#train-sort", "id")
    order = page.evaluate("() => document.querySelector('#savings-figure').data[0].x")
    assert order == sorted(order, key=natural)  # D2 before D10
    # statuses as the API counts them; the attention list links to the coaches
    for status, n in summary["coaches_by_status"].items():
        cell = page.locator(f"#by-status [data-status='{status}']")
        assert cell.inner_text().split() == [status, str(n)]
    model = page.locator("#kpi-model .value").inner_text()
    assert model.endswith("(bound 0.25 K)"), model
    # a bar opens its train's pair comparison
    # (a real click where the bar is drawn: Plotly's drag layer over it takes the mouse)
    page.locator("#savings-figure").scroll_into_view_if_needed()
    paths = page.locator("#savings-figure .bars .point path")
    boxes = [paths.nth(i).bounding_box() for i in range(paths.count())]
    box = next(b for b in boxes if b and b["height"] > 0)  # a bar drawn (not a null's)
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_timeout(300)  # Plotly's hover (throttled) finds the bar the click then opens
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_url(re.compile(r".*#/train/D\d+$"))
    page.wait_for_selector("#pair-figure .main-svg", timeout=20_000)
    assert w.errors == []
    w.close()


def test_the_attention_list_names_an_overridden_coach(browser, server):
    headers = {"Authorization": f"Bearer {server.tokens['operator']}"}
    body = {"t_ref_c": 21.5, "duration_min": 600, "reason": "attention list check"}
    reply = httpx.post(f"{server.url}/api/v1/coaches/D7-A/override", json=body, headers=headers)
    assert reply.status_code == 201, reply.text
    try:
        w = Watched(browser, server, "viewer")
        row = w.page.locator("#attention tr[data-coach='D7-A'][data-kind='override']")
        row.wait_for(timeout=20_000)
        assert "operator's setpoint until" in row.inner_text()
        row.locator("a").click()
        w.page.wait_for_selector("#coach-title:has-text('Coach D7-A')")
        assert w.errors == []
        w.close()
    finally:
        reason = "attention list check done"
        httpx.delete(
            f"{server.url}/api/v1/coaches/D7-A/override", params={"reason": reason}, headers=headers
        )


def test_the_model_page_draws_the_error_per_step_against_the_bound(browser, server):
    w = Watched(browser, server, "viewer")
    w.go("#/model")
    page = w.page
    page.wait_for_function(
        "() => (document.querySelector('#mae-figure') || {}).data", timeout=20_000
    )
    with page.expect_response(lambda r: "/health?hours=6" in r.url and r.ok) as info:
        page.select_option("#model-hours", "6")
    health = info.value.json()
    assert health["samples"] > 0
    page.wait_for_function(
        "(n) => document.querySelector('#kpi-samples .value').textContent === n",
        arg=str(health["samples"]),
    )
    traces = {t["name"]: t["points"] for t in w.traces("#mae-figure")}
    assert traces[f"active v{health['version']}"] == len(health["mae_per_step_c"]) == 6
    assert traces["bound 0.25 K"] == 2
    assert page.locator("#model-title").inner_text() == f"Model health: version {health['version']}"
    # the activated coaches that predicted (one in service only later in the day may not yet)
    assert page.locator("#model-coaches tbody tr").count() == len(health["coaches"]) >= 5
    # the versions: the one active, its validation and online error
    version = page.locator(f"#model-versions tr[data-version='{health['version']}']")
    assert version.get_attribute("data-state") == "active"
    w.shot("dashboard-model")
    assert w.errors == []
    w.close()


def test_pages_load_and_charts_have_data(browser, server):
    w = Watched(browser, server, "viewer", WALL)
    page = w.page
    w.go("#/coaches")
    # fleet: every demo coach, with its status and deck temperatures
    page.wait_for_selector("#coaches tbody tr[data-coach='D3-B']")
    rows = page.locator("#coaches tbody tr")
    ids = sorted(demo.coach_ids())
    assert rows.count() == len(ids) >= 20
    assert page.locator("tr[data-coach='D1-A'] td").nth(2).inner_text() == "activated"
    assert page.locator("tr[data-coach='D1-B'] td").nth(2).inner_text() == "deactivated"
    temps = page.locator("tr[data-coach='D1-A'] td").nth(5).inner_text()
    assert len([t for t in temps.split(" / ") if t.replace(".", "").isdigit()]) == 3, temps
    # filter and sort
    page.fill("#filter", "D2")
    assert page.locator("#coaches tbody tr").count() == 2
    page.fill("#filter", "")
    first = page.locator("#coaches tbody tr").first
    assert first.get_attribute("data-coach") == "D1-A"  # by coach, ascending
    assert page.locator("th[data-sort='id']").get_attribute("aria-sort") == "ascending"
    page.click("th[data-sort='id'] button")
    assert first.get_attribute("data-coach") == "D10-B"  # natural order, descending
    assert page.locator("th.sorted-desc[data-sort='id']").count() == 1
    assert page.locator("th[data-sort='id']").get_attribute("aria-sort") == "descending"
    order = page.locator("#coaches tbody tr").evaluate_all("rs => rs.map((r) => r.dataset.coach)")
    assert order == sorted(ids, key=natural, reverse=True)
    # the one replica, which decided every demo coach's ticks
    replica = page.locator("#replicas tbody tr").first
    replica.wait_for()
    cells = replica.locator("td").all_inner_texts()
    assert page.locator("#replicas tbody tr").count() == 1
    assert cells[0].endswith("(this one)") and cells[1] == f"{len(ids)}: {', '.join(ids)}"
    assert int(cells[2]) >= len(ids)
    w.shot("dashboard-fleet")

    # the pair comparison: the paper's four panels with data and the summary
    w.go("#/train/D1")
    page.wait_for_function(
        "() => (document.querySelector('#pair-figure').data || []).length > 0", timeout=20_000
    )
    traces = {t["name"]: t for t in w.traces("#pair-figure")}
    for name in ("T_room up", "T_ref", "T_amb", "global irradiance", "30-min savings (%)"):
        assert traces[name]["points"] > 0, (name, traces[name])
    assert traces["energy D1-A (activated)"]["points"] > 60
    assert traces["energy D1-B (deactivated)"]["points"] > 60
    assert page.locator("#pair-figure .main-svg").count() > 0  # drawn, not only data
    savings = page.locator("#kpi-savings .value .main").inner_text()
    assert savings.endswith("%"), savings
    assert page.locator("#kpi-savings .label").inner_text() == "Energy savings (HVAC units)"
    w.shot("dashboard-pair")
    # the range picker asks the API for another range
    with page.expect_response(lambda r: "/comparison?start=" in r.url and r.ok):
        page.select_option("#range", "6")

    # the coach detail: the last completed prediction against what happened, the sources
    w.go("#/coach/D1-A")
    page.wait_for_function(
        "() => (document.querySelector('#prediction-figure').data || []).length > 0",
        timeout=20_000,
    )
    names = {t["name"]: t["points"] for t in w.traces("#prediction-figure")}
    assert names["predicted mid"] > 0 and names["measured mid"] > 0 and names["T_opt"] > 0
    assert {t["name"] for t in w.traces("#sources-figure")} >= {"ddpc", "rule", "T_rule"}
    assert dict((t["name"], t["points"]) for t in w.traces("#sources-figure"))["ddpc"] >= 20
    # the audit log page loads
    w.go("#/audit")
    page.wait_for_selector("#audit thead")
    assert w.errors == []
    w.close()


def test_the_printed_url_signs_in_and_leaves_no_token_in_the_address_bar(browser, server):
    context = browser.new_context(viewport=LAPTOP)
    page = context.new_page()
    try:
        page.goto(server.signin_url)  # as `make demo` prints it: nothing typed
        page.wait_for_selector("#who:has-text('(operator)')")
        page.wait_for_function(  # the overview, with its charts
            "() => (document.querySelector('#savings-figure') || {}).data", timeout=20_000
        )
        assert "token" not in page.url and page.url.endswith("/#/")
        assert not page.locator("#signin").evaluate("d => d.open")
        # kept for the browser session: a reload stays signed in
        page.reload()
        page.wait_for_selector("#who:has-text('(operator)')")
    finally:
        context.close()


def test_viewer_sees_no_write_controls(browser, server):
    w = Watched(browser, server, "viewer")
    w.go("#/coach/D2-A")
    w.page.wait_for_selector("#coach-status .kpi")
    assert not w.page.locator("#override-form").is_visible()
    assert not w.page.locator("#layer-form").is_visible()
    assert w.page.locator("#overrides button").count() == 0
    assert w.errors == []
    w.close()


def test_the_pair_view_shows_and_changes_the_trial_plan(browser, server):
    """D2 runs the demo's alternate plan: the pair view says so, with today's coach; a viewer
    has no form; an operator sets fixed, which is pending until the next service day, as the
    panel and the API's message say, and audited."""
    headers = {"Authorization": f"Bearer {server.tokens['viewer']}"}
    url = f"{server.url}/api/v1/trains/D2/plan"
    viewer = Watched(browser, server, "viewer")
    viewer.go("#/train/D2")
    viewer.page.wait_for_selector("#plan-state[data-plan='alternate']")
    today = httpx.get(url, headers=headers).json()["activated_today"]
    assert f"; {today} runs the layer today." in viewer.page.locator("#plan-state").inner_text()
    assert not viewer.page.locator("#plan-form").is_visible()
    assert viewer.errors == []
    viewer.close()

    w = Watched(browser, server, "operator")
    page = w.page
    w.go("#/train/D2")
    page.wait_for_selector("#plan-state[data-plan='alternate']")
    assert page.locator("#plan-pending").inner_text().startswith("No change pending")
    assert page.locator("#plan-select").input_value() == "alternate"
    assert page.locator("label:has(#plan-hour)").inner_text().startswith("Switch hour")
    page.select_option("#plan-select", "fixed")
    page.fill("#plan-reason", "the trial ends")
    page.click("#plan-form button[type=submit]")
    page.wait_for_selector("#plan-pending[data-plan='fixed']")
    plan = httpx.get(url, headers=headers).json()
    assert plan["plan"] == "alternate" and plan["pending"]["plan"] == "fixed"
    at = datetime.fromisoformat(plan["pending"]["effective_from"]).astimezone(ZURICH)
    pending = page.locator("#plan-pending").inner_text()
    assert pending == (
        f"Pending: fixed from {at:%Y-%m-%d %H:%M} (Zurich), set by demo-operator: the trial ends"
    )
    assert "not mid-day" in page.locator("#plan-message").inner_text()
    assert page.locator("#plan-error").inner_text() == ""
    audit = httpx.get(f"{server.url}/api/v1/audit?target=D2", headers=headers).json()
    assert (audit[0]["action"], audit[0]["user"]) == ("train.plan", "demo-operator")
    assert w.errors == []
    w.close()


def test_operator_overrides_and_it_is_applied_and_audited(browser, server):
    w = Watched(browser, server, "operator")
    page = w.page
    w.go("#/coach/D3-A")
    page.wait_for_selector("#ov-band:has-text('Allowed')")
    assert page.locator("#override-form").is_visible()
    headers = {"Authorization": f"Bearer {server.tokens['viewer']}"}
    t_rule = httpx.get(f"{server.url}/api/v1/coaches/D3-A", headers=headers).json()["t_rule_c"]

    questions: list[str] = []

    def confirm(dialog) -> None:
        questions.append(dialog.message)
        dialog.accept()

    page.on("dialog", confirm)
    # outside T_rule ± 2 K: said in words on the field, nothing asked, nothing stored
    page.fill("#ov-value", f"{t_rule + 2.5:.1f}")
    page.fill("#ov-duration", "30")
    page.fill("#ov-reason", "too warm")
    page.click("#override-form button[type=submit]")
    page.wait_for_selector("#ov-error:has-text('outside T_rule ± 2 K')")
    assert page.locator("#ov-value").get_attribute("aria-invalid") == "true"
    assert "ov-error" in page.locator("#ov-value").get_attribute("aria-describedby")
    # a day at most, in words
    page.fill("#ov-value", f"{t_rule:.1f}")
    page.fill("#ov-duration", "1441")
    page.click("#override-form button[type=submit]")
    page.wait_for_selector("#ov-error:has-text('whole minutes from 1 to 1440')")
    assert page.locator("#ov-duration").get_attribute("aria-invalid") == "true"
    assert page.locator("#ov-value").get_attribute("aria-invalid") is None
    w.shot("dashboard-override-refused")
    assert questions == []
    assert httpx.get(f"{server.url}/api/v1/coaches/D3-A/overrides", headers=headers).json() == []

    # within the band: confirmed (coach, value, duration named), stored, shown as active with a
    # cancel button, audited, and applied
    value = round(t_rule + 1.5, 1)
    page.fill("#ov-value", f"{value:.1f}")
    page.fill("#ov-duration", "600")  # 10 h of the fleet's clock: a minute of the test's
    page.fill("#ov-reason", "passengers report it is cold")
    page.click("#override-form button[type=submit]")
    page.wait_for_selector("#ov-status:has-text('Override applied')")
    assert questions[0].startswith(f"Override coach D3-A: T_ref {value:.1f} °C for 600 min")
    page.wait_for_selector("#overrides button:has-text('Cancel')")
    page.wait_for_selector("#coach-audit td:has-text('override.create')")
    assert page.locator("#ov-error").inner_text() == ""

    def applied():  # the status says override at once; T_ref from the next tick on
        coach = httpx.get(f"{server.url}/api/v1/coaches/D3-A", headers=headers).json()
        return coach if coach["t_ref_c"] == pytest.approx(value) else None

    coach = wait_for(applied, 30, "the override issued at a tick")
    assert coach["status"] == "override"
    page.wait_for_selector("#coach-status .badge.override")
    w.shot("dashboard-coach")

    # cancel, once confirmed: the override ends and the cancellation is audited
    page.click("#overrides button:has-text('Cancel')")
    page.wait_for_selector("#coach-audit td:has-text('override.cancel')")
    assert questions[-1].startswith(
        f"Cancel the override of coach D3-A (T_ref {value:.1f} °C until"
    )
    page.wait_for_selector("#coach-audit td:has-text('override.cancel')")
    page.wait_for_selector("#overrides td:has-text('ended')")
    audit = httpx.get(f"{server.url}/api/v1/audit?target=D3-A", headers=headers).json()
    assert [a["action"] for a in audit][:2] == ["override.cancel", "override.create"]
    assert audit[1]["user"] == "demo-operator" and audit[1]["reason"] == (
        "passengers report it is cold"
    )
    assert len(questions) == 2 and w.errors == []
    w.close()


def test_a_service_preparing_its_model_says_so_and_runs_the_coaches_under_t_rule(browser, tmp_path):
    """A first start without a model (no ``--predictor``, nothing cached): the dashboard shows
    the preparation's progress and the activated coaches as ``preparing`` under T_rule."""
    port = free_port()
    args = serve_args(port, "--fleet", "demo", "--speedup", "600", "--new-token", "operator")
    srv = Server(args, child_env(tmp_path / "new" / "home"), port, tmp_path / "server.log")
    try:
        srv.start()
        printed = srv.printed(r"operator token: (tc_\S+)")
        srv.tokens = {"operator": printed.group(1)}
        w = Watched(browser, srv, "operator")
        w.go("#/coaches")
        notice = w.page.locator("#preparing")
        notice.wait_for(state="visible", timeout=10_000)
        assert re.match(r"Preparing the predictor model: .+, \d+ %\.", notice.inner_text())
        assert "coaches follow the rule-based setpoint T_rule" in notice.inner_text()
        # the status cell's badge (a coach outside the comfort band has one in its comfort cell)
        status = "tr[data-coach='{}'] td[data-label='Status'] .badge"
        w.page.wait_for_selector(status.format("D1-A") + ".preparing", timeout=20_000)
        assert w.page.locator(status.format("D1-B")).inner_text() == "inactive"
        w.shot("dashboard-preparing")
        assert w.errors == []
        w.close()
    finally:
        srv.stop()


# --- savings with their uncertainty, on a seeded fleet ------------------------------------------
#: The seeded trial's service days (each 4 h from 07:00 Zurich), the saving the layer makes on
#: them, the coaches' own levels, each day's level and coach 1's day-to-day scatter.
TRIAL_DAYS = 6
DAY_MIN = 240
SAVING = 0.10
COACH_LEVEL = (1.0, 1.08)
DAY_LEVEL = (1.0, 1.1, 0.95, 1.05, 0.9, 1.0)
SCATTER = (1.0, 1.03, 0.98, 1.01, 0.97, 1.02)
ROLES = ("viewer", "operator")


def seed_pair(srv, train: str, days: range, plan: str) -> None:
    """Train ``train`` with coaches ``{train}-A`` (coach 0) and ``{train}-B``: on each service
    day of ``days``, DAY_MIN minutes of telemetry from T0's time of day and the setpoints of
    their ticks (up to the one at their end) — on the ``crossover`` plan coach A under the layer
    on even days, B on odd ones; on ``fixed``, A every day; on ``preparing``, A waiting for the
    model (``rule``/``no_model``) and B on T_rule. The setpoints are stored first (the coaches'
    last tick moved up to the newest), so the live loop does not decide those ticks again when
    the telemetry arrives."""
    coaches = (f"{train}-A", f"{train}-B")
    operator = {"Authorization": f"Bearer {srv.tokens['operator']}"}
    with httpx.Client(base_url=srv.url) as http:
        for i, coach in enumerate(coaches):
            assert register(http, operator, coach, train, active=i == 0).status_code == 201
        db = Database(srv.db_url)
        store = SimpleNamespace(app=SimpleNamespace(state=SimpleNamespace(db=db)))
        for d in days:
            first = d * 24 * 60
            on = d % 2 if plan == "crossover" else 0
            for c, coach in enumerate(coaches):
                if plan == "preparing":
                    source, reason = ("rule", "no_model") if c == 0 else ("rule", "inactive")
                else:
                    source, reason = ("ddpc", "ok") if c == on else ("rule", "inactive")
                decided(store, coach, first, first + DAY_MIN, source, reason)
        db.dispose()
        for c, coach in enumerate(coaches):
            rows = []
            for d in days:
                saving = 1.0 - SAVING if c == (d % 2 if plan == "crossover" else 0) else 1.0
                level = COACH_LEVEL[c] * DAY_LEVEL[d] * (SCATTER[d] if c == 1 else 1.0)
                first = d * 24 * 60
                rows += flat_rows(first + 1, first + DAY_MIN, power_kw=10.0 * level * saving)
            reply = post_rows(http, operator, coach, rows)
            assert reply.status_code in (200, 201, 202), reply.text


@pytest.fixture(scope="module")
def seeded(tmp_path_factory, small_predictor_file):
    """The service without a demo fleet, with one train seeded, ``P``: two hours in which the
    model was still being prepared (every window excluded as ``preparing``). ``seed_trial()``
    adds train ``X`` on a crossover plan over six service days (a 95 % interval) and ``F`` on a
    fixed plan over two (confounded: none), once."""
    srv = sqlite_server(tmp_path_factory.mktemp("dashboard-trial"), small_predictor_file)
    migrate(srv.db_url)
    db = Database(srv.db_url)
    with db.transaction() as s:
        srv.tokens = {role: create_token(s, role, f"browser-{role}")[0] for role in ROLES}
    db.dispose()
    seed_pair(srv, "P", range(1), "preparing")
    seeded_trial = []

    def seed_trial() -> None:
        if not seeded_trial:
            seed_pair(srv, "X", range(TRIAL_DAYS), "crossover")
            seed_pair(srv, "F", range(2), "fixed")
            seeded_trial.append(True)

    srv.seed_trial = seed_trial
    yield srv
    srv.stop()


def summary_of(srv, hours: int) -> dict:
    headers = {"Authorization": f"Bearer {srv.tokens['viewer']}"}
    reply = httpx.get(f"{srv.url}/api/v1/fleet/summary?hours={hours}", headers=headers)
    assert reply.status_code == 200, reply.text
    return reply.json()


def interval_text(f: dict) -> str:
    """A figure with its interval as the dashboard writes it."""
    low, high = f["savings_ci95_pct"]
    text = f"{f['savings_pct']:.1f} % (95 % CI {low:.1f} to {high:.1f})"
    return text + (" — not yet distinguishable from zero" if low <= 0 <= high else "")


def test_the_overview_says_no_comparable_windows_while_every_window_is_preparing(browser, seeded):
    summary = summary_of(seeded, 24)
    assert summary["counted_windows"] == 0 and summary["savings_pct"] is None
    [train] = summary["trains"]
    assert set(train["excluded_minutes_by_reason"]) == {"preparing"}
    w = Watched(browser, seeded, "viewer")
    page = w.page
    tile = page.locator("#kpi-fleet-savings .value")
    tile.wait_for(timeout=20_000)
    assert tile.inner_text() == "no comparable windows yet"
    row = page.locator("#train-savings tr[data-train='P'] td")
    row.first.wait_for()
    assert row.nth(1).inner_text() == "no comparable windows yet"
    assert "0.0 %" not in page.locator("#fleet-kpis").inner_text()
    assert w.errors == []
    w.close()


def test_savings_show_their_interval_or_why_they_have_none(browser, seeded):
    seeded.seed_trial()
    summary = summary_of(seeded, 168)
    trains = {t["id"]: t for t in summary["trains"]}
    x, f = trains["X"], trains["F"]
    assert x["estimator"] == "crossover" and x["savings_ci95_pct"] is not None
    assert f["estimator"] == "fixed_naive" and f["savings_ci95_pct"] is None
    assert summary["estimator"] == "random_effects" and summary["trains_pooled"] == 1
    w = Watched(browser, seeded, "viewer", WALL)
    page = w.page
    page.wait_for_selector("#kpi-fleet-savings .value")
    with page.expect_response(lambda r: "/fleet/summary?hours=168" in r.url and r.ok):
        page.select_option("#hours", "168")
    # the fleet's figure pooled over the train with an interval; the confounded one left out
    tile = page.locator("#kpi-fleet-savings .value")
    page.wait_for_function(
        "(v) => document.querySelector('#kpi-fleet-savings .value').textContent === v",
        arg=interval_text(summary),
    )
    sub = page.locator("#kpi-fleet-savings .sub").inner_text()
    assert "pooled over 1 train with an interval" in sub
    assert "1 train left out: confounded with the coaches" in sub
    assert tile.inner_text().startswith(f"{summary['savings_pct']:.1f} %")
    # per train: the interval, the reason there is none, or that nothing counted
    cells = {
        t: page.locator(f"#train-savings tr[data-train='{t}'] td").all_inner_texts()
        for t in ("X", "F", "P")
    }
    assert cells["X"][1:3] == [interval_text(x), "crossover over 6 days"]
    assert cells["F"][1:] == [
        f"{f['savings_pct']:.1f} % — confounded with the coaches: fixed plan",
        "fixed plan, no reference days",
        "–",
    ]
    assert cells["P"][1:] == ["no comparable windows yet", "–", "–"]
    # the bars: X's with its error bars, F's hatched, none for P
    bars = page.evaluate(
        """() => document.querySelector('#savings-figure').data.map((t) => ({
            name: t.name, x: t.x, y: t.y, pattern: (t.marker.pattern || {}).shape || '',
            plus: (t.error_y || {}).array || [], minus: (t.error_y || {}).arrayminus || []}))"""
    )
    solid, hatched = bars
    assert hatched["name"] == "no interval (confounded or too few days)" and hatched["pattern"]
    order = sorted(("X", "F"), key=lambda t: -trains[t]["savings_pct"])
    assert solid["x"] == hatched["x"] == [*order, "P"]  # by savings, P without any last
    i, j = order.index("X"), order.index("F")
    low, high = x["savings_ci95_pct"]
    assert solid["y"][i] == pytest.approx(x["savings_pct"]) and solid["y"][j] is None
    assert solid["plus"][i] == pytest.approx(high - x["savings_pct"])
    assert solid["minus"][i] == pytest.approx(x["savings_pct"] - low)
    assert hatched["y"][i] is None and hatched["y"][j] == pytest.approx(f["savings_pct"])
    assert solid["y"][2] is None and hatched["y"][2] is None
    w.shot("dashboard-overview-trial")

    # the pair: its estimate in words, the excluded minutes by reason, the windows shaded
    w.go("#/train/X")
    page.wait_for_function(
        "() => (document.querySelector('#pair-figure').data || []).length > 0", timeout=20_000
    )
    page.select_option("#range", "custom")
    page.fill("#range-start", "2024-11-28T00:00")
    page.fill("#range-end", "2024-12-03T12:00")
    with page.expect_response(lambda r: "/comparison?start=" in r.url and r.ok) as info:
        page.click("#range-apply")
    cmp = info.value.json()
    assert cmp["estimator"] == "crossover" and cmp["days"]["coach_0"] == 3
    page.wait_for_function(
        "(v) => document.querySelector('#kpi-savings .value').textContent === v",
        arg=interval_text(cmp),
    )
    assert page.locator("#kpi-estimator .value").inner_text() == "crossover over 6 days"
    target = cmp["days_to_target"]
    expected = "reached: ±2 points or better" if target == 0 else f"about {target} more day"
    assert page.locator("#kpi-days-to-target .value").inner_text().startswith(expected)
    g14 = page.locator("#kpi-guideline-14 .value").inner_text()
    assert g14 == ("yes" if cmp["meets_guideline_14"] else "no")
    # five switches of the activated coach: an hour's lead-in after each
    reasons = dict(
        zip(
            page.locator("#excluded-reasons tr[data-reason]").evaluate_all(
                "(rows) => rows.map((r) => r.dataset.reason)"
            ),
            page.locator("#excluded-reasons tr[data-reason] td.num").all_inner_texts(),
            strict=True,
        )
    )
    assert reasons["plan_switch"] == "300"
    assert reasons == {k: f"{v:.0f}" for k, v in cmp["excluded_minutes_by_reason"].items()}
    key = page.locator("#pair-key").inner_text()
    assert "X-A under the layer" in key and "X-B under the layer" in key
    # the strip above the chart: a run of windows per day, by the coach under the layer
    shapes = page.evaluate(
        "() => document.querySelector('#pair-figure').layout.shapes.map((s) => s.name)"
    )
    assert shapes.count("layer:X-A") == shapes.count("layer:X-B") == 3
    assert shapes.count("excluded:plan_switch") == 5
    w.shot("dashboard-pair-trial")
    assert w.errors == []
    w.close()
