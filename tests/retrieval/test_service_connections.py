"""Connection-level limits against a real server: uvicorn on 127.0.0.1 (an ephemeral port) in a thread.

Raw sockets send what ordinary clients never would (half a request, a 4 MB request line, 40 kB of
headers); every read has a short timeout, so a limit that does not hold fails the test instead of
hanging it.
"""

from __future__ import annotations

import http.client
import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx
import pytest
from retrieval_fakes import FakeEmbedder, HashTextEncoder, make_clips_dir, make_run_dir

from retrieval.embedding import model_hash
from retrieval.scenesearch import SceneSearch
from retrieval.service import ServiceLimits, create_app, serving_in_thread

LIMITS = ServiceLimits(read_timeout_s=0.6, request_timeout_s=1.0, keep_alive_s=2.0, linger_s=1.0,
                       max_concurrent_searches=1, max_waiting_searches=1, max_request_line_bytes=8192,
                       max_header_bytes=8192, max_body_bytes=1024)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    root = tmp_path_factory.mktemp("connections")
    clips = make_clips_dir(root / "clips", n_logs=2, clips_per_log=6)
    run = make_run_dir(root / "run")
    search = SceneSearch.build(run, clips, root / "index", embedder=FakeEmbedder(model_hash(run)),
                               text_encoder=HashTextEncoder())
    holds: dict[str, threading.Event] = {}
    original = search.search_captions

    def search_captions(query: str, *args: Any, **kwargs: Any) -> Any:
        if query in holds:  # a query that waits until the test releases it
            holds[query].wait(10)
        return original(query, *args, **kwargs)

    search.search_captions = search_captions  # type: ignore[method-assign]
    app = create_app(search, LIMITS)
    with serving_in_thread(app, LIMITS) as url:
        yield {"port": int(url.rsplit(":", 1)[1]), "url": url, "holds": holds, "gate": app.state.search_gate,
               "index": root / "index"}
        for event in holds.values():
            event.set()


def _connect(server: dict[str, Any], timeout_s: float = 5.0) -> socket.socket:
    return socket.create_connection(("127.0.0.1", server["port"]), timeout=timeout_s)


def _read_all(sock: socket.socket) -> bytes:
    """Everything until the server closes the connection (fails on a reset or a read timeout)."""
    chunks = []
    while chunk := sock.recv(65536):
        chunks.append(chunk)
    return b"".join(chunks)


def _wait_for(predicate: Any, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail("condition not met within the time limit")
        time.sleep(0.01)


def _status_and_detail(raw: bytes) -> tuple[int, str]:
    head, _, body = raw.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), json.loads(body)["detail"] if body else ""


def test_ordinary_requests_and_keep_alive_still_work(server: dict[str, Any]) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", server["port"], timeout=5)
    for _ in range(3):  # three requests on one connection
        conn.request("GET", "/api/search?q=stops+ahead+of+the+host&mode=captions&k=2")
        response = conn.getresponse()
        assert response.status == 200 and len(json.loads(response.read())["results"]) == 2
    conn.close()


