"""Request-level limits of the service (FastAPI's test client) and thread-safe embedding caches."""

from __future__ import annotations

import hashlib
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import anyio
import numpy as np
import pytest
from fastapi.testclient import TestClient
from retrieval_fakes import FakeEmbedder, HashTextEncoder, make_clips_dir, make_run_dir

from retrieval.embedding import EmbeddingCache, ModelEmbedder, model_hash
from retrieval.scenesearch import SceneSearch
from retrieval.service import ServiceLimits, create_app
from retrieval.service.limits import SearchGate, ServiceBusyError


@pytest.fixture(scope="module")
def search(tmp_path_factory: pytest.TempPathFactory) -> SceneSearch:
    root = tmp_path_factory.mktemp("limits")
    clips = make_clips_dir(root / "clips", n_logs=2, clips_per_log=6)
    run = make_run_dir(root / "run")
    return SceneSearch.build(run, clips, root / "index", embedder=FakeEmbedder(model_hash(run)),
                             text_encoder=HashTextEncoder())


@pytest.fixture(scope="module")
def client(search: SceneSearch) -> TestClient:
    return TestClient(create_app(search, ServiceLimits(max_k=20, max_query_chars=200)))


# ------------------------------------------------------------------------------ parameters
@pytest.mark.parametrize(
    ("path", "params", "status", "needle"),
    [
        ("/api/search", {"q": "car", "kk": 5}, 422, "unknown parameter 'kk'"),
        ("/api/search", {"q": "car", "k": [1, 15]}, 422, "parameter 'k' is given 2 times"),
        ("/api/search", {"q": ["car", "bus"]}, 422, "parameter 'q' is given 2 times"),
        ("/api/search", {"q": "car", "mode": "captions", "view": "lidar"}, 422, "unknown view 'lidar'"),
        ("/api/search", {"q": "car", "mode": "Captions"}, 422, "parameter 'mode'"),
        ("/api/search", {"q": "car", "k": "1.5"}, 422, "parameter 'k'"),
        ("/api/search", {}, 422, "parameter 'q': Field required"),
        ("/api/search", {"q": "car", "filter": "category=" + "x" * 300}, 413, "parameter 'filter'"),
        ("/api/search", {"q": "car", "filter": ["category=car"] * 9}, 422, "at most 8 filters"),
        ("/api/export", {"q": "x" * 201}, 413, "parameter 'q'"),
        ("/api/search", {"q": "car\x00", "mode": "captions"}, 422, "parameter 'q' holds the control character U+0000"),
        ("/api/search", {"q": "car\x07"}, 422, "parameter 'q' holds the control character U+0007"),
        ("/api/search", {"q": "car", "filter": "category=car\x1b"}, 422, "parameter 'filter' holds the control"),
        ("/api/export", {"q": "car\x00"}, 422, "parameter 'q' holds the control character U+0000"),
        ("/api/export", {"ids": "a", "view": "lidar"}, 422, "unknown view"),
        ("/api/fields", {"verbose": 1}, 422, "unknown parameter 'verbose' for /api/fields; valid parameters: none"),
        ("/health", {"x": 1}, 422, "unknown parameter 'x'"),
    ],
)
def test_every_parameter_is_checked(client: TestClient, path: str, params: dict[str, Any], status: int,
                                    needle: str) -> None:
    response = client.get(path, params=params)
    assert response.status_code == status, response.text
    assert needle in response.json()["detail"]


@pytest.mark.parametrize(("query", "needle"), [
    ("q=car%FF&mode=captions", "parameter 'q' is not valid UTF-8: byte 0xff at byte 3"),
    ("q=%C3%28", "parameter 'q' is not valid UTF-8: byte 0xc3 at byte 0"),
    ("q=car&filter=category%3D%ED%A0%80", "parameter 'filter' is not valid UTF-8"),  # an encoded surrogate
])
def test_a_parameter_that_is_not_utf8_gets_422_naming_it(client: TestClient, query: str, needle: str) -> None:
    """Starlette would pass such bytes on as replacement characters; the service refuses them instead."""
    response = client.get(f"/api/search?{query}")
    assert response.status_code == 422 and needle in response.json()["detail"], response.text


