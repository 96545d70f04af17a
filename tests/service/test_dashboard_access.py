"""The dashboard for a control room, in a real browser (Playwright driving Debian's Chromium against
``trainclimate serve --fleet demo`` as its own process on SQLite):

- axe-core (WCAG 2.1 A and AA rules) finds nothing on any page state: sign-in, overview (a chart's
  data table open), coaches, pair, coach (an operator's forms), model, audit log, tokens, and the
  overview at phone width;
- a keyboard-only walk through the operator's tasks: skip link, sorting the coaches (header
  buttons with ``aria-sort``), opening a pair, exporting its windows (the CSV's numbers are the
  API's), an override confirmed (coach, value and duration named) and cancelled;
- refreshes keep the focus where it is and a failed one says so, and that it recovered; leaving
  views while their refreshes are under way throws nothing;
- Escape leaves the sign-in dialog open, and a ``#token=`` URL pasted into it signs in;
- Plotly's PNG download works under the page's CSP, and its cloud buttons are gone;
- activated and deactivated, ok and stale stay apart under a deuteranopia simulation;
- at 390 px nothing scrolls sideways and "Needs attention" comes first;
- the first load is at most 1.5 MB and an idle overview asks at most 12 times a minute.
"""

from __future__ import annotations

import csv
import io
import random
import re
import time
from pathlib import Path

import httpx
import pytest

from helpers.processes import demo_server, wait_for_ddpc
from service import test_dashboard
from trainclimate.service import dashboard_files
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token

browser = test_dashboard.browser  # the fixture: Chromium, headless
ARGS = test_dashboard.ARGS
AXE = Path(__file__).parents[1] / "browser" / "node_modules" / "axe-core" / "axe.min.js"
LAPTOP = {"width": 1440, "height": 900}
PHONE = {"width": 390, "height": 844}
#: The WCAG 2.1 A and AA rules of axe-core.
WCAG_AA = ["wcag2a", "wcag2aa", "wcag21a", "wcag21aa"]
#: axe-core's run on the page, its violations as "rule: the first three elements".
AXE_RUN = """(tags) => axe.run(document, { runOnly: { type: 'tag', values: tags } })
    .then((r) => r.violations.map((v) =>
        `${v.id}: ${v.nodes.slice(0, 3).map((n) => n.target.join(' ')).join(', ')}`))"""


@pytest.fixture(scope="module")
def server(tmp_path_factory, small_predictor_file):
    """The demo fleet at 600× on SQLite, with a viewer, an operator and an admin token, running
    until D1-A has 20 DDPC setpoints."""
    srv = demo_server(tmp_path_factory.mktemp("dashboard-access"), Path(small_predictor_file))
    migrate(srv.db_url)
    db = Database(srv.db_url)
    with db.transaction() as s:
        srv.tokens = {
            r: create_token(s, r, f"access-{r}")[0] for r in ("viewer", "operator", "admin")
        }
    db.dispose()
    wait_for_ddpc(srv, srv.tokens["viewer"])
    yield srv
    srv.stop()


class Session(test_dashboard.Watched):
    """A signed-in page with its page errors and console errors collected; ``csp=False``
    bypasses the page's CSP (to inject axe-core only)."""

    def __init__(self, browser, server, role: str, viewport=LAPTOP, csp: bool = True):
        super().__init__(browser, server, role, viewport, accept_downloads=True, bypass_csp=not csp)

    def api(self, path: str, role: str = "viewer", **params):
        headers = {"Authorization": f"Bearer {self.server.tokens[role]}"}
        return httpx.get(f"{self.server.url}/api/v1{path}", params=params, headers=headers)

    def tab_to(self, selector: str, limit: int = 300) -> None:
        """Presses Tab until the focus is on ``selector``."""
        for _ in range(limit):
            self.page.keyboard.press("Tab")
            if self.page.evaluate("(s) => document.activeElement?.matches(s)", selector):
                return
        raise AssertionError(f"Tab never reached {selector}")

    def axe(self, state: str) -> None:
        """axe-core's WCAG 2.1 A/AA violations on the page as it is: none."""
        if not self.page.evaluate("() => !!window.axe"):
            self.page.add_script_tag(path=str(AXE))
        found = self.page.evaluate(AXE_RUN, WCAG_AA)
        assert found == [], (state, found)