def test_half_a_request_head_gets_408_and_the_connection_closes(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        start = time.monotonic()
        sock.sendall(b"GET /api/search?q=car HTTP/1.1\r\nHost: x\r\n")  # no blank line: the head never ends
        raw = _read_all(sock)
        waited = time.monotonic() - start
    status, detail = _status_and_detail(raw)
    assert status == 408 and "not received within 0.6 s" in detail
    assert LIMITS.read_timeout_s - 0.1 < waited < LIMITS.read_timeout_s + 3


def test_a_trickling_head_is_timed_from_its_first_byte(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        start = time.monotonic()
        sock.sendall(b"GET /health HTTP/1.1\r\n")
        for _ in range(4):  # each byte would renew a per-read timer; this one is not renewed
            time.sleep(0.25)
            try:
                sock.sendall(b"X")
            except OSError:
                break
        raw = _read_all(sock)
    assert _status_and_detail(raw)[0] == 408 and time.monotonic() - start < 3


def test_a_silent_connection_is_closed(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        start = time.monotonic()
        assert _read_all(sock) == b""  # closed without an answer: nothing was asked
        assert time.monotonic() - start < LIMITS.read_timeout_s + 3


def test_half_a_body_does_not_hold_the_connection(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        start = time.monotonic()
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n0123456789")
        raw = _read_all(sock)  # the app may answer (it reads no body); the connection closes either way
        assert time.monotonic() - start < LIMITS.read_timeout_s + 3
    assert raw == b"" or raw.startswith(b"HTTP/1.1 ")


@pytest.mark.parametrize("size", [1_000_000, 4_000_000])
def test_a_huge_query_gets_413_not_a_reset(server: dict[str, Any], size: int) -> None:
    with _connect(server) as sock:
        sock.sendall(b"GET /api/search?q=" + b"x" * size + b" HTTP/1.1\r\nHost: x\r\n\r\n")
        raw = _read_all(sock)
    status, detail = _status_and_detail(raw)
    assert status == 413 and "request line is over 8192 bytes" in detail


def test_a_long_query_within_the_request_line_gets_the_apps_413(server: dict[str, Any]) -> None:
    r = httpx.get(server["url"] + "/api/search", params={"q": "x" * 2000, "mode": "captions"}, timeout=5)
    assert r.status_code == 413 and "parameter 'q' is 2000 characters" in r.json()["detail"]


def test_oversized_headers_get_431_even_in_one_read(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: " + b"y" * 40_000 + b"\r\n\r\n")
        status, detail = _status_and_detail(_read_all(sock))
    assert status == 431 and "header fields are over 8192 bytes" in detail


def test_bodies_over_the_limit_or_without_a_length_are_refused(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        sock.sendall(b"POST /api/search HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000\r\n\r\n" + b"z" * 1_000_000)
        status, detail = _status_and_detail(_read_all(sock))
    assert status == 413 and "body is 1000000 bytes" in detail
    with _connect(server) as sock:
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n")
        status, detail = _status_and_detail(_read_all(sock))
    assert status == 411 and "Content-Length" in detail


def test_malformed_requests_get_400(server: dict[str, Any]) -> None:
    with _connect(server) as sock:
        sock.sendall(b"NOT HTTP AT ALL\r\n\r\n")
        assert _status_and_detail(_read_all(sock))[0] == 400


@pytest.mark.parametrize("version", [b"HTTP/9.9", b"HTTP/2.0", b"HTTP/1.2", b"HTTP/0.9"])
def test_other_http_versions_get_505(server: dict[str, Any], version: bytes) -> None:
    with _connect(server) as sock:
        sock.sendall(b"GET /health " + version + b"\r\nHost: x\r\n\r\n")
        raw = _read_all(sock)
    status, detail = _status_and_detail(raw)
    assert raw.startswith(b"HTTP/1.1 505 HTTP Version Not Supported\r\n")
    assert status == 505 and detail == f"{version.decode()} is not supported; this server speaks HTTP/1.0 and HTTP/1.1"


def test_http_1_0_and_1_1_are_answered(server: dict[str, Any]) -> None:
    for version in (b"HTTP/1.0", b"HTTP/1.1"):
        with _connect(server) as sock:
            sock.sendall(b"GET /health " + version + b"\r\nHost: x\r\nConnection: close\r\n\r\n")
            raw = _read_all(sock)
        assert raw.startswith(b"HTTP/1.1 200 OK\r\n") and json.loads(raw.partition(b"\r\n\r\n")[2])["status"] == "ok"


def test_serve_announces_itself_only_once_it_holds_its_port(server: dict[str, Any]) -> None:
    """``scenesearch serve`` binds before it announces: a second one on the same port is one line, exit 2."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    command = [sys.executable, "-u", "-m", "retrieval.cli", "serve", str(server["index"]), "--no-warmup",
               "--port", str(port)]
    first = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert first.stdout is not None
        line = first.stdout.readline()
        assert line.startswith(f"serving {server['index']}") and f"http://127.0.0.1:{port}/" in line, line
        assert httpx.get(f"http://127.0.0.1:{port}/health", timeout=10).json()["status"] == "ok"
        second = subprocess.run(command, capture_output=True, text=True, timeout=120)
        assert second.returncode == 2 and second.stdout == ""
        assert second.stderr == (f"scenesearch serve: error: --port {port}: 127.0.0.1:{port} is already in use by "
                                 "another program; choose another port\n")
    finally:
        first.terminate()
        first.wait(timeout=30)
    out_of_range = subprocess.run([*command[:-1], "70000"], capture_output=True, text=True, timeout=120)
    assert out_of_range.returncode == 2 and out_of_range.stdout == ""
    assert out_of_range.stderr == "scenesearch serve: error: --port 70000: must be an integer in 1 … 65535\n"


def test_past_the_search_slots_requests_get_429_with_retry_after(server: dict[str, Any]) -> None:
    holds = server["holds"]
    holds["hold a"], holds["hold b"] = threading.Event(), threading.Event()
    url = server["url"] + "/api/search"

    def ask(q: str) -> httpx.Response:
        return httpx.get(url, params={"q": q, "mode": "captions"}, timeout=5)

    with ThreadPoolExecutor(2) as pool:
        running = pool.submit(ask, "hold a")  # takes the one slot
        _wait_for(lambda: server["gate"].admitted == 1)
        waiting = pool.submit(ask, "hold b")  # takes the one waiting place
        _wait_for(lambda: server["gate"].admitted == 2)
        refused = ask("stops ahead of the host")
        holds["hold a"].set()
        holds["hold b"].set()
        assert running.result().status_code == 200 and waiting.result().status_code == 200
    assert refused.status_code == 429 and refused.headers["retry-after"] == "1"
    assert "busy" in refused.json()["detail"]
    _wait_for(lambda: server["gate"].admitted == 0)
    assert ask("stops ahead of the host").status_code == 200


def test_a_request_past_the_time_limit_gets_504(server: dict[str, Any]) -> None:
    server["holds"]["hold c"] = threading.Event()
    start = time.monotonic()
    r = httpx.get(server["url"] + "/api/search", params={"q": "hold c", "mode": "captions"}, timeout=5)
    assert r.status_code == 504 and time.monotonic() - start < LIMITS.request_timeout_s + 2
    server["holds"]["hold c"].set()
    _wait_for(lambda: server["gate"].admitted == 0)  # the abandoned search ends and frees its slot
