"""Fixtures of the service tests: a database of each kind, the app, tokens, a small model.

``db_url`` runs a test on SQLite (a fresh file) and on PostgreSQL (a fresh database created on the
server ``TRAINCLIMATE_TEST_PG_URL`` names, dropped afterwards); without that variable the
PostgreSQL case is skipped with the reason. ``.ci/run`` makes sure a server answers and sets it.
"""

from __future__ import annotations

import os

import pytest
from fastapi.testclient import TestClient

from service_processes import CLI, Server, free_port
from service_support import PG_SKIP, PG_URL, drop_pg_database, pg_database
from support import small_predictor
from trainclimate.predict.artifact import save_predictor
from trainclimate.service.app import create_app
from trainclimate.service.settings import Settings
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.tokens import create_token


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request, tmp_path):
    """An empty database: SQLite, then PostgreSQL (skipped without a server)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'trainclimate.db'}"
        return
    if not PG_URL:
        pytest.skip(PG_SKIP)
    url, name = pg_database()
    try:
        yield url
    finally:
        drop_pg_database(name)


@pytest.fixture(scope="session")
def model_file(tmp_path_factory):
    """A small Transient Predictor at the controller's setting, saved (never the default one)."""
    return save_predictor(small_predictor(), tmp_path_factory.mktemp("model") / "transient.npz")


@pytest.fixture
def settings(db_url, model_file) -> Settings:
    return Settings(database_url=db_url, predictor_path=model_file, scheduler_interval_s=0.05)


@pytest.fixture
def sleeping_settings(db_url, model_file) -> Settings:
    """As :func:`settings`, but the app's live loop runs once at start and then sleeps for an
    hour: the setpoints are the test's, and no tick lands between two of its requests."""
    return Settings(database_url=db_url, predictor_path=model_file, scheduler_interval_s=3600)


@pytest.fixture
def client(settings):
    """The app, started (migrations, model, loops) and stopped around the test."""
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture
def tokens(client, settings) -> dict[str, dict[str, str]]:
    """Authorization headers for a viewer, an operator and an admin."""
    migrate(settings.database_url)
    db = Database(settings.database_url)
    out = {}
    with db.transaction() as session:
        for role in ("viewer", "operator", "admin"):
            token, _ = create_token(session, role, f"test-{role}")
            out[role] = {"Authorization": f"Bearer {token}"}
    db.dispose()
    return out


# --- the service as child processes ------------------------------------------------------
@pytest.fixture
def proc_env(tmp_path) -> dict[str, str]:
    """The children's environment: no TRAINCLIMATE_* from outside, a private home."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    env["TRAINCLIMATE_HOME"] = str(tmp_path / "home")
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture
def servers(tmp_path, model_file, proc_env):
    """A factory of servers on ``db_url``; every one is stopped after the test."""
    made: list[Server] = []

    def make(db_url: str, *extra: str, env: dict[str, str] | None = None, port=None) -> Server:
        port = port or free_port()
        args = [
            *CLI,
            "serve",
            "--db",
            db_url,
            "--port",
            str(port),
            "--predictor",
            str(model_file),
            *extra,
        ]
        server = Server(args, env or proc_env, port, tmp_path / f"server-{port}.log")
        made.append(server)
        return server

    yield make
    for server in made:
        server.stop()
