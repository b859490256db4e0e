"""The search service under load: p50/p99 latency and errors at 1, 16 and 64 concurrent clients.

The server is the real ``scenesearch serve`` with its default limits (8 searches at once, 32
waiting, 30 s per request; one torch thread per search) in its own process on 127.0.0.1, over an
index of synthetic clips whose rule captions are embedded with the real sentence encoder
(all-MiniLM-L6-v2), so every caption query pays real text encoding. Each level runs a closed loop:
N clients, each a thread with its own keep-alive connection, send requests (4 in 5 caption
searches, 1 in 5 "more like this") until the level's request count or its time budget is spent.
Every answer is checked (status 200 and, for caption searches, the query's own caption ranked
first); a 429 counts as an error, and its client waits the ``Retry-After`` the server asks for
before going on. Everything is bounded: requests per level, seconds per level, and a client
timeout per request; the server is stopped at the end.

Baselines, in the same run: the 1-client level (latency ratios at 16 and 64 clients) and the same
caption queries answered in-process without HTTP (the service's own overhead). Clients and server
share the machine's cores, so at 64 clients part of the latency is the clients' own.
"""

from __future__ import annotations

import hashlib
import itertools
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

SUBJECTS = ["A car", "A truck", "A bus", "A pedestrian", "A cyclist", "A motorcycle"]
LANES = ["in the left lane", "in the right lane", "in the ego lane", "crossing from the left", "oncoming"]
MOTIONS = ["approaches", "moves away", "keeps its distance", "stops", "moves into the ego lane", "turns left"]
DIM = 64


class _RandomEmbedder:
    """Deterministic pseudo-embeddings per clip: the views only need vectors for clip → clip search."""

    def __init__(self, model_id: str) -> None:
        self._model_id = model_id

    @property
    def model_id(self) -> str:
        return self._model_id

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        raise RuntimeError("this benchmark index has no trained text model; use mode=captions")

    def embed_clips(self, clips_dir: Path, view: str = "fused", split: str | None = None,
                    shuffle_frames: bool = False) -> tuple[list[str], np.ndarray]:
        table = pq.read_table(Path(clips_dir) / "clips.parquet").to_pylist()
        x = np.stack([np.random.default_rng(int(hashlib.sha1(f"{r['caption']}{view}".encode()).hexdigest()[:8], 16))
                      .normal(size=DIM) for r in table]).astype(np.float32)
        x += np.random.default_rng(0).normal(0, 0.3, x.shape).astype(np.float32)
        return [r["clip_id"] for r in table], x / np.linalg.norm(x, axis=1, keepdims=True)

    def embed_arrays(self, clip: Mapping[str, Any], view: str = "fused") -> np.ndarray:
        raise RuntimeError("not used")


