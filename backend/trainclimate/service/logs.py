"""The service's log lines: text for a terminal (the default), or one JSON object a line for a log
store (``trainclimate serve --log-format json``).

A JSON line holds ``time`` (UTC, ISO 8601 with milliseconds), ``level``, ``logger``, ``message``
and ``replica``, and where they apply ``request_id`` (the HTTP request being answered:
:mod:`trainclimate.service.api.observe`), ``coach`` and ``tick`` (the scheduler's tick and the
coach it is deciding for) and ``exception`` (the traceback). Those three come from context
variables set around the work (:func:`context`), so every line written inside carries them —
uvicorn's access lines included, which are written while the request's answer is sent.
"""

from __future__ import annotations

import json
import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from datetime import UTC, datetime

#: The HTTP request being answered (its ``X-Request-ID``).
request_id: ContextVar[str | None] = ContextVar("request_id", default=None)
#: The coach the scheduler is deciding for.
coach: ContextVar[str | None] = ContextVar("coach", default=None)
#: The tick the scheduler is issuing (ISO 8601).
tick: ContextVar[str | None] = ContextVar("tick", default=None)
FORMATS = ("text", "json")
_FIELDS = {"request_id": request_id, "coach": coach, "tick": tick}


@contextmanager
def context(**values: str | None) -> Iterator[None]:
    """Set ``request_id``, ``coach`` or ``tick`` for the log lines written inside."""
    tokens = [(_FIELDS[name], _FIELDS[name].set(value)) for name, value in values.items()]
    try:
        yield
    finally:
        for var, token in reversed(tokens):
            var.reset(token)


class JsonFormatter(logging.Formatter):
    """A record as one JSON object (see the module docstring), for ``replica``."""

    def __init__(self, replica: str):
        super().__init__()
        self.replica = replica

    def format(self, record: logging.LogRecord) -> str:
        at = datetime.fromtimestamp(record.created, UTC)
        out = {
            "time": at.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
            "replica": self.replica,
        }
        for name, var in _FIELDS.items():
            value = getattr(record, name, None) or var.get()
            if value is not None:
                out[name] = str(value)
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out, ensure_ascii=False, default=str)


class StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is when a line is written, not the one at
    its creation: a thread still logging after a command run in-process has returned (and its
    captured stderr closed) writes to the process's stderr instead of failing."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _value) -> None:
        pass


def configure(log_format: str, level: str, replica: str) -> dict | None:
    """Set the process's logging up for ``serve``: with ``json``, every logger (the service's,
    uvicorn's and its access lines, the libraries') writes :class:`JsonFormatter` lines to
    stderr at ``level`` (uvicorn's names: ``info``, ``warning``, …), and None is returned (uvicorn
    must then leave logging alone: ``log_config=None``); with ``text``, nothing changes and
    uvicorn's own configuration is returned (its default)."""
    if log_format not in FORMATS:
        raise ValueError(f"log format must be one of {', '.join(FORMATS)}")
    if log_format == "text":
        from uvicorn.config import LOGGING_CONFIG

        return LOGGING_CONFIG
    handler = StderrHandler()
    handler.setFormatter(JsonFormatter(replica))
    logging.basicConfig(level=logging.WARNING, handlers=[handler], force=True)
    numeric = logging.getLevelName(level.upper())
    for name in ("uvicorn", "uvicorn.error", "uvicorn.access"):
        logger = logging.getLogger(name)
        logger.handlers.clear()
        logger.propagate = True
        logger.setLevel(numeric)
    # the service's own news (INFO) as in text, unless a lower level is asked for
    logging.getLogger("trainclimate").setLevel(min(numeric, logging.INFO))
    return None
