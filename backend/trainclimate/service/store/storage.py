"""Whether the database can store: a full disk, an I/O error or a read-only file, named.

Reads may go on while writes fail (SQLite on a full disk serves every read). A write that fails
so answers 503 like any database error; :class:`StorageHealth` keeps what failed, in memory, so
that ``GET /api/v1/health`` and ``GET /api/v1/ready`` (and the dashboard) name it
(``{"state": "error", "detail": "database or disk is full", "since": …}``) until a write commits
again with no storage error for :data:`CLEAR_AFTER_S` (``{"state": "ok", …}``): on a disk that is
nearly full a small write may still fit where a larger one fails, and one such write does not
make the disk any less full. It watches an engine: every error of the database driver on any
connection — a request's, a loop's, the MQTT bridge's — is classified (:func:`storage_error`),
and a committed transaction that wrote may clear it.
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime

from sqlalchemy import Engine, event

#: SQLSTATE classes and codes of storage errors on PostgreSQL: 53 insufficient resources
#: (53100 disk full, 53200 out of memory), 58 system errors (58030 I/O error), 25006 a read-only
#: transaction (a standby), XX001/XX002 corrupted data or index.
STORAGE_SQLSTATES = ("53", "58", "25006", "XX001", "XX002")
#: SQLite's messages of storage errors (the start of the driver's message).
SQLITE_STORAGE = (
    "database or disk is full",
    "disk i/o error",
    "attempt to write a readonly database",
    "database disk image is malformed",
    "unable to open database file",
)

#: The storage counts as working again once a write commits this long after the last storage
#: error. [s]
CLEAR_AFTER_S = 30.0


def storage_error(exc: BaseException) -> str | None:
    """The first line of ``exc`` (an error of the database driver) if it says the storage
    failed (:data:`STORAGE_SQLSTATES`, :data:`SQLITE_STORAGE`), else None."""
    text = str(exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    sqlstate = getattr(exc, "sqlstate", None)
    if sqlstate and sqlstate.startswith(STORAGE_SQLSTATES):
        return first
    if first.lower().startswith(SQLITE_STORAGE):
        return first
    return None


@dataclass(frozen=True)
class StorageState:
    """``state`` ``ok`` or ``error``; the error's ``detail`` and ``since`` when it first
    happened (wall time, UTC), None when ok."""

    state: str = "ok"
    detail: str | None = None
    since: datetime | None = None

    def as_dict(self) -> dict:
        return asdict(self)


class StorageHealth:
    """The storage's state (:class:`StorageState`), shared by the threads of a process; an
    error clears once a write commits ``clear_after_s`` seconds or more after the last storage
    error."""

    def __init__(self, clear_after_s: float = CLEAR_AFTER_S) -> None:
        self.clear_after_s = clear_after_s
        self._state = StorageState()
        self._last_error = 0.0  # monotonic [s]
        self._lock = threading.Lock()

    @property
    def state(self) -> StorageState:
        """The current state."""
        return self._state

    def failed(self, detail: str, now: datetime | None = None) -> None:
        """A write failed for lack of storage (``detail``): the state is ``error`` since the
        first such failure (a new ``detail`` replaces the old, ``since`` stays)."""
        with self._lock:
            since = self._state.since if self._state.state == "error" else None
            self._state = StorageState("error", detail, since or now or datetime.now(UTC))
            self._last_error = time.monotonic()

    def wrote(self) -> None:
        """A transaction that wrote has committed: the storage works again if no storage error
        happened for ``clear_after_s``."""
        if self._state.state != "ok":
            with self._lock:
                if time.monotonic() - self._last_error >= self.clear_after_s:
                    self._state = StorageState()

    def watch(self, engine: Engine, sessions) -> None:
        """Classify every driver error of ``engine``; clear the state when a session of
        ``sessions`` (a sessionmaker) that wrote commits."""

        @event.listens_for(engine, "handle_error")
        def _error(context) -> None:  # pragma: no cover - driver callback
            detail = storage_error(context.original_exception)
            if detail is not None:
                self.failed(detail)

        @event.listens_for(sessions, "after_flush")
        def _flushed(session, _context) -> None:
            session.info["wrote"] = True

        @event.listens_for(sessions, "do_orm_execute")
        def _executed(state) -> None:
            if state.is_insert or state.is_update or state.is_delete:
                state.session.info["wrote"] = True

        @event.listens_for(sessions, "after_commit")
        def _committed(session) -> None:
            if session.info.pop("wrote", False):
                self.wrote()

        @event.listens_for(sessions, "after_rollback")
        def _rolled_back(session) -> None:
            session.info.pop("wrote", None)
