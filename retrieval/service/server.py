"""The HTTP server of ``scenesearch serve``: uvicorn with connection-level limits.

uvicorn's HTTP/1.1 protocol (h11) on its own leaves three gaps that this module closes:

- A request that is sent only in part is held for ever: uvicorn's keep-alive timer runs only after
  a response, and no timer runs while a request head or body is arriving. Here a client has
  ``read_timeout_s`` from connecting (or from its request's first byte) to send the whole
  request; past that it gets 408 and the connection closes.
- h11 bounds only the *incomplete* part of a request head (16 KiB by default): a head that arrives
  in one read passes whatever its size, while a long one that arrives in several reads gets 400
  and the connection is closed at once, with the rest of the request still unread. The kernel then
  answers the client with a reset, and the client sees "connection reset" instead of the answer.
  Here the request line, the header fields and the declared body are measured as they arrive:
  413 for a request line (a query) over ``max_request_line_bytes``, 431 for header fields over
  ``max_header_bytes``, 413 for a ``Content-Length`` over ``max_body_bytes`` and 411 for a body
  without one (chunked).
- h11 takes any ``HTTP/d.d`` in a request line and answers it as HTTP/1.1, so a client speaking
  another version would read an answer in a protocol it did not ask for. Here a request line whose
  version is not HTTP/1.0 or HTTP/1.1 gets 505 (one that is not ``HTTP/d.d`` at all stays h11's 400).
- After refusing a request the client is still sending, the server shuts its sending side, then
  reads and discards what keeps coming (up to ``max_linger_bytes``, for ``linger_s``) before
  closing, so that the client reads the refusal rather than a reset.

Refusals are JSON ``{"detail": "..."}`` like every other error of the API.

:func:`serve` binds its sockets itself (:func:`listen_sockets`) before uvicorn starts, so an address
that cannot be used (a port out of range or taken, a host that does not resolve) is one
:class:`ListenError` naming the host or the port, raised before the server announces anything.

>>> serve(create_app(search, limits), "127.0.0.1", 8000, limits)
"""

from __future__ import annotations

import asyncio
import errno
import json
import re
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from http import HTTPStatus
from typing import Any, ClassVar

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from retrieval.service.limits import ServiceLimits

