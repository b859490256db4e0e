"""The search service under load: throughput and p50/p99 latency from a second process on loopback.

The server is the real ``scenesearch serve`` in its own process, over an index of synthetic clips
whose rule captions are embedded with the real sentence encoder (all-MiniLM-L6-v2), so every
query pays real text encoding. A bounded number of requests (caption search and "more like this")
is sent by a pool of concurrent clients; each answer is checked (status 200, the query's own
caption ranked first). Baseline, in the same run: the same caption queries answered in-process,
without HTTP, which gives the service's overhead as a ratio.
"""

from __future__ import annotations

import hashlib
import json
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
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
        out.append(f"{s} {lane} {m1}, then {m2}." if m1 != m2 else f"{s} {lane} {m1}.")
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


def run(quick: bool = False) -> dict[str, Any]:
    import httpx

    from retrieval.scenesearch import SceneSearch

    n_clips = 1000 if quick else 5000
    n_requests = 120 if quick else 600
    concurrency = 8
    with tempfile.TemporaryDirectory() as tmp:
        index_dir = _build_index(Path(tmp), n_clips)
        search = SceneSearch.open(index_dir)
        captions = sorted(set(_captions(n_clips)))
        rng = np.random.default_rng(0)
        queries = [captions[i] for i in rng.integers(0, len(captions), n_requests)]
        # Baseline: the same caption queries in-process.
        search.search_captions(queries[0], k=10)  # load the encoder outside the timing
        start = time.perf_counter()
        for q in queries[:100]:
            search.search_captions(q, k=10)
        in_process_ms = (time.perf_counter() - start) / 100 * 1e3

        port = _free_port()
        server = subprocess.Popen(
            [sys.executable, "-m", "retrieval.cli", "serve", str(index_dir), "--port", str(port), "--no-warmup"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        base = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + 60
            with httpx.Client(timeout=10) as client:
                while True:
                    try:
                        if client.get(base + "/health").status_code == 200:
                            break
                    except httpx.TransportError:
                        pass
                    if time.monotonic() > deadline or server.poll() is not None:
                        raise RuntimeError("the server did not start")
                    time.sleep(0.2)
                # The first query loads the sentence encoder: not part of the measured load.
                client.get(base + "/api/search", params={"q": "warm up", "mode": "captions"}, timeout=300)
            clip_ids = search.views["fused"].metadata.table.column("clip_id").to_pylist()

            def one(i: int) -> tuple[float, bool]:
                with httpx.Client(timeout=60) as c:
                    t0 = time.perf_counter()
                    if i % 5 == 4:  # one in five is "more like this"
                        r = c.get(f"{base}/api/similar/{clip_ids[i % len(clip_ids)]}", params={"k": 10})
                        ok = r.status_code == 200 and len(r.json()["results"]) == 10
                    else:
                        r = c.get(base + "/api/search", params={"q": queries[i], "k": 10, "mode": "captions"})
                        ok = r.status_code == 200 and r.json()["results"][0]["caption"] == queries[i]
                    return (time.perf_counter() - t0) * 1e3, ok

            start = time.perf_counter()
            with ThreadPoolExecutor(concurrency) as pool:
                outcomes = list(pool.map(one, range(n_requests)))
            wall_s = time.perf_counter() - start
        finally:
            server.terminate()
            server.wait(timeout=20)
    latencies = np.array([ms for ms, _ in outcomes])
    correct = sum(ok for _, ok in outcomes)
    p50 = float(np.percentile(latencies, 50))
    return {
        "clips": n_clips,
        "requests": n_requests,
        "concurrency": concurrency,
        "throughput_rps": round(n_requests / wall_s, 1),
        "latency_p50_ms": round(p50, 2),
        "latency_p99_ms": round(float(np.percentile(latencies, 99)), 2),
        "correct_answers": correct,
        "all_correct": correct == n_requests,
        "in_process_query_ms": round(in_process_ms, 2),
        "p50_over_in_process": round(p50 / in_process_ms, 2),
        "note": json.dumps("caption search with the real sentence encoder; 1 in 5 requests is clip → clip"),
    }
