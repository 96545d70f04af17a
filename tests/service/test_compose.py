"""The dockerised demo without a Docker engine: ``docker-compose.yml`` and the ``Dockerfile``
name files that exist and commands the CLI takes; and the same set-up — PostgreSQL, the backend
with its migrations at start, the token step and the three gateway emulators — runs here as
separate processes with the compose file's own commands (only host names, ports, paths and the
run's length changed), end to end over HTTP and, for train 126, over MQTT through a Mosquitto
configured as the compose broker (its ACL, its users)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path
from urllib.parse import urlparse

import httpx
import pytest
import yaml

from helpers.processes import CLI, Mosquitto, Server, free_port
from helpers.service import PG_SKIP, PG_URL, drop_pg_database, pg_database, wait_for
from trainclimate.cli import build_parser
from trainclimate.predict import default as models
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
GATEWAYS = sorted(name for name in SERVICES if name.startswith("gateway-1"))


DOCKERFILE = (ROOT / "Dockerfile").read_text()


def dockerfile_env() -> dict[str, str]:
    """The image's ``ENV`` settings."""
    pairs = re.findall(r"^ENV ((?:.+\\\n)*.+)$", DOCKERFILE, flags=re.MULTILINE)
    words = " ".join(pairs).replace("\\\n", " ").split()
    return dict(w.split("=", 1) for w in words if "=" in w)


def dockerfile_exec(instruction: str) -> list[list[str]]:
    """The exec-form commands (``["a", "b"]``) of every ``instruction`` line (RUN, CMD)."""
    found = re.findall(rf"^{instruction} (\[.+\])$", DOCKERFILE, flags=re.MULTILINE)
    return [yaml.safe_load(text) for text in found]


def option(command: list[str], name: str) -> str:
    return command[command.index(name) + 1]


def replaced(command: list[str], name: str, value: str) -> list[str]:
    out = list(command)
    out[out.index(name) + 1] = value
    return out


def mqtt_users() -> dict[str, str]:
    """The broker's users and passwords, as the ``mqtt-users`` step writes them."""
    step = SERVICES["mqtt-users"]
    found = re.findall(r'mosquitto_passwd (?:-c )?-b \S+ (\S+) "\$\$(\w+)"', step["command"][-1])
    return {user: step["environment"][var] for user, var in found}


def acl_users() -> dict[str, list[str]]:
    """The ACL's users and their topic lines."""
    users: dict[str, list[str]] = {}
    for line in (ROOT / "deploy" / "mosquitto" / "acl").read_text().splitlines():
        if line.startswith("user "):
            current = users.setdefault(line.split()[1], [])
        elif line.startswith("topic "):
            current.append(line)
    return users


def test_the_compose_file_names_what_exists():
    assert set(SERVICES) == {
        "postgres",
        "mqtt-users",
        "mosquitto",
        "backend",
        "gateway-token",
        "metrics-token",
        "prometheus",
        *GATEWAYS,
    }
    assert len(GATEWAYS) == 3
    for name, service in SERVICES.items():
        if "build" in service:
            assert (ROOT / service["build"] / "Dockerfile").exists(), name
        for dependency, rule in service.get("depends_on", {}).items():
            assert dependency in SERVICES, (name, dependency)
            assert rule["condition"] in (
                "service_healthy",
                "service_completed_successfully",
            ), name
            if rule["condition"] == "service_healthy":
                assert "healthcheck" in SERVICES[dependency], dependency
        for volume in service.get("volumes", []):
            source = volume.split(":")[0]
            if source.startswith("./"):  # a file of the repository
                assert (ROOT / source).is_file(), (name, volume)
            else:
                assert source in COMPOSE["volumes"], (name, volume)
    assert SERVICES["postgres"]["healthcheck"]["test"][:2] == ["CMD", "pg_isready"]
    # the backend's health check asks a route the app serves without a token
    probe = " ".join(SERVICES["backend"]["healthcheck"]["test"])
    path = urlparse(re.search(r"http://[^'\"]+", probe).group(0)).path
    app = create_app(Settings(database_url="sqlite://"))
    operation = app.openapi()["paths"][path]["get"]
    assert "security" not in operation, "the health check has no token"
    # the database the services use is the compose PostgreSQL's
    url = urlparse(SERVICES["backend"]["environment"]["TRAINCLIMATE_DATABASE_URL"])
    pg = SERVICES["postgres"]["environment"]
    assert (url.scheme, url.hostname, url.username, url.password, url.path[1:]) == (
        "postgresql",
        "postgres",
        pg["POSTGRES_USER"],
        pg["POSTGRES_PASSWORD"],
        pg["POSTGRES_DB"],
    )


