"""What retrieval needs from a model: text and clip embeddings, behind one small protocol.

:class:`Embedder` is the protocol; :class:`ModelEmbedder` implements it with the trained dual encoder
of a run directory (``encoders.inference.load_model``). Tests and benchmarks pass stand-ins that
implement the same four members, so retrieval can be exercised without training a model.

The frozen sentence encoder of rule-caption search, which needs no trained model, is
:class:`retrieval.sentence_encoder.SentenceEncoder`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from encoders.config import EMBED_BATCH_CLIPS, check_device_name
from retrieval.errors import ModelMismatchError
from scenesearch_base.checksums import sha256_file
from scenesearch_base.lru import Lru
from scenesearch_base.ray_cluster import Execution, cluster_gpus, import_ray, node_cpus, ray_runtime
from scenesearch_base.storage import as_location, join, list_files, remove_files, write_file

MODEL_FILE = "model.safetensors"
#: The embedding shards that :class:`RayDataEmbedder`'s actors write (``part-<first row>.parquet``).
SHARD_PATTERN = "part-*.parquet"
CONFIG_FILE = "config.json"


@runtime_checkable
class Embedder(Protocol):
    """Text and clip embeddings of one model; every array comes back L2-normalised float32."""

    @property
    def model_id(self) -> str:
        """A hash that changes whenever the model's weights change."""
        ...

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        """(N, D) embeddings of ``texts``."""
        ...

    def embed_clips(self, clips_dir: Path, view: str = "fused", split: str | None = None,
                    shuffle_frames: bool = False) -> tuple[list[str], np.ndarray]:
        """Clip ids and their (N, D) embeddings, for all clips of ``clips_dir`` (or one split)."""
        ...

    def embed_arrays(self, clip: Mapping[str, Any], view: str = "fused") -> np.ndarray:
        """(B, D) embeddings of a clip item or a collated batch (see ``encoders.data``)."""
        ...


def model_hash(run_dir: Path | str) -> str:
    """SHA-256 of the run's ``model.safetensors``.

    Raises:
        FileNotFoundError: the run directory holds no trained model.
    """
    path = Path(run_dir) / MODEL_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no trained model here (expected the {MODEL_FILE} that "
                                "`scenesearch train` writes)")
    return sha256_file(path)


def l2_normalize(x: np.ndarray) -> np.ndarray:
    """(N, D) rows scaled to unit length (zero rows stay zero); float32."""
    out = np.asarray(x, dtype=np.float32)
    norms = np.linalg.norm(out, axis=-1, keepdims=True)
    return np.asarray(out / np.maximum(norms, 1e-12), dtype=np.float32)


