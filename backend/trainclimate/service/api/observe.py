"""Every HTTP request observed, outermost of the middleware: its request id (``X-Request-ID``,
taken from the request when it is a sane one, else made here; returned on every answer and set
for the log lines written while it runs, :mod:`trainclimate.service.logs`), its answer counted
by status and its latency measured for the metrics (:class:`~trainclimate.service.metrics.
Metrics`)."""

from __future__ import annotations

import re
import time
import uuid

from starlette.datastructures import Headers, MutableHeaders
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from trainclimate.service.logs import request_id
from trainclimate.service.metrics import Metrics

#: A request id taken from the client: 1 to 128 letters, digits and ``. _ : - + / =`` (UUIDs,
#: W3C trace ids, base64); anything else is replaced by a new one (never echoed into the logs).
REQUEST_ID = re.compile(r"^[A-Za-z0-9._:+/=-]{1,128}$")
HEADER = "X-Request-ID"


def valid_request_id(value: str | None) -> str | None:
    """``value`` if it is a request id to keep (:data:`REQUEST_ID`), else None."""
    return value if value is not None and REQUEST_ID.fullmatch(value) else None


def new_request_id() -> str:
    """A new request id: 32 hex digits (a random UUID)."""
    return uuid.uuid4().hex


class Observe:
    """The request id and the metrics of every HTTP request (see the module docstring)."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        rid = valid_request_id(headers.get(HEADER)) or new_request_id()
        scope.setdefault("state", {})["request_id"] = rid
        started = time.perf_counter()
        status, answered = 500, False

        async def observed_send(message: Message) -> None:
            nonlocal status, answered
            if message["type"] == "http.response.start":
                status, answered = message["status"], True
                MutableHeaders(scope=message)[HEADER] = rid
            await send(message)

        token = request_id.set(rid)
        try:
            await self.app(scope, receive, observed_send)
        except Exception:
            # an error no handler answered: the 500 is sent here, with the request id (Starlette's
            # outermost handler sees the answer started and leaves it; the server logs the error)
            if not answered:
                reply = JSONResponse({"detail": "Internal Server Error"}, status_code=500)
                await reply(scope, receive, observed_send)
            raise
        finally:
            request_id.reset(token)
            self.metrics.answered(
                status,
                time.perf_counter() - started,
                had_token="authorization" in headers,
                path=scope.get("path", ""),
            )