def _drawn(page, figure: str) -> None:
    page.wait_for_function(
        "(s) => (document.querySelector(s)?.data || []).length > 0", arg=figure, timeout=30_000
    )


def _rows(text: str) -> list[dict]:
    return list(csv.DictReader(io.StringIO(text)))


@pytest.mark.skipif(not AXE.exists(), reason=f"no {AXE} (npm ci --prefix tests/browser)")
def test_axe_finds_no_wcag_aa_violation_on_any_page_state(browser, server):
    signin = browser.new_context(viewport=LAPTOP, bypass_csp=True)
    page = signin.new_page()
    page.goto(server.url + "/")
    page.wait_for_selector("#signin[open]")
    page.add_script_tag(path=str(AXE))
    found = page.evaluate(AXE_RUN, WCAG_AA)
    assert found == [], ("sign-in", found)
    signin.close()

    s = Session(browser, server, "admin", csp=False)
    states = {
        "#/": "#savings-figure",
        "#/coaches": "#coaches tbody tr[data-coach='D1-A']",
        "#/train/D1": "#pair-figure",
        "#/coach/D1-A": "#prediction-figure",
        "#/model": "#mae-figure",
        "#/audit": "#audit thead",
        "#/tokens": "#tokens tbody tr",
    }
    for hash_, ready in states.items():
        s.go(hash_)
        if ready.endswith("-figure"):
            _drawn(s.page, ready)
        else:
            s.page.wait_for_selector(ready)
        s.axe(hash_)
    # a chart's data table, open
    s.go("#/")
    _drawn(s.page, "#energy-figure")
    s.page.click("#energy-figure + .table-toggle")
    s.page.wait_for_selector("#energy-figure-table tbody tr")
    s.axe("overview with a data table")
    s.close()
    phone = Session(browser, server, "operator", PHONE, csp=False)
    _drawn(phone.page, "#savings-figure")
    phone.axe("overview at 390 px")
    assert phone.errors == [] and s.errors == []
    phone.close()


