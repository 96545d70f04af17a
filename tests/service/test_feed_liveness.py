"""A dead feed shows as dead, with real processes: ``trainclimate serve`` and three gateway
emulators (trains 124–126, 120×) with a gateway token. Stopping one gateway turns its coaches
``stale`` within two periods of their pace (5 s of wall time at 120×) while the others stay
live; a gateway joining later at another simulated time makes nobody stale (and is judged at the
fleet's pace before its own is measured); stopping every gateway turns every live coach
``stale`` — although their clocks, their newest rows, stand still — and the dashboard says the
feed is down."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import httpx
import pytest

from helpers.processes import CLI, token_cli
from helpers.service import wait_for

SPEEDUP = 120.0
#: Two periods of 5 min at 120× in wall time, and a margin for the polling. [s]
STALE_AFTER_S = 2 * 300 / SPEEDUP
CHROMIUM = Path("/usr/bin/chromium")


def test_dead_gateways_turn_their_coaches_stale(db_url, servers, proc_env, tmp_path):
    if not db_url.startswith("sqlite"):
        pytest.skip("judged the same on both databases: one run of the processes is enough")
    server = servers(db_url).start()
    trains = ("124", "125", "126", "130")
    coaches = [f"{t}-{s}" for t in trains for s in "AB"]
    gw_token = token_cli(db_url, "gateway", proc_env, "--coaches", ",".join(coaches))
    viewer = {"Authorization": f"Bearer {token_cli(db_url, 'viewer', proc_env)}"}
    gateways: dict[str, subprocess.Popen] = {}

    def start(train: str) -> None:
        args = [*CLI, "gateway", "--server", server.url, "--coaches", f"{train}-A,{train}-B",
                "--token", gw_token, "--hours", "12", "--speedup", str(SPEEDUP)]  # fmt: skip
        with (tmp_path / f"gw-{train}.log").open("wb") as log:
            gateways[train] = subprocess.Popen(args, env=proc_env, stdout=log, stderr=log)

    def statuses() -> dict[str, str]:
        reply = httpx.get(f"{server.url}/api/v1/coaches", headers=viewer, timeout=10).json()
        return {c["id"]: c["status"] for c in reply if c["fleet"] == "live"}

    def stale_set() -> set[str]:
        return {c for c, s in statuses().items() if s == "stale"}

    try:
        for train in trains[:3]:
            start(train)
        # all six coaches report; the pace is measured over 20 s of wall time first
        wait_for(lambda: len(statuses()) == 6, 60, "six live coaches")
        time.sleep(25)
        assert stale_set() == set()
        # one gateway stops: its coaches turn stale within two periods at the pace, not others
        gateways["124"].kill()
        stopped = time.monotonic()
        wait_for(lambda: stale_set() == {"124-A", "124-B"}, 10 * STALE_AFTER_S, "124 stale")
        assert time.monotonic() - stopped < STALE_AFTER_S + 3
        # a gateway joining at another simulated time (its scenario's start, hours behind the
        # fleet's clock) makes nobody stale
        start("130")
        wait_for(lambda: {"130-A", "130-B"} <= set(statuses()), 30, "train 130 registered")
        time.sleep(2 * STALE_AFTER_S)
        assert stale_set() == {"124-A", "124-B"}
        # every gateway stops: the clock stands still, and yet every live coach turns stale
        for train in ("125", "126", "130"):
            gateways[train].kill()
        stopped = time.monotonic()
        wait_for(lambda: stale_set() == set(coaches), 10 * STALE_AFTER_S, "all stale")
        assert time.monotonic() - stopped < STALE_AFTER_S + 3
        if CHROMIUM.exists():
            assert_dashboard_says_feed_down(server.url, viewer["Authorization"][7:])
    finally:
        for proc in gateways.values():
            if proc.poll() is None:
                proc.kill()


def assert_dashboard_says_feed_down(url: str, viewer_token: str) -> None:
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox", "--disable-gpu"]
        )
        try:
            page = browser.new_page()
            page.goto(f"{url}/")
            page.fill("#token", viewer_token)
            page.click("#signin-form button[type=submit]")
            notice = page.locator("#feed-down")
            notice.wait_for(state="visible", timeout=20_000)
            assert notice.inner_text().startswith("Live feed down since ")
        finally:
            browser.close()