#: The blank line that ends a request head (h11 accepts a bare LF as well).
_BLANK_LINE = re.compile(rb"\n\r?\n")
_CONTENT_LENGTH = re.compile(rb"^content-length[ \t]*:[ \t]*([^\r\n]*?)[ \t]*\r?$", re.IGNORECASE | re.MULTILINE)
_TRANSFER_ENCODING = re.compile(rb"^transfer-encoding[ \t]*:", re.IGNORECASE | re.MULTILINE)
#: The version at the end of a request line, as h11 reads it (``HTTP/`` digit ``.`` digit).
_REQUEST_VERSION = re.compile(rb" (HTTP/[0-9]\.[0-9])\r?$")
#: The versions this server speaks: h11's HTTP/1.1, which also answers HTTP/1.0 clients.
SUPPORTED_VERSIONS = (b"HTTP/1.0", b"HTTP/1.1")


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with the limits of :attr:`service_limits` (see the module docstring).

    Use :func:`guarded_protocol` to bind limits; uvicorn creates one instance per connection.
    """

    service_limits: ClassVar[ServiceLimits] = ServiceLimits()

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        #: Bytes of the request head received so far, while one is arriving.
        self._head = bytearray()
        self._read_timer: asyncio.TimerHandle | None = None
        self._linger_timer: asyncio.TimerHandle | None = None
        self._lingering = False
        self._discarded = 0
        super().connection_made(transport)
        self._arm_read_timer()  # a connection that never sends a request is closed too

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_read_timer()
        if self._linger_timer is not None:
            self._linger_timer.cancel()
            self._linger_timer = None
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._lingering:
            self._discarded += len(data)
            if self._discarded > self.service_limits.max_linger_bytes:
                self.transport.close()
            return
        head_arriving = self.conn.their_state is h11.IDLE
        if head_arriving:
            self._arm_read_timer()
            self._head += data
            if self._refuse_head():
                return
        super().data_received(data)
        if self._lingering or self.transport.is_closing():
            return
        state = self.conn.their_state
        if head_arriving and state is not h11.IDLE:
            self._head.clear()  # the head is complete: h11 has the request
        # Still arriving: a head in part, or a body. Otherwise the request is in and the app answers.
        if state is h11.SEND_BODY or (state is h11.IDLE and self._head):
            self._arm_read_timer()
        else:
            self._cancel_read_timer()

    def send_400_response(self, msg: str) -> None:
        """h11 found the request malformed (or its head over h11's own buffer limit)."""
        limit = self.config.h11_max_incomplete_event_size or 16 * 1024  # h11's default
        if len(self.conn.trailing_data[0]) > limit:
            self._refuse(431, f"the request head is over {limit} bytes")
        else:
            self._refuse(400, "malformed HTTP request")

    # ---------------------------------------------------------------------------------------------
    def _refuse_head(self) -> bool:
        """Refuse the request whose head is in ``self._head`` if it breaks a limit; True if refused."""
        lim = self.service_limits
        head = self._head
        line_end = head.find(b"\n")
        line_bytes = len(head) if line_end < 0 else line_end
        if line_bytes > lim.max_request_line_bytes:
            self._refuse(413, f"the request line is over {lim.max_request_line_bytes} bytes (queries are limited "
                              f"to {lim.max_query_chars} characters)")
            return True
        if line_end < 0:
            return False
        version = _REQUEST_VERSION.search(head, 0, line_end)
        if version and version.group(1) not in SUPPORTED_VERSIONS:
            self._refuse(505, f"{version.group(1).decode()} is not supported; this server speaks HTTP/1.0 and "
                              "HTTP/1.1")
            return True
        blank = _BLANK_LINE.search(head, line_end)
        end = blank.start() if blank else len(head)
        if end - line_end - 1 > lim.max_header_bytes:
            self._refuse(431, f"the request's header fields are over {lim.max_header_bytes} bytes")
            return True
        if blank is None:
            return False
        fields = bytes(head[line_end:end + 1])
        if _TRANSFER_ENCODING.search(fields):
            self._refuse(411, f"a request body needs a Content-Length (of at most {lim.max_body_bytes} bytes)")
            return True
        length = _CONTENT_LENGTH.search(fields)
        if length and length.group(1).isdigit() and int(length.group(1)) > lim.max_body_bytes:
            self._refuse(413, f"the request body is {int(length.group(1))} bytes; the limit is {lim.max_body_bytes}")
            return True
        return False  # malformed lengths are h11's to refuse (400)

    def _refuse(self, status: int, detail: str) -> None:
        """Answer ``status`` and close the connection without losing the answer to a reset."""
        body = json.dumps({"detail": detail}).encode()
        head = (f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\ncontent-type: application/json\r\n"
                f"content-length: {len(body)}\r\nconnection: close\r\n\r\n").encode()
        self.transport.write(head + body)
        self._lingering = True
        self._cancel_read_timer()
        self._unset_keepalive_if_required()
        if self.transport.can_write_eof():
            self.transport.write_eof()  # the client reads the answer, then the end of the stream
        self._linger_timer = self.loop.call_later(self.service_limits.linger_s, self.transport.close)

    def _arm_read_timer(self) -> None:
        if self._read_timer is None:  # measured from the first byte, not renewed by each one
            self._read_timer = self.loop.call_later(self.service_limits.read_timeout_s, self._read_timed_out)

    def _cancel_read_timer(self) -> None:
        if self._read_timer is not None:
            self._read_timer.cancel()
            self._read_timer = None

    def _read_timed_out(self) -> None:
        self._read_timer = None
        if self._lingering or self.transport.is_closing():
            return
        if self.conn.their_state is h11.IDLE and self._head:
            self._refuse(408, f"the request was not received within {self.service_limits.read_timeout_s:g} s")
        else:
            # Nothing sent, or a body still arriving after the app took the request (it may have answered
            # already, so no second answer): close.
            self.transport.close()


def guarded_protocol(limits: ServiceLimits) -> type[GuardedH11Protocol]:
    """A :class:`GuardedH11Protocol` class bound to ``limits``, for ``uvicorn.Config(http=...)``."""
    class Bound(GuardedH11Protocol):
        service_limits = limits

    return Bound


def server_config(app: Any, host: str, port: int, limits: ServiceLimits, **uvicorn_options: Any) -> uvicorn.Config:
    """The uvicorn configuration of the service: the guarded protocol and the limits' timeouts."""
    options: dict[str, Any] = {
        "http": guarded_protocol(limits),
        "timeout_keep_alive": limits.keep_alive_s,
        "limit_concurrency": limits.max_connections,
        # h11's own bound stays a backstop above ours (it sees pipelined requests that ours does not).
        "h11_max_incomplete_event_size": limits.max_request_line_bytes + limits.max_header_bytes + 1024,
        "log_level": "warning",
        **uvicorn_options,
    }
    return uvicorn.Config(app, host=host, port=port, **options)


class ListenError(ValueError):
    """The service cannot listen on the address asked for.

    Attributes:
        option: ``host`` or ``port``, the part of the address at fault.
        value: the host or port as given.
        reason: why, in a few words.
    """

    def __init__(self, option: str, value: object, reason: str) -> None:
        self.option, self.value, self.reason = option, value, reason
        super().__init__(f"{option} {value!r}: {reason}")


def listen_sockets(host: str, port: int) -> list[socket.socket]:
    """Sockets bound to ``port`` on every address ``host`` resolves to (all interfaces for ``""``),
    not yet listening; :func:`serve` hands them to uvicorn.

    As asyncio's own server does, each socket reuses a recent address (``SO_REUSEADDR``) and an IPv6
    one takes IPv6 only, so that ``::`` and ``0.0.0.0`` do not collide.

    Raises:
        ListenError: ``port`` is not in 1 … 65535, ``host`` resolves to no address, an address is
            not this machine's, the port is taken, or binding it needs privileges (no socket stays open).
    """
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise ListenError("port", port, "must be an integer in 1 … 65535")
    try:
        infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, socket.gaierror) else str(exc)
        raise ListenError("host", host, f"not an address of this machine nor a name that resolves ({reason})") from None
    sockets: list[socket.socket] = []
    for family, kind, proto, _, address in dict.fromkeys(infos):  # each address once
        sock = socket.socket(family, kind, proto)
        sockets.append(sock)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
        except OSError as exc:
            for opened in sockets:
                opened.close()
            raise _bind_error(host, port, str(address[0]), exc) from None
    return sockets