def test_a_keyboard_only_walk_through_the_operators_tasks(browser, server):
    s = Session(browser, server, "operator")
    page = s.page
    questions: list[str] = []

    def confirm(dialog) -> None:
        questions.append(dialog.message)
        dialog.accept()

    page.on("dialog", confirm)
    _drawn(page, "#savings-figure")
    # the skip link is the first stop, and takes the focus past the header
    page.keyboard.press("Tab")
    assert page.evaluate("() => document.activeElement.className") == "skip-link"
    page.keyboard.press("Enter")
    assert page.evaluate("() => document.activeElement.id") == "view"

    # sort the coaches by train, then by coach descending: header buttons with aria-sort
    s.tab_to("a[data-nav='coaches']")
    page.keyboard.press("Enter")
    page.wait_for_selector("#coaches tbody tr[data-coach='D10-B']")
    s.tab_to("th[data-sort='id'] button")
    page.keyboard.press("Enter")
    assert page.get_attribute("th[data-sort='id']", "aria-sort") == "descending"
    first = page.locator("#coaches tbody tr").first.get_attribute("data-coach")
    assert first == "D10-B"
    page.keyboard.press("Enter")
    assert page.get_attribute("th[data-sort='id']", "aria-sort") == "ascending"
    order = page.locator("#coaches tbody tr").evaluate_all("rs => rs.map((r) => r.dataset.coach)")
    assert order[:4] == ["D1-A", "D1-B", "D2-A", "D2-B"] and order[-2:] == ["D10-A", "D10-B"]

    # open a pair from the overview's table of trains (what a bar does by mouse)
    s.tab_to("a[data-nav='overview']")
    page.keyboard.press("Enter")
    _drawn(page, "#savings-figure")
    s.tab_to("#train-savings a[href='#/train/D1']")
    page.keyboard.press("Enter")
    _drawn(page, "#pair-figure")

    # export its windows: the CSV the browser saves carries the API's figures for the range
    s.tab_to("#train-export")
    with page.expect_download() as info, page.expect_request(lambda r: ".csv" in r.url) as asked:
        page.keyboard.press("Enter")
    query = asked.value.url.split("comparison.csv", 1)[1]
    assert query.startswith("?start=")
    rows = _rows(Path(info.value.path()).read_text())
    assert info.value.suggested_filename == "comparison-D1.csv"
    cmp = httpx.get(
        f"{server.url}/api/v1/trains/D1/comparison{query}",
        headers={"Authorization": f"Bearer {server.tokens['viewer']}"},
    ).json()
    assert len(rows) == len(cmp["windows"]) > 0
    for row, w in zip(rows, cmp["windows"], strict=True):
        assert row["savings_pct"] == ("" if w["savings_pct"] is None else repr(w["savings_pct"]))
        assert float(row["energy_activated_kwh"]) == w["energy_activated_kwh"]
        assert row["excluded_reason"] == (w["excluded_reason"] or "")
    page.wait_for_selector(".export-status:has-text('Downloaded comparison-D1.csv')")

    # an override on D4-A, confirmed, then cancelled, confirmed
    s.go("#/coach/D4-A")
    page.wait_for_selector("#ov-band:has-text('Allowed')")
    t_rule = s.api("/coaches/D4-A").json()["t_rule_c"]
    value = round(t_rule - 1.0, 1)
    s.tab_to("#ov-value")
    page.keyboard.type(f"{value:.1f}")
    page.keyboard.press("Tab")
    page.keyboard.press("Control+a")
    page.keyboard.type("300")
    page.keyboard.press("Tab")
    page.keyboard.type("keyboard walk")
    page.keyboard.press("Enter")
    page.wait_for_selector("#overrides button:has-text('Cancel')", timeout=20_000)
    assert questions[-1].startswith(f"Override coach D4-A: T_ref {value:.1f} °C for 300 min")
    s.tab_to("#overrides button")
    page.keyboard.press("Enter")
    page.wait_for_selector("#overrides td:has-text('ended')", timeout=20_000)
    assert questions[-1].startswith("Cancel the override of coach D4-A")
    actions = [a["action"] for a in s.api("/audit", target="D4-A").json()][:2]
    assert actions == ["override.cancel", "override.create"]

    # the layer off, once confirmed (and back on)
    s.tab_to("#layer-reason")
    page.keyboard.type("keyboard walk")
    page.keyboard.press("Enter")
    page.wait_for_selector("#layer-button:has-text('Switch the layer on')", timeout=20_000)
    assert questions[-1].startswith("Switch the DDPC layer off for coach D4-A?")
    s.tab_to("#layer-reason")
    page.keyboard.type("keyboard walk done")
    page.keyboard.press("Enter")
    page.wait_for_selector("#layer-button:has-text('Switch the layer off')", timeout=20_000)
    assert len(questions) == 4 and s.errors == []
    s.close()


