"""Limits that keep the service answering under load and against slow or hostile clients.

Three layers, each owning what it can see:

- the connection (:mod:`retrieval.service.server`): request line, header and body sizes, the time a
  client has to send its request, idle connections;
- every request (:class:`RequestTimeout`): the time the service has to answer it (504 past it);
- searches (:class:`SearchGate`): how many run at once and how many may wait (429 past that).

All of them read one :class:`ServiceLimits`.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, TypeVar

from retrieval.querying import MAX_QUERY_CHARS, QueryTextError, QueryTooLongError, check_text

if TYPE_CHECKING:  # the CLI reads the defaults at start-up: no web framework imports for that
    import anyio
    from starlette.types import ASGIApp, Message, Receive, Scope, Send

T = TypeVar("T")


@dataclass(frozen=True)
class ServiceLimits:
    """Limits of one service; ``scenesearch serve`` sets the main ones from its options.

    Attributes:
        max_k: the most results one request may ask for.
        max_query_chars: the longest query, filter or tag expression accepted (longer → 413); at most
            :data:`retrieval.querying.MAX_QUERY_CHARS`, the limit of every other entry point.
        max_filters: the most ``filter`` parameters in one request.
        max_export_ids: the most clips one export may name.
        request_timeout_s: the time the service has to answer a request (504 past it).
        read_timeout_s: the time a client has, from connecting or from its request's first byte,
            to send the whole request (408 and the connection closed past it).
        keep_alive_s: how long an idle connection stays open between requests.
        max_concurrent_searches: searches computed at once.
        max_waiting_searches: searches that may wait for one of those slots; past them, 429.
        max_waiting_previews: previews that may wait to be drawn (one at a time, apart from the
            searches, so that a page's previews never take a search's slot); past them, 429.
        retry_after_s: the ``Retry-After`` a 429 asks for.
        max_request_line_bytes: the longest request line (method, path and query; longer → 413).
        max_header_bytes: the most bytes of header fields (more → 431).
        max_body_bytes: the largest request body (larger → 413; no endpoint reads one).
        max_connections: open connections served at once (503 for requests past it).
        linger_s: after refusing a request that the client is still sending, how long the server
            keeps reading (and discarding) it so that the client reads the refusal, not a reset.
        max_linger_bytes: the most bytes discarded that way.
    """

    max_k: int = 100
    max_query_chars: int = MAX_QUERY_CHARS
    max_filters: int = 8
    max_export_ids: int = 1000
    request_timeout_s: float = 30.0
    read_timeout_s: float = 10.0
    keep_alive_s: float = 5.0
    max_concurrent_searches: int = 8
    max_waiting_searches: int = 32
    max_waiting_previews: int = 64
    retry_after_s: int = 1
    max_request_line_bytes: int = 32 * 1024
    max_header_bytes: int = 32 * 1024
    max_body_bytes: int = 64 * 1024
    max_connections: int = 256
    linger_s: float = 2.0
    max_linger_bytes: int = 16 * 1024 * 1024

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            least = 0 if f.name == "max_waiting_searches" else 1e-9  # zero waiting places: refuse at once
            if isinstance(value, bool) or not isinstance(value, int | float) or not least <= value < math.inf:
                raise ValueError(f"service limit {f.name} must be a positive number, got {value!r}")
        if self.max_query_chars > MAX_QUERY_CHARS:
            raise ValueError(f"service limit max_query_chars must be at most {MAX_QUERY_CHARS} (the limit of every "
                             f"search entry point), got {self.max_query_chars}")


def check_chars(name: str, value: str, limits: ServiceLimits) -> str:
    """``value`` when the query check (:func:`retrieval.querying.check_text`) passes it under
    ``limits.max_query_chars``; else 413 (too long) or 422 (a control character), naming the parameter."""
    from fastapi import HTTPException

    try:
        return check_text(value, f"parameter {name!r}", limits.max_query_chars)
    except QueryTooLongError as exc:
        raise HTTPException(413, str(exc)) from None
    except QueryTextError as exc:
        raise HTTPException(422, str(exc)) from None


class ServiceBusyError(Exception):
    """Every search slot and every waiting place is taken."""

    def __init__(self, capacity: int) -> None:
        super().__init__(f"the service is busy: {capacity} searches are running or waiting; retry shortly")


class _Abandoned(Exception):
    """The request gave up (timed out) before its search started; the search is skipped."""


class SearchGate:
    """At most ``running`` searches computed at once and ``waiting`` more queued; past that, refuse.

    A search runs in a worker thread. When its request times out the request stops waiting for it,
    but the thread cannot be stopped: it keeps its slot until it finishes, so the bound holds for
    the work really being done, not only for the requests still waiting. A search whose request
    gave up before it got a slot is skipped.
    """

    def __init__(self, running: int, waiting: int) -> None:
        self.capacity = running + waiting
        self._slots = threading.BoundedSemaphore(running)
        self._lock = threading.Lock()
        self._admitted = 0
        self._limiter: anyio.CapacityLimiter | None = None

    @property
    def admitted(self) -> int:
        """Searches running or waiting now (abandoned ones included until their thread ends)."""
        with self._lock:
            return self._admitted

    def _leave(self) -> None:
        with self._lock:
            self._admitted -= 1

    async def run(self, fn: Callable[[], T]) -> T:
        """``fn()`` in a worker thread, once a slot is free.

        Raises:
            ServiceBusyError: all slots and waiting places are taken (nothing is run).
        """
        import anyio

        with self._lock:
            if self._admitted >= self.capacity:
                raise ServiceBusyError(self.capacity)
            self._admitted += 1
        if self._limiter is None:  # created inside the event loop, on first use
            # Its own threads, so that searches never starve the cheap endpoints of the default pool.
            self._limiter = anyio.CapacityLimiter(self.capacity)
        abandoned = threading.Event()
        claimed = [False]

        def claim() -> bool:
            """Exactly one of the worker and the giving-up request releases the admission."""
            with self._lock:
                if claimed[0]:
                    return False
                claimed[0] = True
                return True

        def work() -> T:
            if not claim():
                raise _Abandoned
            try:
                with self._slots:
                    if abandoned.is_set():
                        raise _Abandoned
                    return fn()
            finally:
                self._leave()

        try:
            return await anyio.to_thread.run_sync(work, abandon_on_cancel=True, limiter=self._limiter)
        except BaseException:
            abandoned.set()
            if claim():  # the thread never started: release its place here
                self._leave()
            raise


class RequestTimeout:
    """ASGI middleware: a request not answered within ``timeout_s`` gets 504 (JSON ``detail``).

    Searches run in threads that the request abandons on timeout (see :class:`SearchGate`), so the
    answer comes on time even while the search is still computing. A response already under way
    when the time is up is cut off (the connection closes).
    """

    def __init__(self, app: ASGIApp, timeout_s: float) -> None:
        self.app = app
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        import anyio

        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def send_tracked(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        with anyio.move_on_after(self.timeout_s) as cancel:
            await self.app(scope, receive, send_tracked)
        if not cancel.cancelled_caught:
            return
        if started:
            raise TimeoutError(f"the response took longer than {self.timeout_s:g} s")
        body = json.dumps({"detail": f"the request took longer than the limit of {self.timeout_s:g} s"}).encode()
        await send({"type": "http.response.start", "status": 504,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})
