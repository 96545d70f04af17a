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

**No session waits long on PostgreSQL.** Each connection sets ``lock_timeout``
(:data:`LOCK_TIMEOUT_S` by default) and ``idle_in_transaction_session_timeout``
(:data:`IDLE_IN_TRANSACTION_S`): a statement that waits for a row lock longer fails (the request
answers 503 with ``Retry-After``, a loop retries), and a session that holds its transaction open
without a statement for longer — its process paused (SIGSTOP, a VM migration, a stuck disk) — is
ended by the server, its locks released, so a paused replica cannot hold the others up for
longer than that. The readiness probe has a connection of its own (:meth:`Database.probe`), with
a short ``statement_timeout``, outside the pool the requests use.

**Storage errors** (a full disk, an I/O error, a read-only file) are kept in
:attr:`Database.storage` (:mod:`.storage`) as they happen, on any connection, and cleared by a
write that commits once none has happened for a while.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import Engine, create_engine, event, make_url
from sqlalchemy.orm import Session, sessionmaker

from trainclimate.paths import sqlite_file, writable_dir
from trainclimate.resources import migrations_dir
from trainclimate.service.store.storage import StorageHealth

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
#: How long a PostgreSQL statement waits for a lock before it fails (``lock_timeout``). [s]
LOCK_TIMEOUT_S = 2.0
#: How long a PostgreSQL session may stay idle inside a transaction before the server ends it
#: (``idle_in_transaction_session_timeout``). [s]
IDLE_IN_TRANSACTION_S = 30.0
#: The readiness probe's limit on its statements and on connecting. [s]
PROBE_TIMEOUT_S = 2.0


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


def session_options(url: str, **timeouts_s: float) -> str:
    """libpq ``options`` setting each PostgreSQL parameter of ``timeouts_s`` (name → seconds;
    0: no limit) for every session of a connection, after the ``options`` the URL carries
    (e.g. ``-csearch_path=…``), which they would otherwise replace."""
    own = " ".join(f"-c {name}={round(value * 1000)}" for name, value in timeouts_s.items())
    given = make_url(url).query.get("options")
    given = " ".join(given) if isinstance(given, tuple) else given
    return f"{given} {own}" if given else own


def make_engine(
    url: str,
    worker_threads: int = WORKER_THREADS,
    lock_timeout_s: float = LOCK_TIMEOUT_S,
    idle_in_transaction_s: float = IDLE_IN_TRANSACTION_S,
    application_name: str | None = None,
) -> Engine:
    """An engine for ``url`` with its pool sized to ``worker_threads`` (:func:`pool_options`;
    an in-memory SQLite database keeps SQLAlchemy's one connection per thread). SQLite gets
    foreign keys, WAL and a busy timeout, so the scheduler thread and the API share one file
    safely; PostgreSQL sessions ``lock_timeout_s`` and ``idle_in_transaction_s`` (seconds; 0:
    no limit; see the module docstring) and ``application_name`` (what ``pg_stat_activity``
    shows: which replica holds a lock)."""
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
    options = session_options(
        url, lock_timeout=lock_timeout_s, idle_in_transaction_session_timeout=idle_in_transaction_s
    )
    # times come back in UTC, as Python's own UTC (psycopg's for the session's zone "UTC"):
    # :class:`~.models.UTCDateTime` then takes them as they are (900 coaches' four times a
    # summary; the server's own zone, e.g. Etc/UTC, gave a zoneinfo to convert from)
    connect = {"options": f"{options} -c TimeZone=UTC"}
    if application_name:
        connect["application_name"] = application_name[:63]
    return create_engine(url, pool_pre_ping=True, connect_args=connect, **pool)


def probe_engine(url: str) -> Engine:
    """A PostgreSQL engine of one connection (two at a pinch, waited for 1 s at most) for the
    readiness probe: connecting and each statement limited to :data:`PROBE_TIMEOUT_S`."""
    options = session_options(url, statement_timeout=PROBE_TIMEOUT_S, lock_timeout=PROBE_TIMEOUT_S)
    return create_engine(
        url,
        pool_pre_ping=True,
        pool_size=1,
        max_overflow=1,
        pool_timeout=1.0,
        connect_args={"options": options, "connect_timeout": round(PROBE_TIMEOUT_S)},
    )


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
    """An engine (its pool sized to ``worker_threads``, its PostgreSQL sessions' timeouts in
    seconds and application name: :func:`make_engine`), its session factory and the state of
    its storage (:attr:`storage`)."""

    def __init__(
        self,
        url: str,
        worker_threads: int = WORKER_THREADS,
        lock_timeout_s: float = LOCK_TIMEOUT_S,
        idle_in_transaction_s: float = IDLE_IN_TRANSACTION_S,
        application_name: str | None = None,
    ):
        self.url = normalise_url(url)
        self.engine = make_engine(
            self.url, worker_threads, lock_timeout_s, idle_in_transaction_s, application_name
        )
        self.sessions = sessionmaker(self.engine, expire_on_commit=False)
        self.storage = StorageHealth()
        self.storage.watch(self.engine, self.sessions)
        self._probe: Engine | None = None

    def probe(self) -> Engine:
        """The engine the readiness probe uses: on PostgreSQL one of its own
        (:func:`probe_engine`), which neither waits for the requests' pool nor for long; on
        SQLite the main one (its reads wait for no writer)."""
        if self.dialect != "postgresql":
            return self.engine
        if self._probe is None:
            self._probe = probe_engine(self.url)
        return self._probe

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
        """Close the engines' pooled connections."""
        self.engine.dispose()
        if self._probe is not None:
            self._probe.dispose()
