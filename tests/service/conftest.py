"""Fixtures of the service tests: a database of each kind (``db_url`` empty, ``app_database`` the
app's, ``database_with_model`` with the small predictor registered), the app, tokens, the service
as child processes (the small predictor's file, ``small_predictor_file``, is tests/conftest.py's).

``db_url`` runs a test on SQLite (a fresh file) and on PostgreSQL (a fresh database created on the
server ``TRAINCLIMATE_TEST_PG_URL`` names, dropped afterwards); without that variable the
PostgreSQL case is skipped with the reason. ``.ci/run`` makes sure a server answers and sets it.
"""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from helpers.processes import Server, child_env, free_port, serve_args
from helpers.service import PG_SKIP, PG_URL, drop_pg_database, pg_database
from trainclimate.service.app import create_app, register_model_file
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


@pytest.fixture
def settings(db_url, small_predictor_file) -> Settings:
    return Settings(
        database_url=db_url, predictor_path=small_predictor_file, scheduler_interval_s=0.05
    )


@pytest.fixture
def sleeping_settings(db_url, small_predictor_file) -> Settings:
    """As :func:`settings`, but the app's live loop runs once at start and then sleeps for an
    hour: the setpoints are the test's, and no tick lands between two of its requests."""
    return Settings(
        database_url=db_url, predictor_path=small_predictor_file, scheduler_interval_s=3600
    )


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


@pytest.fixture
def app_database(client, settings):
    """The app's database (migrated by the app, the small predictor model version 1, active),
    for writing a test's data beside the app."""
    database = Database(settings.database_url)
    yield database
    database.dispose()


@pytest.fixture
def database_with_model(settings):
    """The database of ``settings`` (SQLite or PostgreSQL), migrated, with the small predictor as
    model version 1, and no app: for the scheduler and the stores on their own."""
    migrate(settings.database_url)
    database = Database(settings.database_url)
    with database.transaction() as session:
        register_model_file(session, settings)
    yield database
    database.dispose()


# --- the service as child processes ------------------------------------------------------
@pytest.fixture
def proc_env(tmp_path) -> dict[str, str]:
    """The children's environment: no TRAINCLIMATE_* from outside, a private home."""
    return child_env(tmp_path / "home")


@pytest.fixture
def servers(tmp_path, small_predictor_file, proc_env):
    """A factory of servers on ``db_url``; every one is stopped after the test."""
    made: list[Server] = []

    def make(db_url: str, *extra: str, env: dict[str, str] | None = None, port=None) -> Server:
        port = port or free_port()
        args = serve_args(port, "--db", db_url, "--predictor", str(small_predictor_file), *extra)
        server = Server(args, env or proc_env, port, tmp_path / f"server-{port}.log")
        made.append(server)
        return server

    yield make
    for server in made:
        server.stop()