class EmbeddingCache:
    """A bounded LRU cache of text embeddings (:class:`scenesearch_base.lru.Lru`), safe to share between
    threads (the service's workers).

    Embedding the texts not cached runs outside the cache's lock, so threads encode at the same time
    and a hit never waits for another thread's encoding. Two threads missing the same text may both
    encode it; the rows are the same.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._rows: Lru[str, np.ndarray] = Lru(size)

    def __len__(self) -> int:
        return len(self._rows)

    def get_or_embed(self, texts: Sequence[str], embed: Callable[[list[str]], np.ndarray]) -> list[np.ndarray]:
        """The rows of ``texts`` (in order), calling ``embed`` once for those not cached."""
        unique = list(dict.fromkeys(texts))
        found = {t: row for t in unique if (row := self._rows.get(t)) is not None}
        missing = [t for t in unique if t not in found]
        if missing:
            found.update(zip(missing, embed(missing)))
        for t in unique:
            self._rows.put(t, found[t])
        return [found[t] for t in texts]


class ModelEmbedder:
    """The dual encoder of ``run_dir``, loaded on first use on ``device``; clips load in ``num_workers`` processes."""

    def __init__(self, run_dir: Path | str, expected_model_id: str | None = None,
                 batch_size: int = EMBED_BATCH_CLIPS, cache_size: int = 1024, device: str = "cpu",
                 num_workers: int = 0) -> None:
        check_device_name(device)  # auto (CUDA when available), cpu or cuda[:i]
        if batch_size < 1 or num_workers < 0:
            raise ValueError(f"batch_size must be at least 1 and num_workers ≥ 0, got {batch_size}, {num_workers}")
        self.run_dir, self.device, self.num_workers = Path(run_dir), device, num_workers
        self._model_id = model_hash(self.run_dir)
        if expected_model_id is not None and expected_model_id != self._model_id:
            raise ModelMismatchError(
                f"index built by another model version: the index was built with model "
                f"{expected_model_id[:12]}, {self.run_dir / MODEL_FILE} is {self._model_id[:12]}; "
                "rebuild the index with `scenesearch index`")
        self.batch_size = batch_size
        self._model: Any = None
        self._model_lock = threading.Lock()  # threads asking for the model at once load it once
        self._cache = EmbeddingCache(cache_size)
        # All views of the last clips folder (and split) embedded, so each view is computed once.
        self._views_key: tuple[str, str | None] | None = None
        self._views: tuple[list[str], dict[str, np.ndarray]] = ([], {})
        self._views_lock = threading.Lock()
        self._fitting_clips: set[str] = set()  # clips folders whose shape the model was trained on

    @property
    def model_id(self) -> str:
        return self._model_id

    @property
    def model(self) -> Any:
        if self._model is None:
            with self._model_lock:
                if self._model is None:
                    from encoders.inference import load_model

                    model = load_model(self.run_dir, device=self.device)
                    model.eval()  # every call below also runs under torch.inference_mode()
                    self._model = model
        return self._model

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        texts = list(texts)
        if not texts:
            return np.zeros((0, 0), np.float32)
        return np.stack(self._cache.get_or_embed(texts, self._encode_texts))

    def _encode_texts(self, texts: list[str]) -> np.ndarray:
        import torch

        from encoders.sentence import few_texts

        rows = []
        for start in range(0, len(texts), 256):
            with torch.inference_mode(), few_texts(len(texts)):
                emb = self.model.encode_text(texts[start:start + 256], normalize=True)
            rows.append(l2_normalize(_to_numpy(emb)))
        return np.concatenate(rows)

    def embed_clips(self, clips_dir: Path, view: str = "fused", split: str | None = None,
                    shuffle_frames: bool = False) -> tuple[list[str], np.ndarray]:
        """Clip ids and their (N, D) embeddings, for all clips of ``clips_dir`` (or one split).

        Raises:
            ClipShapeError: the clips' shape (frames per clip, camera image, BEV raster) is not that of
                the clips the model was trained on (:func:`encoders.inference.check_clips_fit`);
                nothing is embedded.
        """
        import torch

        from encoders.inference import check_clips_fit, embed_clips

        folder = str(Path(clips_dir).resolve())
        if folder not in self._fitting_clips:
            check_clips_fit(self.run_dir, clips_dir)
            self._fitting_clips.add(folder)
        if shuffle_frames:
            with torch.inference_mode():
                ids, x = embed_clips(self.model, clips_dir, split=split, view=view, shuffle_frames=True,
                                     batch_size=self.batch_size)
            return [str(i) for i in ids], l2_normalize(np.asarray(x))
        # Index builds and evaluations ask for every view of the same clips in turn: encode the clips
        # once for all views (each tower runs once) and serve the other views from memory.
        key = (str(Path(clips_dir).resolve()), split)
        with self._views_lock:  # held while embedding: the clips are encoded once, not once per thread
            if self._views_key != key:
                self._views_key, self._views = key, self._embed_views(Path(clips_dir), split)
            ids, views = self._views
        if view not in views:
            raise ValueError(f"unknown view {view!r}; valid views: {', '.join(views)}")
        return ids, l2_normalize(views[view])

    def _embed_views(self, clips_dir: Path, split: str | None) -> tuple[list[str], dict[str, np.ndarray]]:
        """Clip ids and every view's (N, D) embeddings of the clips of ``split`` (all when None)."""
        import torch

        from encoders.data import ClipDataset
        from encoders.inference import embed_dataset_views

        with torch.inference_mode():
            ids, views = embed_dataset_views(self.model, ClipDataset(clips_dir, split=split, as_uint8=True),
                                             batch_size=self.batch_size, num_workers=self.num_workers)
        return [str(i) for i in ids], views

    def embed_arrays(self, clip: Mapping[str, Any], view: str = "fused") -> np.ndarray:
        import torch

        batch = as_batch(clip)
        with torch.inference_mode():
            emb = self.model.encode_video(batch, view=view, normalize=True)
        return l2_normalize(_to_numpy(emb))


