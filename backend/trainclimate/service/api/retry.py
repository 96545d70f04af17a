"""Requests whose transaction lost a race are run again, not answered with an error.

On PostgreSQL two writers can meet in a deadlock (SQLSTATE 40P01) or, at a stricter isolation
level, a serialization failure (40001); the database then rolls one transaction back and
expects it to be retried. The app's handler for database errors (:func:`database_error`)
marks such an answer with :data:`RETRY_HEADER`; :class:`RetryConflicts`, which keeps the request's
body, runs the request again (the whole route: its transaction is new each time) up to
``attempts`` times with a short back-off, and only then sends the 503 with ``Retry-After`` —
without the mark. Any other database error is the 503 of a database that does not answer.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from sqlalchemy.exc import OperationalError
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger(__name__)

#: SQLSTATEs of a transaction rolled back because it lost a race: serialization failure and
#: deadlock (PostgreSQL's class 40, "transaction rollback").
TRANSIENT_SQLSTATES = {"40001", "40P01"}
#: The mark of an answer whose request may be run again (never sent to a client).
RETRY_HEADER = b"x-trainclimate-retry"
#: Runs of a request in all, at most. [-]
ATTEMPTS = 4
#: Back-off before the second run; doubled for each further one. [s]
FIRST_BACKOFF_S = 0.02


def lost_a_race(exc: BaseException) -> bool:
    """Whether ``exc`` is a transaction rolled back for a serialization failure or deadlock."""
    orig = getattr(exc, "orig", None)
    return getattr(orig, "sqlstate", None) in TRANSIENT_SQLSTATES


def database_error(retry_after_s: int) -> Callable[[Request, Exception], JSONResponse]:
    """The handler of :class:`~sqlalchemy.exc.OperationalError`: 503 ``{"detail": the error's
    first line}`` with ``Retry-After: retry_after_s``, marked for :class:`RetryConflicts` when
    the transaction lost a race."""

    def handler(_request: Request, exc: Exception) -> JSONResponse:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        headers = {"Retry-After": str(retry_after_s)}
        if isinstance(exc, OperationalError) and lost_a_race(exc):
            headers[RETRY_HEADER.decode()] = "1"
        return JSONResponse({"detail": message}, status_code=503, headers=headers)

    return handler


class RetryConflicts:
    """Runs an API request again when its answer carries :data:`RETRY_HEADER` (see the module
    docstring), at most ``attempts`` times in all; counts the runs again in ``retried``."""

    def __init__(self, app: ASGIApp, attempts: int = ATTEMPTS) -> None:
        self.app = app
        self.attempts = attempts
        self.retried = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not scope.get("path", "").startswith("/api/"):
            await self.app(scope, receive, send)
            return
        body = await _whole_body(receive)
        for attempt in range(1, self.attempts + 1):
            last = attempt == self.attempts
            again = await self._run(scope, body, receive, send, last)
            if not again:
                return
            self.retried += 1
            log.info("%s %s lost a race in the database; run %d of %d",
                     scope["method"], scope["path"], attempt + 1, self.attempts)  # fmt: skip
            await asyncio.sleep(FIRST_BACKOFF_S * 2 ** (attempt - 1))

    async def _run(
        self, scope: Scope, body: bytes, client: Receive, send: Send, last: bool
    ) -> bool:
        """Run the request once (its kept ``body`` first, then whatever the ``client`` sends,
        e.g. its disconnection); True if it is to be run again (nothing was sent)."""
        replayed = False
        dropped = False

        async def receive() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await client()

        async def forward(message: Message) -> None:
            nonlocal dropped
            if message["type"] == "http.response.start":
                headers = [(k, v) for k, v in message.get("headers", []) if k != RETRY_HEADER]
                dropped = len(headers) < len(message.get("headers", [])) and not last
                message = {**message, "headers": headers}
            if not dropped:
                await send(message)

        await self.app(scope, receive, forward)
        return dropped


async def _whole_body(receive: Receive) -> bytes:
    """The request's body (the body limit outside has bounded it)."""
    chunks = []
    while True:
        message = await receive()
        if message["type"] != "http.request":
            break
        chunks.append(message.get("body", b""))
        if not message.get("more_body", False):
            break
    return b"".join(chunks)
