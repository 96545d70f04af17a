"""Hardening of every HTTP exchange, as pure ASGI middleware installed by
:func:`trainclimate.service.app.create_app` (outermost first):

- :class:`SecurityHeaders` — the Content Security Policy and the other security headers on every
  response, the API's and the dashboard's (a 500 included), and ``Cache-Control: no-store`` on
  the API's (a new token's secret among them);
- :class:`AuthFailureThrottle` — after ``auth_failures_burst`` failed authentications (401 to a
  request that carried an ``Authorization`` header) within ``auth_failures_window_s`` from one
  client, that client's requests whose token fails answer 429 (``Retry-After``) until the window
  frees; a valid token is always served, and so are requests without a token (the dashboard's
  files). The client is ``scope["client"]``: the connection's peer, or the address a trusted
  proxy puts in ``X-Forwarded-For`` (uvicorn's ``ProxyHeadersMiddleware``, installed outside
  all of these only for the proxies of ``forwarded_allow_ips``);
- :class:`BodySizeLimit` — a request body over ``max_body_bytes`` answers 413, read off
  ``Content-Length`` when given, else counted while it streams in (chunked), never read whole
  first;
- :class:`RefuseNul` — a NUL character in the path or the query string answers 422;
- :class:`Admission` — at most ``worker_threads`` API requests at once (:class:`Slots`); one
  more waits up to ``overload_wait_s`` for a slot, first come first served, and else answers
  503 with ``Retry-After``, so that an overloaded service says so at once instead of answering
  late or not at all. Liveness and readiness (:data:`UNCOUNTED`) and the dashboard's files are
  not counted.

:func:`pace_threads` sets, at start, how many threads run the requests and how often the
interpreter switches between threads.
"""

from __future__ import annotations

import asyncio
import logging
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from urllib.parse import unquote_to_bytes

from anyio import to_thread
from starlette.datastructures import Headers, MutableHeaders
from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger(__name__)

#: The dashboard loads its script, style and Plotly.js from the same origin and uses no inline
#: script or event handler; inline styles are allowed because Plotly.js sets style attributes
#: (a stricter ``style-src 'self'`` blocks them in the browser); images from ``data:`` and
#: ``blob:`` URLs because Plotly.js draws a chart's PNG download from a blob of its SVG.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; "
    "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
)
SECURITY_HEADERS = {
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
}
#: The API's answers are for one token's holder, and one of them carries a new token's secret
#: (``POST /api/v1/tokens``): no cache, the browser's or a proxy's, may keep any of them.
API_CACHE_CONTROL = "no-store"


class SecurityHeaders:
    """Adds :data:`SECURITY_HEADERS` to every HTTP response, and ``Cache-Control``
    (:data:`API_CACHE_CONTROL`) to every answer under ``/api/``. An exception escaping the app
    before it answered is answered here (500, with the headers) and raised again, so that the
    server still logs it."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def send_with_headers(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                headers = MutableHeaders(scope=message)
                for name, value in SECURITY_HEADERS.items():
                    headers[name] = value
                if scope.get("path", "").startswith("/api/"):
                    headers["Cache-Control"] = API_CACHE_CONTROL
            await send(message)

        try:
            await self.app(scope, receive, send_with_headers)
        except Exception:
            if not started:
                response = JSONResponse({"detail": "Internal Server Error"}, status_code=500)
                await response(scope, receive, send_with_headers)
            raise


class BodyTooLarge(HTTPException):
    """A request body over the limit (413); raised by the counting ``receive``, answered by the
    app's exception handling or else by :class:`BodySizeLimit`."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than {limit} bytes")


class BodySizeLimit:
    """413 for a request body over ``max_bytes``: at once if ``Content-Length`` says so (the app
    is not called), else as soon as the chunks received add up to more."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        error = BodyTooLarge(self.max_bytes)
        response = JSONResponse({"detail": error.detail}, status_code=413)
        await response(scope, receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = Headers(scope=scope).get("content-length")
        if length is not None:
            try:
                too_large = int(length) > self.max_bytes
            except ValueError:
                too_large = False  # the server refuses a malformed Content-Length itself
            if too_large:
                await self._refuse(scope, receive, send)
                return
        received = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise BodyTooLarge(self.max_bytes)
            return message

        async def watching_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, watching_send)
        except BodyTooLarge:
            if started:
                raise
            await self._refuse(scope, receive, send)


class RefuseNul:
    """422 ``{"detail": …}`` for a request whose path or query string holds a NUL character
    (``%00``; the app is not called): no id, reason or file name holds one, and PostgreSQL
    refuses it in text, so it is refused alike on every database and for every route."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and (
            "\x00" in scope.get("path", "")
            or b"\x00" in unquote_to_bytes(scope.get("query_string", b""))
        ):
            response = JSONResponse(
                {"detail": "the path or query string holds a NUL character (%00)"},
                status_code=422,
            )
            await response(scope, receive, send)
            return
        await self.app(scope, receive, send)