def as_batch(clip: Mapping[str, Any]) -> dict[str, Any]:
    """A collated batch from a clip item or a batch: numpy arrays become tensors, items gain a batch axis.

    An item's ``camera`` is (T, 4, Hc, Wc); a batch's is (B, T, 4, Hc, Wc).
    """
    import torch

    if "camera" not in clip and "bev_lidar" not in clip:
        raise ValueError(f"a clip needs 'camera' and 'bev_lidar' arrays (see encoders.data), got keys "
                         f"{sorted(clip)}")
    probe = clip.get("bev_lidar", clip.get("camera"))
    single = np.ndim(probe) == 4
    out: dict[str, Any] = {}
    for key, value in clip.items():
        if isinstance(value, (np.ndarray, torch.Tensor)):
            t = torch.as_tensor(np.asarray(value) if isinstance(value, np.ndarray) else value)
            if t.dtype == torch.float64:
                t = t.float()
            out[key] = t.unsqueeze(0) if single else t
        elif key == "has_camera" and isinstance(value, bool | np.bool_):
            out[key] = torch.tensor([bool(value)])
        elif single and isinstance(value, str | list):
            out[key] = [value]
        else:
            out[key] = value
    if "has_camera" not in out:
        batch_size = int(out[next(k for k in out if isinstance(out[k], torch.Tensor))].shape[0])
        out["has_camera"] = torch.ones(batch_size, dtype=torch.bool)
    return out


def _to_numpy(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float32)


