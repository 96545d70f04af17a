"""Database engines and sessions (SQLAlchemy 2.0), and the schema through Alembic.

SQLite (the embedded default) and PostgreSQL (psycopg 3) take the same code. The schema is only
ever created by the Alembic migrations in ``migrations/`` (shipped in the package), applied at
start (:func:`migrate`).

The connection pool is sized to the threads that use it, on both: the server's worker threads
(``worker_threads`` of the settings, which also sets anyio's limit on the threads running the
sync routes) plus :data:`BACKGROUND_THREADS`. A request holds at most one connection at a time,
so with at most ``worker_threads`` requests admitted at once
(:class:`~trainclimate.service.api.hardening.Admission`) no thread waits for one; if one still
does for :data:`POOL_TIMEOUT_S`, the request answers 503 with ``Retry-After``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker

from trainclimate.paths import sqlite_file, writable_dir
from trainclimate.resources import migrations_dir

#: The Alembic migrations, shipped in the package (:mod:`trainclimate.resources`; in a checkout
#: the top-level ``migrations/`` directory).
MIGRATIONS = migrations_dir().resolve()
#: The server's worker threads by default (anyio's own default is 40). The requests are mostly
#: Python work under one GIL: more threads add no throughput on 2 cores, only contention, which
#: delays the event loop and takes CPU time from the control loop's threads (docs/benchmarks.md,
#: "Service under load").
WORKER_THREADS = 8
#: The service's own threads that hold a connection, one each: the live loop, the demo fleet, the
#: model preparation and the MQTT bridge.
BACKGROUND_THREADS = 4
#: Connections beyond the pool, for what the admission does not count (readiness probes) and to
#: spare. [connections]
POOL_OVERFLOW = 10
#: How long a thread waits for a connection before the request answers 503. [s]
POOL_TIMEOUT_S = 10.0


def normalise_url(url: str) -> str:
    """``postgresql://`` and ``postgres://`` mean psycopg 3 here."""
    for prefix in ("postgresql://", "postgres://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix) :]
    return url


def pool_options(worker_threads: int) -> dict:
    """The pool of a server with ``worker_threads``: a connection for each of them and for each
    of :data:`BACKGROUND_THREADS`, :data:`POOL_OVERFLOW` more at a pinch, and
    :data:`POOL_TIMEOUT_S` of waiting for one."""
    return {
        "pool_size": worker_threads + BACKGROUND_THREADS,
        "max_overflow": POOL_OVERFLOW,
        "pool_timeout": POOL_TIMEOUT_S,
    }


def make_engine(url: str, worker_threads: int = WORKER_THREADS) -> Engine:
    """An engine for ``url`` with its pool sized to ``worker_threads`` (:func:`pool_options`;
    an in-memory SQLite database keeps SQLAlchemy's one connection per thread). SQLite gets
    foreign keys, WAL and a busy timeout, so the scheduler thread and the API share one file
    safely."""
    url = normalise_url(url)
    pool = pool_options(worker_threads)
    if url.startswith("sqlite"):
        sqlite_directory(url)
        engine = create_engine(
            url,
            connect_args={"check_same_thread": False, "timeout": 30},
            **(pool if sqlite_file(url) is not None else {}),
        )

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_connection, _record):  # pragma: no cover - driver callback
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.close()

        return engine
    return create_engine(url, pool_pre_ping=True, **pool)


def sqlite_directory(url: str) -> None:
    """Create the directory of a SQLite database file with its parents (a one-line
    :class:`~trainclimate.paths.StorageError` when it cannot be)."""
    path = sqlite_file(url)
    if path is not None:
        writable_dir(path.parent, "the SQLite database's directory")


def alembic_config(url: str):
    """The Alembic configuration of ``migrations/`` for the database at ``url``."""
    from alembic.config import Config

    sqlite_directory(url)

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.set_main_option("sqlalchemy.url", normalise_url(url).replace("%", "%%"))
    return cfg


def migrate(url: str, revision: str = "head") -> None:
    """Bring the database at ``url`` to ``revision`` (default: the newest)."""
    from alembic import command

    command.upgrade(alembic_config(url), revision)


def head_revision() -> str:
    """The newest revision of ``migrations/`` (what :func:`migrate` brings a database to)."""
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    return ScriptDirectory.from_config(cfg).get_current_head()


def downgrade(url: str, revision: str = "base") -> None:
    """Take the database at ``url`` back to ``revision`` (default: empty)."""
    from alembic import command

    command.downgrade(alembic_config(url), revision)


class Database:
    """An engine (its pool sized to ``worker_threads``, :func:`make_engine`) and its session
    factory."""

    def __init__(self, url: str, worker_threads: int = WORKER_THREADS):
        self.url = normalise_url(url)
        self.engine = make_engine(self.url, worker_threads)
        self.sessions = sessionmaker(self.engine, expire_on_commit=False)

    @property
    def dialect(self) -> str:
        """The database's kind: ``sqlite`` or ``postgresql``."""
        return self.engine.dialect.name

    @contextmanager
    def transaction(self) -> Iterator[Session]:
        """A session whose work is committed together at the end, or not at all."""
        with self.sessions() as session, session.begin():
            yield session

    def dispose(self) -> None:
        """Close the engine's pooled connections."""
        self.engine.dispose()