def _bind_error(host: str, port: int, address: str, exc: OSError) -> ListenError:
    shown = f"[{address}]:{port}" if ":" in address else f"{address}:{port}"
    if exc.errno == errno.EADDRINUSE:
        return ListenError("port", port, f"{shown} is already in use by another program; choose another port")
    if exc.errno in (errno.EACCES, errno.EPERM):
        return ListenError("port", port, f"permission denied to listen on {shown} (ports below 1024 need "
                                         "privileges); choose another port")
    if exc.errno == errno.EADDRNOTAVAIL:
        return ListenError("host", host, f"{address} is not an address of this machine")
    return ListenError("host", host, f"cannot listen on {shown} ({exc.strerror or exc})")


def serve(app: Any, host: str, port: int, limits: ServiceLimits,
          sockets: list[socket.socket] | None = None) -> None:
    """Serve ``app`` on ``host:port`` until interrupted, on ``sockets`` when given (from
    :func:`listen_sockets`), else on sockets bound here.

    Raises:
        ListenError: the address cannot be used (see :func:`listen_sockets`).
    """
    bound = sockets if sockets is not None else listen_sockets(host, port)
    try:
        uvicorn.Server(server_config(app, host, port, limits)).run(sockets=bound)
    finally:
        for sock in bound:
            sock.close()


@contextmanager
def serving_in_thread(app: Any, limits: ServiceLimits, host: str = "127.0.0.1", port: int = 0,
                      start_timeout_s: float = 20.0) -> Iterator[str]:
    """Serve ``app`` from a background thread while the block runs; yields its base URL.

    ``port=0`` takes a free port. For tests, benchmarks and notebooks.

    Raises:
        RuntimeError: the server did not start within ``start_timeout_s``.
    """
    server = uvicorn.Server(server_config(app, host, port, limits))
    thread = threading.Thread(target=server.run, name="scenesearch-serve", daemon=True)
    thread.start()
    deadline = time.monotonic() + start_timeout_s
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            server.should_exit = True
            raise RuntimeError(f"the server on {host}:{port} did not start within {start_timeout_s:g} s")
        time.sleep(0.02)
    bound = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://{host}:{bound}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)