class FailureCounter:
    """Failed authentications per client address: the times (monotonic) of each address's last
    ``burst`` failures, kept under a lock (the server's threads share one). An address is
    blocked while its last ``burst`` failures all fall within ``window_s``; another address's
    success or failure leaves its count alone."""

    def __init__(
        self, burst: int, window_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.burst = burst
        self.window_s = window_s
        self.clock = clock
        self._failures: dict[str, deque[float]] = {}
        self._lock = threading.Lock()

    def _sweep(self, now: float) -> None:
        """Forget the addresses whose last failure is out of the window (the caller locks)."""
        for address in [a for a, d in self._failures.items() if d[-1] <= now - self.window_s]:
            del self._failures[address]

    def retry_after(self, address: str) -> int | None:
        """Seconds until ``address`` may try again (at least 1), or ``None`` if not blocked."""
        with self._lock:
            times = self._failures.get(address)
            now = self.clock()
            if times is None or not self._blocked(times, now):
                return None
            return max(1, math.ceil(times[0] + self.window_s - now))

    def record_failure(self, address: str) -> bool:
        """Count a failure of ``address``; ``True`` if that one starts a block."""
        with self._lock:
            now = self.clock()
            if len(self._failures) > 1024:
                self._sweep(now)
            times = self._failures.setdefault(address, deque(maxlen=self.burst))
            was_blocked = self._blocked(times, now)
            times.append(now)
            return not was_blocked and self._blocked(times, now)

    def _blocked(self, times: deque[float], now: float) -> bool:
        return len(times) >= self.burst and times[0] > now - self.window_s


class AuthFailureThrottle:
    """Counts a 401 to a request carrying an ``Authorization`` header as a failure of the
    request's client address (:class:`FailureCounter`), and refuses only failures: from an
    address the counter blocks, the header is checked first with ``verify`` (the header's value
    → whether it holds a valid token; run in a worker thread: one SHA-256 and one indexed read)
    and a request that fails it answers 429 with ``Retry-After`` at once (the app is not called,
    its body not read, and the failure not counted again), while a valid token goes on to the
    app as from any other address. A ``verify`` that raises (the database down) leaves the
    answer to the app. Each block is logged once, with the address."""

    def __init__(self, app: ASGIApp, counter: FailureCounter, verify: Callable[[str], bool]):
        self.app = app
        self.counter = counter
        self.verify = verify

    async def _refused(self, authorization: str, address: str) -> int | None:
        """The seconds ``address`` must wait if it is blocked and ``authorization`` fails, else
        ``None`` (not blocked, a valid token, or no answer from ``verify``)."""
        wait = self.counter.retry_after(address)
        if wait is None:
            return None
        try:
            valid = await to_thread.run_sync(self.verify, authorization)
        except Exception:  # the app answers (503 for a database that does not answer)
            log.debug("the token of a blocked address could not be checked", exc_info=True)
            return None
        return None if valid else wait

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        authorization = (
            Headers(scope=scope).get("authorization") if scope["type"] == "http" else None
        )
        if authorization is None:
            await self.app(scope, receive, send)
            return
        address = scope["client"][0] if scope.get("client") else "unknown"
        wait = await self._refused(authorization, address)
        if wait is not None:
            response = JSONResponse(
                {"detail": f"too many failed authentications; try again in {wait} s"},
                status_code=429,
                headers={"Retry-After": str(wait)},
            )
            await response(scope, receive, send)
            return

        async def watching_send(message: Message) -> None:
            failed = message["type"] == "http.response.start" and message["status"] == 401
            if failed and self.counter.record_failure(address):
                log.warning(
                    "%s: %d failed authentications within %g s; its requests whose token "
                    "fails answer 429 until the window frees",
                    address,
                    self.counter.burst,
                    self.counter.window_s,
                )
            await send(message)

        await self.app(scope, receive, watching_send)


#: What a 503 of :class:`Admission` or of a pool time-out asks the client to wait. [s]
OVERLOAD_RETRY_AFTER_S = 1
#: What a 503 of a database that does not answer asks the client to wait. [s]
DATABASE_RETRY_AFTER_S = 5
#: :class:`Slots` logs its refusals at most this often. [s]
OVERLOAD_LOG_EVERY_S = 10.0
#: The interpreter's thread switch interval while the service runs (Python's default: 5 ms): the
#: event loop and a thread back from the database take the GIL again within 1 ms of asking,
#: rather than 5, while other threads compute. [s]
SWITCH_INTERVAL_S = 0.001
#: The API's paths that :class:`Admission` lets through without a slot: they stay cheap and say
#: whether the service is alive and ready even when it is overloaded.
UNCOUNTED = ("/api/v1/health", "/api/v1/ready", "/api/v1/metrics")


def pace_threads(worker_threads: int) -> None:
    """At most ``worker_threads`` threads run the sync routes and dependencies (anyio's default
    limiter of the running event loop), and the process switches threads every
    :data:`SWITCH_INTERVAL_S` (for the whole process, until it ends)."""
    to_thread.current_default_thread_limiter().total_tokens = worker_threads
    sys.setswitchinterval(SWITCH_INTERVAL_S)


class Slots:
    """``size`` slots for requests, taken and given back in the server's event loop: a request
    takes a free one at once, or waits up to ``wait_s`` (s) in line for one given back, first
    come first served. ``busy`` counts the slots taken, ``waiting`` the requests in line,
    ``rejected`` those that got none (since start); each refusal is logged at WARNING, at most
    once per :data:`OVERLOAD_LOG_EVERY_S`."""

    def __init__(
        self, size: int, wait_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.size = size
        self.wait_s = wait_s
        self.clock = clock
        self.busy = 0
        self.rejected = 0
        self._line: deque[asyncio.Future] = deque()
        self._logged_at = -math.inf

    @property
    def waiting(self) -> int:
        """Requests in line for a slot."""
        return len(self._line)

    async def acquire(self) -> bool:
        """Take a slot, waiting up to ``wait_s`` for one; ``False`` if none came free (counted
        and logged)."""
        if self.busy < self.size and not self._line:
            self.busy += 1
            return True
        loop = asyncio.get_running_loop()
        turn = loop.create_future()  # True: a slot handed over by release(); False: time is up
        self._line.append(turn)
        timer = loop.call_later(self.wait_s, self._time_up, turn)
        try:
            granted = await turn
        except asyncio.CancelledError:  # the client left; a slot it was handed goes on
            if turn.done() and not turn.cancelled() and turn.result():
                self.release()
            raise
        finally:
            timer.cancel()
            if turn in self._line:
                self._line.remove(turn)
        if not granted:
            self._refused()
        return granted

    @staticmethod
    def _time_up(turn: asyncio.Future) -> None:
        if not turn.done():
            turn.set_result(False)

    def release(self) -> None:
        """Give a slot back: to the first request in line, else free."""
        while self._line:
            turn = self._line.popleft()
            if not turn.done():
                turn.set_result(True)
                return
        self.busy -= 1

    def _refused(self) -> None:
        self.rejected += 1
        now = self.clock()
        if now - self._logged_at >= OVERLOAD_LOG_EVERY_S:
            self._logged_at = now
            log.warning(
                "overloaded: %d API requests at once and no slot free within %g s; "
                "%d requests answered 503 since start",
                self.size,
                self.wait_s,
                self.rejected,
            )


class Admission:
    """Lets an API request (a path under ``/api/`` but :data:`UNCOUNTED`) through only with one
    of ``slots``, held until its answer is sent; without one, 503 ``{"detail": …}`` with
    ``Retry-After`` (the app is not called)."""

    def __init__(self, app: ASGIApp, slots: Slots) -> None:
        self.app = app
        self.slots = slots

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if scope["type"] != "http" or not path.startswith("/api/") or path in UNCOUNTED:
            await self.app(scope, receive, send)
            return
        if not await self.slots.acquire():
            response = JSONResponse(
                {
                    "detail": f"the service is busy ({self.slots.size} requests at once); "
                    f"try again in {OVERLOAD_RETRY_AFTER_S} s"
                },
                status_code=503,
                headers={"Retry-After": str(OVERLOAD_RETRY_AFTER_S)},
            )
            await response(scope, receive, send)
            return
        try:
            await self.app(scope, receive, send)
        finally:
            self.slots.release()