def test_refreshes_keep_the_focus_and_say_when_they_fail_and_recover(browser, server):
    s = Session(browser, server, "viewer")
    page = s.page
    s.go("#/coaches")
    page.wait_for_selector("#coaches tbody tr[data-coach='D3-A']")
    assert page.get_attribute("#view", "aria-live") is None  # only status messages are live
    s.tab_to("tr[data-coach='D3-A'] a")
    # two refreshes of the list (every 10 s): the focus stays on the link
    with page.expect_response(lambda r: r.url.endswith("/api/v1/coaches")):
        pass
    with page.expect_response(lambda r: r.url.endswith("/api/v1/coaches"), timeout=15_000):
        pass
    time.sleep(0.5)
    focused = page.evaluate("() => document.activeElement.closest('tr')?.dataset.coach")
    assert focused == "D3-A"
    # the API unreachable: a notice says the refresh failed; back: that it recovered
    page.route("**/api/v1/coaches", lambda route: route.abort())
    notice = page.locator("#refresh-status")
    notice.wait_for(state="visible", timeout=15_000)
    assert notice.inner_text().startswith("Refresh failed at ")
    assert "(wall time, Zurich)" in notice.inner_text()
    assert notice.get_attribute("role") == "status"
    page.unroute("**/api/v1/coaches")
    page.wait_for_selector("#refresh-status:has-text('Refresh recovered')", timeout=15_000)
    assert [e for e in s.errors if "ERR_FAILED" not in e] == []
    s.close()


def test_leaving_views_while_they_refresh_throws_nothing(browser, server):
    s = Session(browser, server, "viewer")
    rng = random.Random(36)
    views = ["#/", "#/coaches", "#/train/D2", "#/coach/D2-A", "#/model", "#/audit"]
    for _ in range(24):
        s.page.evaluate("(h) => { location.hash = h; }", rng.choice(views)[1:])
        time.sleep(rng.uniform(0.05, 0.8))
    s.go("#/")
    _drawn(s.page, "#savings-figure")
    time.sleep(1)
    assert s.errors == []
    s.close()


def test_escape_and_a_token_url_on_the_sign_in_dialog(browser, server):
    context = browser.new_context(viewport=LAPTOP)
    page = context.new_page()
    try:
        page.goto(server.url + "/")
        page.wait_for_selector("#signin[open]")
        page.keyboard.press("Escape")
        assert page.locator("#signin").evaluate("d => d.open")
        assert "needs a token" in page.locator("#signin-error").inner_text()
        # the printed URL pasted into this tab: signed in, the token gone from the address bar
        page.goto(f"{server.url}/#token={server.tokens['operator']}")
        page.wait_for_selector("#who:has-text('(operator)')")
        assert not page.locator("#signin").evaluate("d => d.open")
        assert "token" not in page.url
    finally:
        context.close()


def test_plotly_downloads_a_png_under_the_csp_and_offers_no_cloud(browser, server):
    s = Session(browser, server, "viewer")
    page = s.page
    _drawn(page, "#energy-figure")
    page.hover("#energy-figure")
    assert page.locator("#energy-figure .modebar-btn[data-title*='Chart Studio']").count() == 0
    assert page.locator("#energy-figure .modebar-btn[data-title*='Cloud']").count() == 0
    assert page.locator("#energy-figure .modebar .plotlyjsicon").count() == 0  # no logo
    with page.expect_download() as info:
        page.click("#energy-figure .modebar-btn[data-title='Download plot as a PNG']")
    assert info.value.suggested_filename == "energy.png"
    assert Path(info.value.path()).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with page.expect_download() as info:
        page.click("#energy-figure .modebar-btn[data-title='Download plot as SVG']")
    assert Path(info.value.path()).read_text().startswith("<svg")
    assert [e for e in s.errors if "Content Security Policy" in e] == [] and s.errors == []
    s.close()


# --- colour under deuteranopia (Machado et al. 2009, severity 1, on linear RGB) ---------------
DEUTERANOPIA = (
    (0.367322, 0.860646, -0.227968),
    (0.280085, 0.672501, 0.047413),
    (-0.011820, 0.042940, 0.968881),
)


def _linear(c: str) -> tuple[float, ...]:
    rgb = [int(c[i : i + 2], 16) / 255 for i in (1, 3, 5)]
    return tuple(v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4 for v in rgb)