def test_the_service_limit_on_queries_is_the_api_limit() -> None:
    from retrieval.querying import MAX_QUERY_CHARS

    assert ServiceLimits().max_query_chars == MAX_QUERY_CHARS
    with pytest.raises(ValueError, match=f"max_query_chars must be at most {MAX_QUERY_CHARS}"):
        ServiceLimits(max_query_chars=MAX_QUERY_CHARS + 1)


def test_repeatable_parameters_may_repeat_and_valid_views_pass(client: TestClient) -> None:
    ok = client.get("/api/search", params={"q": "stops ahead of the host", "filter": ["category=car", "category=car"],
                                          "k": 3, "view": "bev"})
    assert ok.status_code == 200 and ok.json()["view"] == "bev"
    # Caption search uses no clip view: a valid one is accepted, and not echoed as if it had been used.
    captions = client.get("/api/search", params={"q": "stops ahead of the host", "mode": "captions",
                                                "view": "camera"})
    assert captions.status_code == 200 and captions.json()["view"] is None and captions.json()["mode"] == "captions"
    # The page's own address carries its state (?q=...): only the API's parameters are checked.
    assert client.get("/", params={"q": "a car", "anything": 1}).status_code == 200


def test_the_similar_path_is_checked_too(client: TestClient, search: SceneSearch) -> None:
    clip_id = search.get(next(iter(search.views["fused"].metadata.table.column("clip_id").to_pylist()))).clip_id
    assert client.get(f"/api/similar/{clip_id}", params={"k": 2}).status_code == 200
    r = client.get(f"/api/similar/{clip_id}", params={"k": 2, "q": "car"})
    assert r.status_code == 422 and "unknown parameter 'q'" in r.json()["detail"]


