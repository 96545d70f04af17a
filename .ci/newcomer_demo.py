"""The README's first command as a new user runs it, on a machine that has never seen trainclimate.

``make demo`` with ``HOME`` pointing at a directory that does not exist yet and no
``TRAINCLIMATE_*`` variable set; it must print its URL and an operator token within 15 s of the
install finishing (make echoes the serve command when the install is done), the URL opened in
Chromium with nothing typed must show the fleet overview with its charts within a minute, the
token must read the fleet, and an activated coach must get its first DDPC setpoint within 5 min.
Then the demo is stopped with Ctrl-C. Exit 1 with the demo's output on any failure. Standard
library only: this runs before anything is installed (the browser is driven by the Playwright
that ``make demo`` installs into ``.venv``).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
URL_WITHIN_S = 15.0
DDPC_WITHIN_S = 300.0
INSTALL_WITHIN_S = 900.0
OVERVIEW_WITHIN_S = 60.0
CHROMIUM = Path("/usr/bin/chromium")
#: Opens the printed URL (argv[1]) and waits for the overview's charts to have data.
OPEN_OVERVIEW = """
import sys
from playwright.sync_api import sync_playwright
with sync_playwright() as p:
    args = ["--no-sandbox", "--disable-gpu"]
    b = p.chromium.launch(executable_path="/usr/bin/chromium", args=args)
    page = b.new_page()
    page.goto(sys.argv[1])
    page.wait_for_function(
        "() => ['#energy-figure', '#savings-figure']"
        ".every((s) => (document.querySelector(s) || {}).data)",
        timeout=float(sys.argv[2]) * 1000,
    )
    assert "token" not in page.url, page.url
    b.close()
"""


def fail(message: str, log: list[str]) -> None:
    print(f"newcomer: FAILED: {message}", file=sys.stderr)
    print("newcomer: the demo's output:\n" + "".join(log[-80:]), file=sys.stderr)
    sys.exit(1)


def get(url: str, token: str | None = None):
    request = urllib.request.Request(url)
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    with urllib.request.urlopen(request, timeout=10) as reply:
        return json.load(reply)


def main() -> None:
    home = Path(tempfile.mkdtemp(prefix="newcomer-")) / "home-that-does-not-exist"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    env["HOME"] = str(home)
    env.pop("XDG_CACHE_HOME", None)
    started = time.monotonic()
    demo = subprocess.Popen(
        ["make", "demo"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    log: list[str] = []
    seen: dict[str, float] = {}

    def read() -> None:
        for line in demo.stdout:
            log.append(line)
            now = time.monotonic()
            if "trainclimate serve" in line and "installed" not in seen:
                seen["installed"] = now
            if (m := re.match(r"dashboard: (\S+)", line)) and "url" not in seen:
                seen["url"], seen["url_text"] = now, m.group(1)
            if (m := re.match(r"operator token: (\S+)", line)) and "token" not in seen:
                seen["token"], seen["token_text"] = now, m.group(1)

    threading.Thread(target=read, daemon=True).start()
    try:
        while "installed" not in seen:
            if demo.poll() is not None or time.monotonic() - started > INSTALL_WITHIN_S:
                fail("make demo did not get to the serve command", log)
            time.sleep(0.2)
        installed = seen["installed"]
        print(f"newcomer: install done after {installed - started:.0f} s", file=sys.stderr)
        while "token" not in seen:
            if demo.poll() is not None:
                fail("make demo ended before printing its URL and token", log)
            if time.monotonic() - installed > URL_WITHIN_S:
                fail(f"no URL and token within {URL_WITHIN_S:.0f} s of the install", log)
            time.sleep(0.1)
        url_s = seen["token"] - installed
        base, token = seen["url_text"].split("#")[0].rstrip("/"), seen["token_text"]
        print(f"newcomer: URL and token {url_s:.1f} s after the install", file=sys.stderr)
        if CHROMIUM.exists():
            opened = subprocess.run(
                [
                    ROOT / ".venv/bin/python",
                    "-c",
                    OPEN_OVERVIEW,
                    seen["url_text"],
                    str(OVERVIEW_WITHIN_S),
                ],
                capture_output=True,
                text=True,
            )
            if opened.returncode != 0:
                fail(f"the printed URL did not show the overview's charts: {opened.stderr}", log)
            overview_s = time.monotonic() - installed
            print(
                f"newcomer: overview with its charts {overview_s:.1f} s after the install",
                file=sys.stderr,
            )
        else:
            print(
                f"newcomer: no Chromium at {CHROMIUM}: the overview is not opened", file=sys.stderr
            )
        coaches = get(f"{base}/api/v1/coaches", token)
        active = [c["id"] for c in coaches if c["ddpc_active"]]
        if not active:
            fail(f"the token read no activated coach: {coaches}", log)
        while True:
            sources = {
                cid: get(f"{base}/api/v1/coaches/{cid}/setpoints", token)["source"]
                for cid in active
            }
            if any("ddpc" in s for s in sources.values()):
                break
            if demo.poll() is not None:
                fail("the demo ended before any DDPC setpoint", log)
            if time.monotonic() - installed > DDPC_WITHIN_S:
                health = get(f"{base}/api/v1/health")
                fail(f"no DDPC setpoint within {DDPC_WITHIN_S:.0f} s; health: {health}", log)
            time.sleep(2)
        ddpc_s = time.monotonic() - installed
        print(f"newcomer: first DDPC setpoint {ddpc_s:.0f} s after the install", file=sys.stderr)
        if not (home / ".cache" / "trainclimate" / "trainclimate.db").is_file():
            fail(f"the embedded database is not under {home}/.cache/trainclimate", log)
    finally:
        if demo.poll() is None:
            os.killpg(demo.pid, signal.SIGINT)  # Ctrl-C, as a user stops it
            try:
                demo.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(demo.pid, signal.SIGKILL)
                fail("the demo did not stop on Ctrl-C within 30 s", log)
    print("newcomer: make demo on a fresh home: ok", file=sys.stderr)


if __name__ == "__main__":
    main()