def _luminance(rgb: tuple[float, ...]) -> float:
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]


def _deuteranope_luminance(colour: str) -> float:
    lin = _linear(colour)
    seen = [
        max(0.0, min(1.0, sum(m * v for m, v in zip(row, lin, strict=True))))
        for row in DEUTERANOPIA
    ]
    return _luminance(tuple(seen))


def _ratio(a: float, b: float) -> float:
    return (max(a, b) + 0.05) / (min(a, b) + 0.05)


def _hex(css: str) -> str:
    r, g, b = (int(v) for v in re.findall(r"\d+", css)[:3])
    return f"#{r:02x}{g:02x}{b:02x}"


def test_colours_stay_apart_under_deuteranopia_and_graphics_reach_3_to_1(browser, server):
    s = Session(browser, server, "viewer")
    page = s.page
    _drawn(page, "#energy-figure")
    lines = page.evaluate(
        """() => Object.fromEntries(
            document.querySelector('#energy-figure').data.map((t) => [t.name, t.line]))"""
    )
    act, deact = lines["activated coaches"], lines["deactivated coaches"]
    assert act["dash"] != deact["dash"]
    seen = _ratio(_deuteranope_luminance(act["color"]), _deuteranope_luminance(deact["color"]))
    assert seen >= 3.0, seen  # was 2.0 (#009E73 against #555555)
    for colour in (act["color"], deact["color"], "#0072B2"):  # and the savings bars
        assert _ratio(_luminance(_linear(colour)), 1.0) >= 3.0, colour
    # ok and stale: told apart by fill and icon, not only by hue
    s.go("#/coaches")
    page.wait_for_selector("#coaches .badge")
    style = page.evaluate(
        """() => { const b = document.createElement('span'); const out = {};
        for (const c of ['ok', 'stale', 'fallback']) {
          b.className = 'badge ' + c; document.body.append(b);
          const cs = getComputedStyle(b); const icon = getComputedStyle(b, '::before').content;
          out[c] = { bg: cs.backgroundColor, fg: cs.color, icon }; }
        b.remove(); return out; }"""
    )
    ok_bg = _deuteranope_luminance(_hex(style["ok"]["bg"]))
    stale_bg = _deuteranope_luminance(_hex(style["stale"]["bg"]))
    assert _ratio(ok_bg, stale_bg) >= 3.0, style  # was 1.04
    assert len({style[c]["icon"] for c in style}) == 3, style
    s.close()


def test_a_phone_shows_attention_first_and_nothing_scrolls_sideways(browser, server):
    s = Session(browser, server, "admin", PHONE)
    page = s.page
    for hash_, ready in {
        "#/": "#savings-figure",
        "#/coaches": "#coaches tbody tr",
        "#/train/D1": "#pair-figure",
        "#/coach/D1-A": "#prediction-figure",
        "#/model": "#mae-figure",
        "#/audit": "#audit tbody tr",
        "#/tokens": "#tokens tbody tr",
    }.items():
        s.go(hash_)
        if ready.endswith("-figure"):
            _drawn(page, ready)
        else:
            page.wait_for_selector(ready)
        width = page.evaluate("() => document.documentElement.scrollWidth")
        assert width <= PHONE["width"], (hash_, width)
        if hash_ == "#/":
            attention = page.locator("h2:has-text('Needs attention')").bounding_box()
            tiles = page.locator("#fleet-kpis").bounding_box()
            energy = page.locator("#energy-figure").bounding_box()
            assert attention["y"] < tiles["y"] < energy["y"]
            s.shot("dashboard-phone-overview")
        if hash_ == "#/coaches":
            # a card per coach: each value under its column's name
            label = page.locator("tr[data-coach='D1-A'] td").nth(2).get_attribute("data-label")
            assert label == "Layer"
            s.shot("dashboard-phone-coaches")
    assert s.errors == []
    s.close()