def test_the_dockerfile_copies_what_exists_and_runs_a_valid_command():
    text = (ROOT / "Dockerfile").read_text()
    copies = re.findall(r"^COPY (?!--from=)(.+) \S+$", text, flags=re.MULTILINE)
    sources = [s for line in copies for s in line.split()]
    assert {"requirements.lock", "pyproject.toml", "backend", "migrations", "frontend"} <= set(
        sources
    )
    for source in sources:
        assert (ROOT / source).exists(), source
    # the image is the wheel's, built in the first stage: no source tree in the final stage
    final = text.split("\nFROM ")[-1]
    assert "COPY --from=wheel /dist" in final and "pip install --no-deps /tmp/dist/" in final
    assert not re.search(r"^COPY (backend|migrations|frontend)", final, flags=re.MULTILINE)
    assert "python -m build --wheel" in text and re.search(
        r"^build==", (ROOT / "requirements.lock").read_text(), flags=re.MULTILINE
    )
    [args] = dockerfile_exec("CMD")
    assert args[0] == "trainclimate"
    assert build_parser().parse_args(args[1:]).command == "serve"
    backend = SERVICES["backend"]["command"]
    assert backend[: len(args)] == args, "the compose backend runs the image's command"
    # the image builds its default model at build time, into its home
    [build] = [a for a in dockerfile_exec("RUN") if a[0] == "trainclimate"]
    parsed = build_parser().parse_args(build[1:])
    assert (parsed.command, parsed.predictor_command, parsed.quick) == (
        "predictor",
        "default",
        False,
    )
    assert dockerfile_env()["TRAINCLIMATE_HOME"].startswith("/")


def test_every_compose_command_is_one_the_cli_takes():
    parser = build_parser()
    backend = parser.parse_args(SERVICES["backend"]["command"][1:])
    assert backend.command == "serve" and backend.host == "0.0.0.0"
    token = parser.parse_args(SERVICES["gateway-token"]["command"][1:])
    assert token.role == "gateway" and token.out
    coaches = set()
    for name in GATEWAYS:
        command = SERVICES[name]["command"]
        assert command[0] == "trainclimate"
        args = parser.parse_args(command[1:])
        server = urlparse(args.server)
        assert (server.hostname, server.port) == ("backend", backend.port), name
        assert args.token_file == token.out, name
        assert SERVICES[name]["depends_on"]["gateway-token"]["condition"] == (
            "service_completed_successfully"
        )
        coaches |= set(args.coaches.split(","))
    assert len(coaches) == 6  # three trains, two coaches each, none shared
    assert set(token.coaches.split(",")) == coaches  # the gateways' token: for those, no other


