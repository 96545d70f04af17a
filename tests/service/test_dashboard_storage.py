"""A full disk on the dashboard, in a real browser (Debian's Chromium through Playwright) against
the service served by uvicorn on a port (in this process, so that its SQLite file can be made
full: ``PRAGMA max_page_count`` at its size on every connection): the status banner names the
storage error, without signing in, and is gone once writes commit again."""

from __future__ import annotations

import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import pytest
import uvicorn
from sqlalchemy import event

from helpers.processes import free_port
from helpers.service import API, flat_row, to_wire, wait_for
from trainclimate.service.app import create_app
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token

CHROMIUM = Path("/usr/bin/chromium")


def post(url: str, headers: dict, start: datetime, n: int) -> httpx.Response:
    rows = [to_wire(flat_row(start + timedelta(minutes=m))) for m in range(n)]
    body = {"coach_id": "A", "rows": rows}
    return httpx.post(f"{url}{API}/telemetry", json=body, headers=headers, timeout=30)


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_the_dashboard_names_a_full_disk(settings):
    if not CHROMIUM.exists():
        pytest.skip("no Chromium at /usr/bin/chromium")
    sync_api = pytest.importorskip("playwright.sync_api")
    app = create_app(settings)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    try:
        wait_for(lambda: _answers(url), 60, "the server")
        migrate(settings.database_url)
        db = Database(settings.database_url)
        with db.transaction() as s:
            op = {"Authorization": f"Bearer {create_token(s, 'operator', 'disk-op')[0]}"}
        db.dispose()
        body = {"id": "A", "train_id": "T", "ddpc_active": False}
        assert httpx.post(f"{url}{API}/coaches", json=body, headers=op).status_code == 201
        start = datetime.now(UTC).replace(second=0, microsecond=0) - timedelta(days=3)
        assert post(url, op, start, 10).status_code == 200
        engine = app.state.db.engine
        app.state.db.storage.clear_after_s = 1.0

        def full(dbapi_connection, _record):
            cursor = dbapi_connection.cursor()
            pages = cursor.execute("PRAGMA page_count").fetchone()[0]
            cursor.execute(f"PRAGMA max_page_count = {pages}")
            cursor.close()

        event.listen(engine, "connect", full)
        engine.dispose()
        written = 10
        for _ in range(5):
            reply = post(url, op, start + timedelta(minutes=written), 1440)
            if reply.status_code == 503:
                break
            written += 1440
        assert reply.status_code == 503, reply.text
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=str(CHROMIUM),
                headless=True,
                args=["--no-sandbox", "--disable-gpu"],
            )
            try:
                page = browser.new_page()
                page.goto(f"{url}/")
                banner = page.locator("#preparing")
                banner.wait_for(state="visible", timeout=20_000)
                text = banner.inner_text()
                assert text.startswith("Storage error since ") and "disk is full" in text, text
                assert "failed" in banner.get_attribute("class")
                # room again: a write commits, and the banner goes on reload
                event.remove(engine, "connect", full)
                engine.dispose()
                time.sleep(1.1)
                assert post(url, op, start + timedelta(minutes=written), 5).status_code == 200
                page.reload()
                page.wait_for_load_state("networkidle")
                assert banner.is_hidden()
            finally:
                browser.close()
    finally:
        server.should_exit = True
        thread.join(timeout=30)


def _answers(url: str) -> bool:
    try:
        return httpx.get(f"{url}{API}/health", timeout=1).status_code == 200
    except httpx.TransportError:
        return False
