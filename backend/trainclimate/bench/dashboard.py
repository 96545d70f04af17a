"""``bench dashboard``: the operator dashboard's weight in a real browser (Playwright driving
Chromium, ``/usr/bin/chromium`` unless told otherwise) against a running service.

- **first load**: the bytes transferred (compressed, as on the wire: Chromium's
  ``encodedDataLength``, its cache off) and the requests, from opening the page signed in until
  the overview's charts are drawn;
- **again**: the same with the browser's cache kept (what a reload costs);
- **idle**: the requests a minute while the page sits on the overview, and on a coach's page,
  over ``idle_s`` seconds each.

Targets: a first load of at most 1.5 MB, an idle overview of at most 12 requests a minute.
Needs the ``playwright`` package (a test dependency) and a Chromium.
"""

from __future__ import annotations

import time
from pathlib import Path

#: The largest first load [bytes] and the most requests a minute of an idle overview.
TARGET = {"first_load_bytes": 1_500_000, "idle_overview_requests_per_min": 12}
CHROMIUM = Path("/usr/bin/chromium")
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"]
DRAWN = "() => (document.querySelector('#savings-figure')?.data || []).length > 0"


class DashboardBenchError(RuntimeError):
    """``bench dashboard`` could not run (no Playwright or Chromium, the page did not load)."""


def _load(context, url: str, token: str, cache: bool) -> dict:
    """Opens ``url`` signed in with ``token`` (its ``#token=`` URL) until the overview is drawn;
    the bytes transferred and the requests made. [bytes]"""
    page = context.new_page()
    cdp = context.new_cdp_session(page)
    cdp.send("Network.enable")
    cdp.send("Network.setCacheDisabled", {"cacheDisabled": not cache})
    sizes: dict[str, float] = {}
    cdp.on(
        "Network.loadingFinished",
        lambda e: sizes.__setitem__(e["requestId"], e["encodedDataLength"]),
    )
    page.goto(f"{url}/#token={token}")
    page.wait_for_function(DRAWN, timeout=60_000)
    page.wait_for_load_state("networkidle")
    page.close()
    return {"bytes": int(sum(sizes.values())), "requests": len(sizes)}


def _idle(context, url: str, token: str, hash_: str, seconds: float) -> float:
    """The requests a minute the page makes while it sits on ``hash_`` (signed in with ``token``:
    a new tab has no session yet), over ``seconds``."""
    page = context.new_page()
    page.goto(f"{url}/#token={token}")
    page.wait_for_function(DRAWN, timeout=60_000)
    page.evaluate("(h) => { location.hash = h; }", hash_)
    page.wait_for_load_state("networkidle")
    time.sleep(2)
    seen: list[str] = []
    page.on("request", lambda r: seen.append(r.url))
    time.sleep(seconds)
    page.close()
    return len(seen) * 60.0 / seconds


def run(
    url: str,
    token: str,
    idle_s: float = 60.0,
    chromium: Path = CHROMIUM,
    progress=None,
    browser=None,
) -> dict:
    """The dashboard at ``url`` (a running service; ``token`` a viewer's or better): first load
    [bytes, requests], a reload with the cache kept, idle requests a minute on the overview and
    on coach D1-A's page over ``idle_s`` [s] each. ``browser``: a Playwright Chromium already
    launched (else one is, from ``chromium``)."""
    if browser is not None:
        return _measure(browser, url.rstrip("/"), token, idle_s, progress)
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        raise DashboardBenchError("bench dashboard needs the playwright package") from exc
    if not chromium.exists():
        raise DashboardBenchError(f"no Chromium at {chromium}")
    with sync_playwright() as p:
        launched = p.chromium.launch(executable_path=str(chromium), headless=True, args=ARGS)
        try:
            return _measure(launched, url.rstrip("/"), token, idle_s, progress)
        finally:
            launched.close()


def _measure(browser, url: str, token: str, idle_s: float, progress) -> dict:
    step = progress or (lambda *a: None)
    context = browser.new_context(viewport={"width": 1440, "height": 900})
    try:
        first = _load(context, url, token, cache=False)
        step(1)
        again = _load(context, url, token, cache=True)
        step(1)
        overview = _idle(context, url, token, "#/", idle_s)
        step(1)
        coach = _idle(context, url, token, "#/coach/D1-A", idle_s)
        step(1)
    finally:
        context.close()
    data = {
        "url": url,
        "first_load_bytes": first["bytes"],
        "first_load_requests": first["requests"],
        "reload_bytes": again["bytes"],
        "reload_requests": again["requests"],
        "idle_s": idle_s,
        "idle_overview_requests_per_min": round(overview, 1),
        "idle_coach_requests_per_min": round(coach, 1),
        "target": TARGET,
    }
    data["target_met"] = (
        data["first_load_bytes"] <= TARGET["first_load_bytes"]
        and data["idle_overview_requests_per_min"] <= TARGET["idle_overview_requests_per_min"]
    )
    return data


def text(d: dict) -> str:
    """The figures in words."""
    return (
        f"dashboard at {d['url']}\n"
        f"first load: {d['first_load_bytes'] / 1e6:.2f} MB transferred in "
        f"{d['first_load_requests']} requests\n"
        f"reload (cache kept): {d['reload_bytes'] / 1e3:.0f} kB in "
        f"{d['reload_requests']} requests\n"
        f"idle ({d['idle_s']:g} s each): overview {d['idle_overview_requests_per_min']:g} "
        f"requests/min, coach page {d['idle_coach_requests_per_min']:g} requests/min"
    )