def test_the_broker_users_are_the_acl_users_and_each_gateway_has_its_coaches_only():
    parser = build_parser()
    backend = parser.parse_args(SERVICES["backend"]["command"][1:])
    assert urlparse(backend.mqtt).hostname == "mosquitto"
    users, acl = mqtt_users(), acl_users()
    assert set(users) == set(acl) == {backend.mqtt_username, "gateway-126"}
    env = SERVICES["backend"]["environment"]
    assert env["TRAINCLIMATE_MQTT_PASSWORD"] == users[backend.mqtt_username]
    prefix = backend.mqtt_prefix
    assert acl[backend.mqtt_username] == [
        f"topic read {prefix}/coaches/+/telemetry",
        f"topic write {prefix}/coaches/+/setpoint",
        f"topic write {prefix}/coaches/+/stored",
    ]
    mqtt_gateways = 0
    for name in GATEWAYS:
        args = parser.parse_args(SERVICES[name]["command"][1:])
        if args.mqtt is None:
            continue
        mqtt_gateways += 1
        assert args.mqtt == backend.mqtt and args.mqtt_prefix == prefix
        password = SERVICES[name]["environment"]["TRAINCLIMATE_MQTT_PASSWORD"]
        assert password == users[args.mqtt_username]
        assert sorted(acl[args.mqtt_username]) == sorted(
            f"topic {access} {prefix}/coaches/{coach}/{kind}"
            for coach in args.coaches.split(",")
            for access, kind in (("write", "telemetry"), ("read", "setpoint"), ("read", "stored"))
        )
    assert mqtt_gateways == 1


def compose_env(service: str) -> dict[str, str]:
    """The service's ``environment`` in the compose file (the shared anchor's or its own)."""
    return {k: str(v) for k, v in SERVICES[service].get("environment", {}).items()}


def image_home(tmp_path: Path, model_file: Path) -> Path:
    """The image's ``TRAINCLIMATE_HOME`` re-rooted under ``tmp_path``, as its build leaves it:
    nothing but the default model that ``trainclimate predictor default`` writes (the test's
    small model in its place: the real build takes minutes)."""
    home = tmp_path / "image" / dockerfile_env()["TRAINCLIMATE_HOME"].lstrip("/")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TRAINCLIMATE_HOME", str(home))
        target = models.default_model_path()
    target.parent.mkdir(parents=True)
    shutil.copy(model_file, target)
    return home


