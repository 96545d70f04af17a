"""The service as real child processes: ``trainclimate serve`` on a port, started and stopped,
killed and restarted; tokens through the console script. Shared by the process tests, the
browser tests and the compose mirror."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from service_support import wait_for

#: ``python -m trainclimate.cli`` (cli.py has the ``__main__`` guard) and the console script.
CLI = [sys.executable, "-m", "trainclimate.cli"]
SCRIPT = Path(sys.executable).with_name("trainclimate")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """``trainclimate serve`` as a child process on a fixed port: started (waiting for
    ``GET /api/v1/health``), stopped (SIGTERM, SIGKILL after a timeout), killed, restarted."""

    def __init__(self, args: list[str], env: dict[str, str], port: int, log: Path):
        self.args, self.env, self.port, self.log = args, env, port, log
        self.url = f"http://127.0.0.1:{port}"
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 60.0) -> Server:
        with self.log.open("ab") as out:
            self.proc = subprocess.Popen(
                self.args, env=self.env, stdout=out, stderr=subprocess.STDOUT
            )
        wait_for(self._healthy, timeout, f"the server on port {self.port}")
        return self

    def _healthy(self) -> bool:
        if self.proc.poll() is not None:
            pytest.fail(f"the server exited with {self.proc.returncode}:\n{self.output()}")
        try:
            return httpx.get(f"{self.url}/api/v1/health", timeout=1.0).status_code == 200
        except httpx.TransportError:
            return False

    def output(self) -> str:
        return self.log.read_text(errors="replace")[-4000:]

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=10)

    def kill(self) -> None:
        """SIGKILL: no shutdown, transactions cut where they are."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)


def token_cli(db_url: str, role: str, env: dict[str, str]) -> str:
    """``trainclimate token create --json`` (the console script): the new token."""
    assert SCRIPT.exists(), f"no console script {SCRIPT}"
    done = subprocess.run(
        [str(SCRIPT), "token", "create", "--db", db_url, "--role", role, "--json"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    reply = json.loads(done.stdout)
    assert reply["role"] == role and reply["token"].startswith("tc_")
    return reply["token"]