class RayDataEmbedder(ModelEmbedder):
    """:class:`ModelEmbedder` whose clip embeddings come from Ray Data (``scenesearch index --workers``).

    The clip table becomes a Ray Dataset of row numbers; ``map_batches`` embeds it on a pool of
    :class:`ClipEmbedActor` (one model per actor: one GPU per actor when the cluster has GPUs, else
    one actor per node running on as many threads as the node has CPUs, see :func:`cpu_actors`).
    Each actor writes the embeddings of every block of rows it embeds as a Parquet shard
    ``shards_dir/part-<first row>.parquet`` (``row``, ``clip_id`` and one fixed-size list column per
    view; the shards of an earlier run there are removed first), and the index is built from the
    shards, read back in clip-table order. Texts, splits and shuffled frames are embedded here, as by
    :class:`ModelEmbedder`. Every node must read ``run_dir`` and the clips folder at the same path
    (a shared file system) and write ``shards_dir``: a shared folder or a ``pyarrow.fs`` URI.
    """

    def __init__(self, run_dir: Path | str, execution: Execution, shards_dir: Path | str,
                 batch_size: int = EMBED_BATCH_CLIPS) -> None:
        super().__init__(run_dir, batch_size=batch_size)
        self.execution = execution
        self.shards_dir = shards_dir
        #: Figures of the last embedding: actors, GPUs per actor, clips, shard files, seconds.
        self.last_run: dict[str, float] = {}

    def _embed_views(self, clips_dir: Path, split: str | None) -> tuple[list[str], dict[str, np.ndarray]]:
        if split is not None:
            return super()._embed_views(clips_dir, split)
        return self._embed_on_ray(clips_dir.resolve())

    def _embed_on_ray(self, clips_dir: Path) -> tuple[list[str], dict[str, np.ndarray]]:
        import pyarrow as pa
        import pyarrow.parquet as pq

        from encoders.clips.layout import read_clip_table

        start = time.perf_counter()
        n = read_clip_table(clips_dir, columns=["clip_id"]).num_rows
        if n == 0:
            return super()._embed_views(clips_dir, None)
        ray = import_ray()
        with ray_runtime(self.execution) as parallelism:
            gpus = cluster_gpus()
            batches = -(-n // self.batch_size)
            actors, threads = (gpus, 1) if gpus else cpu_actors(parallelism, node_cpus(ray))
            actors = max(1, min(actors, batches))
            # Blocks of whole batches, up to 64 per actor, each handed to an actor only when it is
            # idle: the actors share the work evenly, and one that is up first does not queue it
            # all. The blocks are made here (no read tasks), and each actor writes the shard of a
            # block itself: Ray Data's write tasks started worker processes of their own beside the
            # actors, a large share of the embedding's time on 2 cores (benchmarks/bench_scale.py;
            # docs/research/ray-scale.md).
            blocks = min(batches, 64 * actors)
            _quiet_ray_data(ray, self.execution)
            remove_files(self.shards_dir, SHARD_PATTERN)
            starts = [int(b[0]) * self.batch_size for b in np.array_split(np.arange(batches), blocks)]
            parts = [pa.table({"id": np.arange(a, b, dtype=np.int64)}) for a, b in zip(starts, [*starts[1:], n])]
            ds = ray.data.from_arrow(parts).map_batches(
                ClipEmbedActor, batch_size=None, batch_format="numpy",  # a block per call: a shard each
                fn_constructor_kwargs={"run_dir": str(self.run_dir), "clips_dir": str(clips_dir),
                                       "shards_dir": str(self.shards_dir), "batch_size": self.batch_size,
                                       "device": "cuda" if gpus else "cpu", "threads": threads},
                compute=ray.data.ActorPoolStrategy(size=actors, max_tasks_in_flight_per_actor=1), num_cpus=threads,
                num_gpus=1 if gpus else 0)
            ds.materialize()  # runs the pipeline; what it keeps is each shard's row numbers
        shards = list_files(self.shards_dir, SHARD_PATTERN)
        table = pa.concat_tables([pq.read_table(str(path)) for path in shards]).sort_by("row")
        rows = table.column("row").to_numpy()
        if not np.array_equal(rows, np.arange(n)):
            raise RuntimeError(f"{self.shards_dir}: the embedding shards hold {len(rows)} rows, not each of the "
                               f"{n} clips once; embed again")
        views = {v: table.column(v).combine_chunks().flatten().to_numpy().reshape(n, -1).astype(np.float32)
                 for v in table.column_names if v not in ("row", "clip_id")}
        self.last_run = {"actors": actors, "gpus_per_actor": 1 if gpus else 0, "threads_per_actor": threads, "clips": n,
                         "shards": len(shards), "seconds": time.perf_counter() - start}
        return [str(c) for c in table.column("clip_id").to_pylist()], views


def cpu_actors(parallelism: int, node_cpus: Sequence[int]) -> tuple[int, int]:
    """(actors, threads per actor) for embedding on CPUs: one actor per node, on all of its CPUs
    that the run may use (the smallest node's CPUs: an actor fits on every node).

    One model on k threads embeds faster than k models on one thread each: the threads share one
    copy of the weights and split each batch's activations, where k models each stream their own
    through the memory they share (on 2 cores a second thread gains more than a second process:
    ``benchmarks/bench_scale.py``, ``docs/research/ray-scale.md``).
    """
    per_node = max(1, min(min((c for c in node_cpus if c > 0), default=1), parallelism))
    return max(1, parallelism // per_node), per_node


def _quiet_ray_data(ray: Any, execution: Execution) -> None:
    """Ray Data's progress bars only where :class:`Execution` shows one, and no per-stage log lines."""
    import logging
    import os
    import sys
    import warnings

    os.environ.setdefault("RAY_DATA_LOG_LEVEL", "ERROR")  # read when Ray Data sets up its loggers
    logging.getLogger("ray.data").setLevel(logging.ERROR)
    with warnings.catch_warnings():  # the context warns of its own deprecated fields when copied
        warnings.simplefilter("ignore", DeprecationWarning)
        context = ray.data.DataContext.get_current()
    context.enable_progress_bars = sys.stderr.isatty() if execution.progress is None else execution.progress


class ClipEmbedActor:
    """One model on one device, embedding blocks of clip-table rows into Parquet shards (a Ray Data actor)."""

    def __init__(self, run_dir: str, clips_dir: str, shards_dir: str, batch_size: int = EMBED_BATCH_CLIPS,
                 device: str = "cpu", threads: int = 1) -> None:
        import torch

        from encoders.data import ClipDataset
        from encoders.inference import load_model

        # The CPUs the actor reserved: more threads would contend with the other actors.
        torch.set_num_threads(threads)
        self.model = load_model(run_dir, device=device, text=False)  # clips only: no sentence encoder to load
        self.dataset = ClipDataset(clips_dir, as_uint8=True)
        self.shards_dir = shards_dir
        self.batch_size = batch_size

    def __call__(self, block: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Embed the rows ``block["id"]``, ``batch_size`` at a time, and write them as the shard
        ``part-<first row>.parquet``; → the rows. A block retried after a failure writes the same
        shard again, whole."""
        import pyarrow as pa
        import pyarrow.parquet as pq
        import torch
        from torch.utils.data import Subset

        from encoders.inference import embed_dataset_views

        rows = [int(i) for i in block["id"]]
        with torch.inference_mode():  # the serial path's embedding, on this block's rows
            ids, views = embed_dataset_views(self.model, Subset(self.dataset, rows), self.batch_size)
        columns: dict[str, Any] = {"row": pa.array(rows, pa.int64()),
                                   "clip_id": pa.array([str(c) for c in ids], pa.string())}
        for view, flat in views.items():
            columns[view] = pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])
        table = pa.table(columns)
        write_file(join(as_location(self.shards_dir), f"part-{rows[0]:010d}.parquet"),
                   lambda path: pq.write_table(table, path))
        return {"row": np.asarray(rows, np.int64)}