def test_the_compose_setup_runs_as_local_processes(tmp_path, small_predictor_file, proc_env):
    """PostgreSQL (a fresh database on the test server) + the backend (the image's command, its
    environment and its home with the model its build made) + the token step + the three
    gateways as child processes: the backend registers the image's model, every minute of every
    coach is stored, the layer is on in coach A only, and the pair comparison of every train is
    answered."""
    if not PG_URL:
        pytest.skip(PG_SKIP)
    db_url, db_name = pg_database()
    home = image_home(tmp_path, small_predictor_file)
    image_env = {**dockerfile_env(), "TRAINCLIMATE_HOME": str(home)}
    env = {**proc_env, **image_env, "TRAINCLIMATE_DATABASE_URL": db_url}
    port = free_port()
    broker = Mosquitto(tmp_path / "mosquitto", mqtt_users())  # the compose broker's config
    backend = SERVICES["backend"]["command"]
    backend = replaced(backend, "--host", "127.0.0.1")
    backend = replaced(backend, "--port", str(port))
    backend = replaced(backend, "--mqtt", broker.url)
    backend_env = {**env, **compose_env("backend"), "TRAINCLIMATE_DATABASE_URL": db_url}
    server = Server([*CLI, *backend[1:]], backend_env, port, tmp_path / "backend.log")
    gateways: list[subprocess.Popen] = []
    try:
        server.start()  # the compose health check: /ready answers once migrated
        wait_for(lambda: httpx.get(f"{server.url}/api/v1/ready").status_code == 200, 30, "ready")
        health = f"{server.url}/api/v1/health"
        wait_for(lambda: httpx.get(health).json()["preparing"] == [], 30, "the image's model")
        token_file = tmp_path / "run" / "token"
        step = replaced(SERVICES["gateway-token"]["command"], "--out", str(token_file))
        done = subprocess.run(
            [*CLI, *step[1:]], env=env, capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        assert token_file.stat().st_mode & 0o077 == 0  # owner only
        hours, minutes = 1.5, 90
        for name in GATEWAYS:
            command = replaced(SERVICES[name]["command"], "--server", server.url)
            command = replaced(command, "--token-file", str(token_file))
            # the live fleet has one clock, the newest row of any gateway, and waits 4 minutes
            # of it for a late coach's row at a tick: emulators that start a second or two
            # apart must stay closer than that, so 90× (1.5–3 simulated minutes), not faster
            command = replaced(command, "--speedup", "90")
            gateway_env = {**env, **compose_env(name), "TRAINCLIMATE_DATABASE_URL": db_url}
            if "--mqtt" in command:
                command = replaced(command, "--mqtt", broker.url)
            log = (tmp_path / f"{name}.log").open("wb")
            gateways.append(
                subprocess.Popen(
                    [*CLI, *command[1:], "--hours", str(hours)],
                    env=gateway_env,
                    stdout=log,
                    stderr=log,
                )
            )
        for name, proc in zip(GATEWAYS, gateways, strict=True):
            assert proc.wait(timeout=240) == 0, (tmp_path / f"{name}.log").read_text()

        api = f"{server.url}/api/v1"
        gateway = {"Authorization": f"Bearer {token_file.read_text().strip()}"}
        # the gateways' token reads nothing: the checks below use a viewer's
        assert httpx.get(f"{api}/coaches", headers=gateway).status_code == 403
        viewer = subprocess.run(
            [*CLI, "token", "create", "--role", "viewer", "--json"],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert viewer.returncode == 0, viewer.stderr
        headers = {"Authorization": f"Bearer {json.loads(viewer.stdout)['token']}"}
        [model] = httpx.get(f"{api}/models", headers=headers).json()
        assert model["info"]["source"] == "default model, prepared at start"
        reply = httpx.get(f"{api}/coaches", headers=headers)
        assert reply.status_code == 200, reply.text
        coaches = reply.json()
        assert sorted(c["id"] for c in coaches) == [
            f"{t}-{s}" for t in (124, 125, 126) for s in "AB"
        ]
        for c in coaches:
            ts = httpx.get(f"{api}/coaches/{c['id']}/timeseries", headers=headers).json()
            assert len(ts["time"]) == minutes, c["id"]
            sp = httpx.get(f"{api}/coaches/{c['id']}/setpoints", headers=headers).json()
            reasons = set(sp["reason"])
            # the gateways start a second or two apart: the live clock can run ahead of the last
            # one started, whose first tick may be stale
            if c["id"].endswith("-A"):
                assert c["ddpc_active"] and "ddpc" in sp["source"], (c["id"], reasons)
            else:
                assert not c["ddpc_active"] and "inactive" in reasons, (c["id"], reasons)
                assert reasons <= {"inactive", "stale"}, (c["id"], reasons)
        # train 126's rows came through the broker, each stored once, nothing dropped (a
        # confirmation slower than the gateway's wait has it send its oldest row again, which
        # the service counts as a duplicate and does not store: the outcome is judged)
        feed = httpx.get(health).json()["mqtt"]
        assert (feed["rows_stored"], feed["dropped"]) == (2 * minutes, {})
        assert feed["connected"] and feed["setpoints_published"] > 0
        for train in ("124", "125", "126"):
            reply = httpx.get(f"{api}/trains/{train}/comparison", headers=headers)
            assert reply.status_code == 200, reply.text
            cmp = reply.json()
            assert (cmp["activated"], cmp["deactivated"]) == (f"{train}-A", f"{train}-B")
            assert cmp["energy_activated_kwh"] > 0 and cmp["energy_deactivated_kwh"] > 0
    finally:
        for proc in gateways:
            if proc.poll() is None:
                proc.kill()
        server.stop()
        broker.stop()
        drop_pg_database(db_name)