def _captions(n: int) -> list[str]:
    out = []
    for i in range(n):
        s, lane = SUBJECTS[i % 6], LANES[(i // 6) % 5]
        m1, m2 = MOTIONS[(i // 30) % 6], MOTIONS[(i // 180) % 6]
        text = f"{s} {lane} {m1}, then {m2}" if m1 != m2 else f"{s} {lane} {m1}"
        out.append(f"{text}, {i + 1} m ahead.")  # unique: every measured query is encoded, none is cached
    return out


def _build_index(root: Path, n_clips: int) -> Path:
    from retrieval.embedding import model_hash
    from retrieval.scenesearch import SceneSearch

    clips = root / "clips"
    clips.mkdir(parents=True)
    captions = _captions(n_clips)
    rows = [{"clip_id": f"log{i // 100:03d}:t{i:06d}:{i}", "log_id": f"log{i // 100:03d}", "track_id": f"t{i:06d}",
             "category": "car", "start_ns": i * 10**9, "end_ns": i * 10**9 + 3 * 10**9, "caption": c,
             "canonical_caption": c, "tags": ["left:approach"], "split": "test", "time_of_day": "day",
             "weather": "clear", "preview_path": None} for i, c in enumerate(captions)]
    pq.write_table(pa.Table.from_pylist(rows), clips / "clips.parquet")
    run = root / "run"
    run.mkdir()
    (run / "model.safetensors").write_bytes(b"benchmark stand-in")
    (run / "config.json").write_text("{}")
    SceneSearch.build(run, clips, root / "index", embedder=_RandomEmbedder(model_hash(run)))
    return root / "index"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start_server(index_dir: Path, port: int) -> subprocess.Popen[str]:
    import httpx

    server = subprocess.Popen(
        [sys.executable, "-m", "retrieval.cli", "serve", str(index_dir), "--host", "127.0.0.1", "--port", str(port),
         "--no-warmup"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    with httpx.Client(timeout=10) as client:
        while True:
            try:
                if client.get(f"http://127.0.0.1:{port}/health").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline or server.poll() is not None:
                server.kill()
                raise RuntimeError("the server did not start")
            time.sleep(0.2)
        # The first query loads the sentence encoder: not part of the measured load.
        client.get(f"http://127.0.0.1:{port}/api/search", params={"q": "warm up", "mode": "captions"}, timeout=300)
    return server


def _level(base: str, clients: int, n_requests: int, budget_s: float, queries: list[str],
           clip_ids: list[str]) -> dict[str, Any]:
    """One closed-loop load level; latencies of correct answers and counts of every other outcome."""
    import httpx

    counter = itertools.count()
    lock = threading.Lock()
    latencies_ms: list[float] = []
    errors: Counter[str] = Counter()
    start = time.perf_counter()
    deadline = start + budget_s

    def client_loop() -> None:
        with httpx.Client(base_url=base, timeout=60) as c:
            while time.perf_counter() < deadline:
                i = next(counter)
                if i >= n_requests:
                    return
                t0 = time.perf_counter()
                try:
                    if i % 5 == 4:  # one in five is "more like this"
                        r = c.get(f"/api/similar/{clip_ids[i % len(clip_ids)]}", params={"k": 10})
                        ok = r.status_code == 200 and len(r.json()["results"]) == 10
                    else:
                        q = queries[i % len(queries)]
                        r = c.get("/api/search", params={"q": q, "k": 10, "mode": "captions"})
                        ok = r.status_code == 200 and r.json()["results"][0]["caption"] == q
                    outcome = "ok" if ok else str(r.status_code) if r.status_code != 200 else "wrong answer"
                except httpx.HTTPError as exc:
                    outcome, r = type(exc).__name__, None
                ms = (time.perf_counter() - t0) * 1e3
                with lock:
                    if outcome == "ok":
                        latencies_ms.append(ms)
                    else:
                        errors[outcome] += 1
                if r is not None and r.status_code == 429:  # as a well-behaved client does
                    time.sleep(min(float(r.headers.get("retry-after", 1)), max(0.0, deadline - time.perf_counter())))

    threads = [threading.Thread(target=client_loop) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(budget_s + 120)  # a client's last request may start just before the deadline
    wall_s = time.perf_counter() - start
    lat = np.asarray(latencies_ms) if latencies_ms else np.asarray([np.nan])
    return {"clients": clients, "requests": len(latencies_ms) + sum(errors.values()), "ok": len(latencies_ms),
            "errors": sum(errors.values()), "errors_by_kind": dict(sorted(errors.items())),
            "latency_p50_ms": round(float(np.percentile(lat, 50)), 2),
            "latency_p99_ms": round(float(np.percentile(lat, 99)), 2),
            "answers_per_s": round(len(latencies_ms) / wall_s, 1), "wall_s": round(wall_s, 1),
            "stopped_by": "time budget" if time.perf_counter() >= deadline else "request count"}


def run(quick: bool = False) -> dict[str, Any]:
    import torch

    from retrieval.scenesearch import SceneSearch

    torch.set_num_threads(1)  # as `serve` does by default, so that the in-process baseline is like for like
    n_clips = 1000 if quick else 5000
    # Requests per level; with the baseline's queries they fit in the clips, so no query repeats.
    levels = {1: 40, 16: 240, 64: 480} if quick else {1: 100, 16: 1200, 64: 2400}
    budget_s = 45.0 if quick else 75.0  # seconds per level
    with tempfile.TemporaryDirectory() as tmp:
        index_dir = _build_index(Path(tmp), n_clips)
        search = SceneSearch.open(index_dir)
        captions = _captions(n_clips)
        # Disjoint queries for the baseline and for each level: the server and the in-process search
        # each cache what they encoded, so a query seen before would not measure encoding.
        order = [captions[i] for i in np.random.default_rng(0).permutation(n_clips)]
        n_baseline = 30
        search.search_captions("warm up", k=10)  # load the encoder outside the timing
        start = time.perf_counter()
        for q in order[:n_baseline]:
            search.search_captions(q, k=10)
        in_process_ms = (time.perf_counter() - start) / n_baseline * 1e3
        level_queries, used = {}, n_baseline
        for n, count in levels.items():
            level_queries[n] = order[used:used + count]
            used += count
        clip_ids = search.views["fused"].metadata.table.column("clip_id").to_pylist()

        port = _free_port()
        server = _start_server(index_dir, port)
        base = f"http://127.0.0.1:{port}"
        try:
            results = {n: _level(base, n, count, budget_s, level_queries[n], clip_ids) for n, count in levels.items()}
            import httpx

            healthy_after = httpx.get(base + "/health", timeout=10).status_code == 200
        finally:
            server.terminate()
            try:
                server.wait(timeout=20)
            except subprocess.TimeoutExpired:
                server.kill()
    one = results[1]
    out: dict[str, Any] = {"clips": n_clips, "in_process_query_ms": round(in_process_ms, 2),
                           "p50_1_client_over_in_process": round(one["latency_p50_ms"] / in_process_ms, 2),
                           "healthy_after": healthy_after}
    for n, level in results.items():
        out[f"clients_{n}"] = level
        if n != 1:
            out[f"p50_{n}_over_1_client"] = round(level["latency_p50_ms"] / one["latency_p50_ms"], 2)
            out[f"p99_{n}_over_1_client"] = round(level["latency_p99_ms"] / one["latency_p99_ms"], 2)
            out[f"answers_per_s_{n}_over_1_client"] = round(level["answers_per_s"] / max(one["answers_per_s"], 1e-9), 2)
    out["note"] = ("caption search with the real sentence encoder, 1 in 5 requests clip -> clip; default limits; "
                   "clients and server on the same cores")
    return out
