"""The service as real child processes: ``trainclimate serve`` on a port, started and stopped,
killed and restarted; tokens through the console script; a private Mosquitto broker. Shared by
the process tests, the browser tests and the compose mirror."""

from __future__ import annotations

import getpass
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from helpers.service import wait_for

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

    def printed(self, pattern: str, timeout: float = 15.0) -> re.Match:
        """The first match of ``pattern`` in the server's output, once it is printed (the URL
        and token lines follow the first answer by a moment)."""
        return wait_for(
            lambda: re.search(pattern, self.output()), timeout, f"{pattern!r} in the output"
        )

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


def child_env(home: Path) -> dict[str, str]:
    """A child's environment: none of the ``TRAINCLIMATE_*`` variables from outside, ``home`` as
    ``TRAINCLIMATE_HOME``, its output unbuffered."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    return env | {"TRAINCLIMATE_HOME": str(home), "PYTHONUNBUFFERED": "1"}


def serve_args(port: int, *options: str) -> list[str]:
    """The command of ``trainclimate serve`` on ``port`` with ``options``."""
    return [*CLI, "serve", "--port", str(port), *options]


def sqlite_server(home: Path, model_file: Path | str, *extra: str) -> Server:
    """``serve`` on a SQLite file in ``home`` (its ``db_url``) with the predictor ``model_file``
    (``extra`` appended to the command), started in :func:`child_env` of ``home``, its output in
    ``home``/server.log."""
    db_url = f"sqlite:///{home / 'trainclimate.db'}"
    port = free_port()
    args = serve_args(port, "--db", db_url, "--predictor", str(model_file), *extra)
    srv = Server(args, child_env(home), port, home / "server.log")
    srv.db_url = db_url
    srv.start()
    return srv


def demo_server(home: Path, model_file: Path | str, *extra: str) -> Server:
    """:func:`sqlite_server` of ``serve --fleet demo --speedup 600`` (``extra`` appended)."""
    return sqlite_server(home, model_file, "--fleet", "demo", "--speedup", "600", *extra)


def wait_for_ddpc(srv: Server, token: str, coach: str = "D1-A", n: int = 20) -> None:
    """Wait (at most 120 s) until ``coach`` has ``n`` DDPC setpoints."""

    def predicted() -> bool:
        reply = httpx.get(
            f"{srv.url}/api/v1/coaches/{coach}/setpoints",
            headers={"Authorization": f"Bearer {token}"},
        )
        return sum(s == "ddpc" for s in reply.json()["source"]) >= n

    wait_for(predicted, 120, f"{n} DDPC setpoints of {coach}")


def token_cli(db_url: str, role: str, env: dict[str, str], *options: str) -> str:
    """``trainclimate token create --role ROLE [OPTIONS…] --json`` (the console script): the new
    token."""
    assert SCRIPT.exists(), f"no console script {SCRIPT}"
    done = subprocess.run(
        [str(SCRIPT), "token", "create", "--db", db_url, "--role", role, *options, "--json"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    reply = json.loads(done.stdout)
    assert reply["role"] == role and reply["token"].startswith("tc_")
    return reply["token"]


#: The compose demo's broker configuration (Mosquitto's config and ACL).
MOSQUITTO_DEPLOY = Path(__file__).resolve().parents[2] / "deploy" / "mosquitto"
#: Where Debian installs Mosquitto's dynamic security plugin.
DYNSEC_PLUGIN = Path("/usr/lib/x86_64-linux-gnu/mosquitto_dynamic_security.so")


class Mosquitto:
    """A private Mosquitto broker (the machine's ``mosquitto``) on a free port, configured as
    ``deploy/mosquitto/{config}`` says (the compose demo's: no anonymous users, its ACL) with
    ``users`` {name: password} in a password file that ``mosquitto_passwd`` writes, or — with
    ``admin`` (name, password) — the dynamic security plugin, its file made by ``mosquitto_ctrl
    dynsec init``; ``settings`` replace or add lines of the config; its paths under ``tmp``.
    It can be killed (SIGKILL) and started again on the same port with the same data."""

    def __init__(
        self,
        tmp: Path,
        users: dict[str, str] | None = None,
        *,
        config: str = "mosquitto.conf",
        admin: tuple[str, str] | None = None,
        settings: dict[str, str] | None = None,
    ):
        if not (shutil.which("mosquitto") or Path("/usr/sbin/mosquitto").exists()):
            pytest.skip("no mosquitto binary on this machine (apt-get install mosquitto)")
        self.port = free_port()
        self.url = f"mqtt://127.0.0.1:{self.port}"
        self.tmp = tmp
        tmp.mkdir(parents=True, exist_ok=True)
        (tmp / "data").mkdir(exist_ok=True)
        where = {
            "listener": f"{self.port} 127.0.0.1",
            "password_file": str(self._passwords(users or {})),
            "acl_file": str(tmp / "acl"),
            "persistence_location": f"{tmp / 'data'}/",
            "plugin": str(DYNSEC_PLUGIN),
            "plugin_opt_config_file": str(tmp / "dynamic-security.json"),
            **(settings or {}),
        }
        shutil.copy(MOSQUITTO_DEPLOY / "acl", tmp / "acl")
        if admin is not None:
            if not DYNSEC_PLUGIN.exists():
                pytest.skip(f"no dynamic security plugin at {DYNSEC_PLUGIN}")
            init = [str(tmp / "dynamic-security.json"), *admin]
            subprocess.run(
                ["mosquitto_ctrl", "dynsec", "init", *init], check=True, capture_output=True
            )
        lines = []
        for line in (MOSQUITTO_DEPLOY / config).read_text().splitlines():
            key = line.split(" ", 1)[0]
            lines.append(f"{key} {where.pop(key)}" if key in where else line)
        lines += [f"{key} {value}" for key, value in (settings or {}).items() if key in where]
        lines.append(f"user {getpass.getuser()}")  # as root it would switch to "mosquitto"
        (tmp / "mosquitto.conf").write_text("\n".join(lines) + "\n")
        self.log = tmp / "mosquitto.log"
        self.start()

    def _passwords(self, users: dict[str, str]) -> Path:
        passwd = self.tmp / "passwd"
        for i, (name, password) in enumerate(users.items()):
            create = ["-c"] if i == 0 else []
            subprocess.run(
                ["mosquitto_passwd", *create, "-b", str(passwd), name, password], check=True
            )
        return passwd

    def start(self) -> Mosquitto:
        """Start the broker (again) and wait until it listens."""
        binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        with self.log.open("ab") as out:
            self.proc = subprocess.Popen(
                [binary, "-c", str(self.tmp / "mosquitto.conf")],
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        wait_for(self._listening, 10, f"mosquitto on port {self.port}")
        return self

    def _listening(self) -> bool:
        if self.proc.poll() is not None:
            pytest.fail(f"mosquitto exited: {self.log.read_text(errors='replace')}")
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
            return True
        except OSError:
            return False

    def ctrl(self, admin: tuple[str, str], *command: str) -> str:
        """``mosquitto_ctrl dynsec COMMAND…`` against this broker as ``admin``: its output."""
        connect = ["-h", "127.0.0.1", "-p", str(self.port), "-u", admin[0], "-P", admin[1]]
        done = subprocess.run(
            ["mosquitto_ctrl", *connect, "dynsec", *command],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert done.returncode == 0 and "Error" not in done.stdout, done.stdout + done.stderr
        return done.stdout

    def kill(self) -> None:
        """SIGKILL: nothing saved that was not saved already."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