def test_the_first_load_and_the_idle_overview_are_light(browser, server):
    """``bench dashboard`` on the demo: the first load at most 1.5 MB transferred (gzip, Plotly's
    basic bundle; 4.9 MB before), an idle overview at most 12 requests a minute (36 before).
    Idle 30 s on each page: the overview's summary refreshes every 30 s, a coach's status every
    10 s, so a page asking 12 times a minute or more shows in 30 s as well as in 60."""
    from trainclimate.bench import dashboard

    if not (Path(__file__).parents[2] / dashboard_files.PLOTLY_BASIC).exists():
        pytest.skip("no Plotly basic bundle (npm ci --prefix npm): the full one is 1.47 MB alone")
    d = dashboard.run(server.url, server.tokens["viewer"], idle_s=30, browser=browser)
    assert d["first_load_bytes"] <= 1_500_000, d
    assert d["idle_overview_requests_per_min"] <= 12, d
    assert d["idle_coach_requests_per_min"] <= 20, d
    assert d["reload_bytes"] < d["first_load_bytes"] / 10, d  # versioned files from the cache
    assert d["target_met"]


def test_charts_show_what_matters_and_each_has_its_data_table(browser, server):
    s = Session(browser, server, "viewer")
    page = s.page
    _drawn(page, "#savings-figure")
    # the savings bars carry their values; every chart has its data table behind a toggle
    texts = page.evaluate("() => document.querySelector('#savings-figure').data.map((t) => t.text)")
    assert any(t and any(v.endswith(" %") for v in t) for t in texts), texts
    for figure in ("#energy-figure", "#savings-figure", "#violation-figure"):
        toggle = page.locator(f"{figure} + .table-toggle")
        assert toggle.get_attribute("aria-expanded") == "false"
    assert "fleet clock" in page.locator("#overview-clock").inner_text()
    s.go("#/train/D1")
    _drawn(page, "#pair-figure")
    layout = page.evaluate(
        "() => { const l = document.querySelector('#pair-figure').layout;"
        " return { y: l.yaxis, y2: l.yaxis2, y5: l.yaxis5, y6: l.yaxis6 }; }"
    )
    # the temperature panels around the band while in service (not 0 … 22 °C for the night)
    low, high = layout["y"]["range"]
    assert high - low <= 10 and low > 10, layout["y"]
    assert layout["y2"]["range"] == layout["y"]["range"]
    # the savings on their own axis, not overlaying the energy's
    assert (
        "overlaying" not in layout["y6"] and layout["y6"]["domain"][1] < layout["y5"]["domain"][0]
    )
    page.check("#whole-range")
    page.wait_for_function(
        "() => document.querySelector('#pair-figure').layout.yaxis.autorange !== false"
    )
    # the coach's telemetry export: the API's rows over the range asked
    s.go("#/coach/D1-A")
    page.wait_for_selector("#coach-clock:has-text('fleet clock')")
    page.select_option("#export-hours", "6")
    with page.expect_download() as info, page.expect_request(lambda r: ".csv" in r.url) as asked:
        page.click("#coach-export")
    query = asked.value.url.split("timeseries.csv", 1)[1]
    rows = _rows(Path(info.value.path()).read_text())
    ts = httpx.get(
        f"{server.url}/api/v1/coaches/D1-A/timeseries{query}",
        headers={"Authorization": f"Bearer {server.tokens['viewer']}"},
    ).json()
    assert len(rows) == len(ts["time"]) > 60
    cell = lambda v: "" if v is None else repr(v)  # noqa: E731
    assert [r["power_kw"] for r in rows] == [cell(v) for v in ts["power_kw"]]
    assert [r["t_room_mid_c"] for r in rows] == [cell(t[1]) for t in ts["t_room_c"]]
    s.go("#/audit")
    assert "wall time" in page.locator("#audit thead").inner_text()
    assert s.errors == []
    s.close()