# ------------------------------------------------------------------------------ timeout and gate
def test_a_search_past_the_time_limit_gets_504_and_frees_its_slot(search: SceneSearch,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    release = threading.Event()
    original = search.search_captions

    def slow(query: str, *args: Any, **kwargs: Any) -> Any:
        release.wait(10)
        return original(query, *args, **kwargs)

    monkeypatch.setattr(search, "search_captions", slow)
    app = create_app(search, ServiceLimits(request_timeout_s=0.3))
    client = TestClient(app)
    start = time.monotonic()
    r = client.get("/api/search", params={"q": "stops", "mode": "captions"})
    assert r.status_code == 504 and "0.3 s" in r.json()["detail"]
    assert time.monotonic() - start < 3  # answered on time, while the search still runs
    gate = app.state.search_gate
    assert gate.admitted == 1  # the abandoned search keeps its slot until it really ends
    release.set()
    deadline = time.monotonic() + 5
    while gate.admitted and time.monotonic() < deadline:
        time.sleep(0.01)
    assert gate.admitted == 0
    assert client.get("/health").status_code == 200


def test_the_gate_bounds_running_and_waiting_searches() -> None:
    gate = SearchGate(running=1, waiting=1)
    release = threading.Event()
    running = []

    def hold() -> str:
        running.append(1)
        release.wait(5)
        return "done"

    async def scenario() -> list[Any]:
        out: list[Any] = []
        async with anyio.create_task_group() as tg:
            async def one() -> None:
                out.append(await gate.run(hold))

            tg.start_soon(one)
            tg.start_soon(one)
            await anyio.sleep(0.2)
            assert len(running) == 1 and gate.admitted == 2  # one runs, one waits
            with pytest.raises(ServiceBusyError, match="busy"):
                await gate.run(hold)
            release.set()
        return out

    assert anyio.run(scenario) == ["done", "done"]
    assert gate.admitted == 0


def test_a_waiting_search_whose_request_gave_up_is_skipped() -> None:
    gate = SearchGate(running=1, waiting=1)
    release = threading.Event()
    calls: list[str] = []

    def work(name: str) -> Any:
        def fn() -> str:
            calls.append(name)
            release.wait(5)
            return name
        return fn

    async def scenario() -> None:
        async with anyio.create_task_group() as tg:
            tg.start_soon(gate.run, work("first"))
            await anyio.sleep(0.1)
            with anyio.move_on_after(0.2):
                await gate.run(work("second"))  # waits for the slot, then its request gives up
            release.set()
        deadline = time.monotonic() + 5
        while gate.admitted and time.monotonic() < deadline:
            await anyio.sleep(0.01)

    anyio.run(scenario)
    assert calls == ["first"] and gate.admitted == 0


@pytest.mark.parametrize("field", ["request_timeout_s", "max_concurrent_searches", "max_header_bytes"])
@pytest.mark.parametrize("value", [0, -1, float("nan"), float("inf")])
def test_limits_must_be_positive(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        ServiceLimits(**{field: value})


# ------------------------------------------------------------------------------ caches under threads
def _row(text: str) -> np.ndarray:
    seed = int.from_bytes(hashlib.blake2b(text.encode(), digest_size=4).digest(), "little")
    return np.random.default_rng(seed).normal(size=8).astype(np.float32)


def _hammer(embed_texts: Any, n_threads: int = 8, calls: int = 300) -> list[BaseException]:
    """Call ``embed_texts`` from many threads over overlapping texts; return what was raised or wrong."""
    problems: list[BaseException] = []
    start = threading.Barrier(n_threads)

    def worker(seed: int) -> None:
        rng = np.random.default_rng(seed)
        start.wait()
        try:
            for _ in range(calls):
                texts = [f"text {i}" for i in rng.integers(0, 12, size=3)]
                out = embed_texts(texts)
                expected = np.stack([_row(t) for t in texts])
                if not np.array_equal(out, expected):
                    problems.append(AssertionError(f"wrong rows for {texts}"))
        except BaseException as exc:  # collected and reported by the test
            problems.append(exc)

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    return problems


def _slow_rows(texts: list[str]) -> np.ndarray:
    time.sleep(0.0005)  # let other threads run between a miss and its use, as a model call would
    return np.stack([_row(t) for t in texts])


def test_the_embedding_cache_is_safe_under_threads() -> None:
    cache = EmbeddingCache(size=4)  # smaller than the texts in use: evictions all the time
    problems = _hammer(lambda texts: np.stack(cache.get_or_embed(texts, _slow_rows)))
    assert not problems, problems[:3]
    assert len(cache) <= 4


def test_model_embedder_text_cache_and_model_load_under_threads(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    embedder = ModelEmbedder(make_run_dir(tmp_path / "run"), cache_size=4)
    monkeypatch.setattr(embedder, "_encode_texts", _slow_rows)
    problems = _hammer(embedder.embed_texts)
    assert not problems, problems[:3]

    loads: list[int] = []

    def load_model(run_dir: Path, device: str = "cpu") -> Any:
        loads.append(1)
        time.sleep(0.05)

        class Model:
            def eval(self) -> Model:
                return self

        return Model()

    monkeypatch.setattr("encoders.inference.load_model", load_model)
    threads = [threading.Thread(target=lambda: embedder.model) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert len(loads) == 1  # loaded once, not once per thread


# ------------------------------------------------------------------------------ tag routes
class _FakeTagSearch:
    """Records how many tag queries run at once; TagSearch itself is not thread-safe."""

    def __init__(self) -> None:
        self.active = 0
        self.most_at_once = 0
        self._lock = threading.Lock()

    def _enter(self) -> None:
        with self._lock:
            self.active += 1
            self.most_at_once = max(self.most_at_once, self.active)
        time.sleep(0.05)
        with self._lock:
            self.active -= 1

    def series(self, log_dir: Path, tag: str, region: str, h: str, kappa: float) -> tuple[np.ndarray, np.ndarray]:
        self._enter()
        return np.arange(3, dtype=np.int64) * 10**8, np.zeros(3, np.float32)

    def find(self, *args: Any) -> list[Any]:
        self._enter()
        return []


def test_tag_routes_check_parameters_and_run_one_at_a_time(search: SceneSearch, tmp_path: Path) -> None:
    from retrieval.service.tags_api import register_tag_routes

    app = create_app(search, ServiceLimits(max_query_chars=50))
    tags = _FakeTagSearch()
    register_tag_routes(app, tags, [tmp_path / "log_a", tmp_path / "log_b"])  # type: ignore[arg-type]
    client = TestClient(app)
    bad = [
        ({"tag": "parked", "threshold": "nan"}, 422, "parameter 'threshold'"),
        ({"tag": "parked", "min_duration_s": -1}, 422, "parameter 'min_duration_s'"),
        ({"tag": "parked", "kappa": "inf"}, 422, "parameter 'kappa'"),
        ({"tag": "parked " * 10}, 413, "parameter 'tag'"),
        ({"tag": "parked", "regoin": "front"}, 422, "unknown parameter 'regoin'"),
        ({"tag": "parked", "k": [1, 2]}, 422, "parameter 'k' is given 2 times"),
    ]
    for params, status, needle in bad:
        r = client.get("/api/tags/find", params=params)
        assert r.status_code == status and needle in r.json()["detail"], (params, r.text)
    ok = client.get("/api/tags/find", params={"tag": "parked", "log_id": ["log_a", "log_b"]})
    assert ok.status_code == 200
    with ThreadPoolExecutor(6) as pool:
        answers = list(pool.map(lambda _: client.get("/api/tags/series", params={"log_id": "log_a", "tag": "parked"}),
                                range(6)))
    assert all(a.status_code == 200 for a in answers)
    assert tags.most_at_once == 1


def test_serve_refuses_bad_limits_before_serving(search: SceneSearch, capsys: pytest.CaptureFixture[str]) -> None:
    from retrieval.cli import main

    assert main(["serve", str(search.index_dir), "--request-timeout-s", "0"]) == 2
    assert "request_timeout_s must be a positive number" in capsys.readouterr().err


@pytest.mark.parametrize(("options", "needle"), [
    (["--port", "70000"], "--port 70000: must be an integer in 1 … 65535"),
    (["--port", "0"], "--port 0: must be an integer in 1 … 65535"),
    (["--port", "-1"], "--port -1: must be an integer in 1 … 65535"),
    (["--host", "no-such-host.invalid"], "--host 'no-such-host.invalid': not an address of this machine nor a name"),
    (["--host", "192.0.2.1"], "--host '192.0.2.1': 192.0.2.1 is not an address of this machine"),
])
def test_serve_refuses_an_address_it_cannot_listen_on_in_one_line(
        search: SceneSearch, capsys: pytest.CaptureFixture[str], options: list[str], needle: str) -> None:
    from retrieval.cli import main

    assert main(["serve", str(search.index_dir), "--no-warmup", *options]) == 2
    out, err = capsys.readouterr()
    assert "serving" not in out
    assert err.startswith(f"scenesearch serve: error: {needle}") and err.count("\n") == 1, err


def test_serve_refuses_a_taken_port_and_one_it_may_not_bind(search: SceneSearch, capsys: pytest.CaptureFixture[str],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    import errno
    import socket

    from retrieval.cli import main

    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        assert main(["serve", str(search.index_dir), "--no-warmup", "--port", str(port)]) == 2
    out, err = capsys.readouterr()
    assert "serving" not in out
    assert err == f"scenesearch serve: error: --port {port}: 127.0.0.1:{port} is already in use by another program; " \
                  "choose another port\n"

    class NoPermission(socket.socket):
        def bind(self, address: Any) -> None:
            raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(socket, "socket", NoPermission)
    assert main(["serve", str(search.index_dir), "--no-warmup", "--port", "80"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("scenesearch serve: error: --port 80: permission denied to listen on 127.0.0.1:80")
