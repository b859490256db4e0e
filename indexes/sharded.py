"""``ShardedIndex``: several :class:`VectorIndex` shards searched together, with the same API.

For collections larger than one index should hold (one machine's memory, one file's size, one
build's time), vectors are split into shards of at most ``shard_size``. All shards share one trained
quantizer (trained once on a sample of the whole collection), so their scores are comparable and
the per-shard top-k lists merge into the exact top-k of the union. New vectors fill the last shard,
then open a new one. Each shard is its own saved directory, so shards can be built on different
machines and combined with :meth:`ShardedIndex.from_shards`.
"""

# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741

from __future__ import annotations

from pathlib import Path
from typing import Any

import faiss
import numpy as np

from indexes.building import IdsLike, prepare_build
from indexes.errors import IdError, ManifestError
from indexes.factory import AutoConfig
from indexes.integrity import FileEntry, Verify, VerifyLike, verifying
from indexes.persistence import (
    MANIFEST_NAME,
    Manifest,
    read_manifest,
    reading_index_dir,
    require_files,
    write_manifest,
    writing_index_dir,
)
from indexes.vector_index import KIND as SHARD_KIND
from indexes.vector_index import VectorIndex, check_k, files_of
from indexes.vectors import Metric, as_metric, prepare_ids, prepare_vectors
from scenesearch_base.checksums import sha256_file

KIND = "sharded_index"
DEFAULT_SHARD_SIZE = 8_000_000


class ShardedIndex:
    """Shards with disjoint ids; search merges their results. See the module docstring."""

    def __init__(self, shards: list[VectorIndex], shard_size: int = DEFAULT_SHARD_SIZE,
                 info: dict[str, Any] | None = None) -> None:
        if not shards:
            raise ValueError("a sharded index needs at least one shard")
        first = shards[0]
        for i, s in enumerate(shards[1:], start=1):
            if s.dim != first.dim or s.metric is not first.metric:
                raise ValueError(f"shard {i} has dimension {s.dim} and metric {s.metric.value}, shard 0 has "
                                 f"{first.dim} and {first.metric.value}")
        all_ids = np.concatenate([s.ids for s in shards] + [s.removed_ids for s in shards])
        uniq, counts = np.unique(all_ids, return_counts=True)
        if (counts > 1).any():
            raise IdError("ids appear in more than one shard", uniq[counts > 1].tolist())
        self.shards = shards
        self.shard_size = int(shard_size)
        self.metric: Metric = first.metric
        self.factory = first.factory
        self.info: dict[str, Any] = dict(info or {})

    @classmethod
    def build(cls, xb: np.ndarray, ids: IdsLike | None = None, metric: Metric | str = "cosine",
              factory: str = "auto", memory_budget_bytes: int | None = None,
              shard_size: int = DEFAULT_SHARD_SIZE, config: AutoConfig | None = None,
              tune_recall: bool = True) -> ShardedIndex:
        """Build shards of at most ``shard_size`` vectors from ``xb`` (N, d); arguments as
        :meth:`VectorIndex.build`. ``auto`` and the memory budget apply to the whole collection."""
        config = config or AutoConfig()
        metric = as_metric(metric)
        x, id_arr, factory, template, info = prepare_build(xb, ids, metric, factory, memory_budget_bytes, config)
        n = x.shape[0]
        shards = [
            VectorIndex.from_trained(template, metric, factory, x[start:start + shard_size],
                                     id_arr[start:start + shard_size], dict(info))
            for start in range(0, max(n, 1), shard_size)
        ]
        out = cls(shards, shard_size, info)
        if tune_recall:
            # Shards share the quantizer and data distribution: tune on the first, apply to all.
            first = shards[0]
            first.tune_on(x[:shard_size], id_arr[:shard_size], config)
            for s in shards[1:]:
                s.search_knob = first.search_knob[1]
                s.info["tuning"] = first.info.get("tuning")
            out.info["tuning"] = first.info.get("tuning")
        return out

    @classmethod
    def from_shards(cls, shards: list[VectorIndex], shard_size: int = DEFAULT_SHARD_SIZE) -> ShardedIndex:
        """Combine separately built indexes with disjoint ids (same dimension and metric)."""
        return cls(list(shards), shard_size)

    # ------------------------------------------------------------------ reading

    def __len__(self) -> int:
        return sum(len(s) for s in self.shards)

    @property
    def dim(self) -> int:
        return self.shards[0].dim

    @property
    def ids(self) -> np.ndarray:
        """(N,) live ids of all shards, sorted."""
        return np.sort(np.concatenate([s.ids for s in self.shards]))

    @property
    def next_id(self) -> int:
        return max(s.next_id for s in self.shards)

    @property
    def recall_at_10(self) -> float | None:
        return self.shards[0].recall_at_10

    def __repr__(self) -> str:
        return (f"ShardedIndex(n={len(self)}, shards={len(self.shards)}, dim={self.dim}, "
                f"metric={self.metric.value}, factory={self.factory!r})")

    def search(self, xq: np.ndarray, k: int, filter: IdsLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Same contract as :meth:`VectorIndex.search`, over all shards."""
        x = prepare_vectors(xq, self.dim, self.metric, "queries")
        check_k(k, len(self))
        allowed = None if filter is None else np.unique(np.asarray(filter, dtype=np.int64))
        parts_d, parts_i = [], []
        for shard in self.shards:
            if len(shard) == 0:
                continue
            D, I = shard.search(x, min(k, len(shard)), allowed)
            parts_d.append(D)
            parts_i.append(I)
        return merge_results(parts_d, parts_i, k, self.metric)

    def reconstruct(self, ids: IdsLike) -> np.ndarray:
        """(M, d) stored vectors of ``ids``, from whichever shard holds each."""
        arr = np.atleast_1d(np.asarray(ids, dtype=np.int64))
        out = np.empty((len(arr), self.dim), dtype=np.float32)
        found = np.zeros(len(arr), dtype=bool)
        for shard in self.shards:
            here = np.isin(arr, shard.ids)
            if here.any():
                out[here] = shard.reconstruct(arr[here])
                found |= here
        if not found.all():
            raise IdError("ids not in the index", arr[~found].tolist())
        return out

    # ------------------------------------------------------------------ changes

    def add(self, xb: np.ndarray, ids: IdsLike | None = None) -> np.ndarray:
        """Add vectors to the last shard until it is full, then to new shards; returns the ids."""
        x = prepare_vectors(xb, self.dim, self.metric, "xb")
        id_arr = prepare_ids(None if ids is None else np.asarray(ids), len(x), start=self.next_id)
        for shard in self.shards:
            clash = id_arr[np.isin(id_arr, shard.ids) | np.isin(id_arr, shard.removed_ids)]
            if len(clash):
                raise IdError("ids already used in the index (live or removed)", clash.tolist())
        for shard in self.shards:
            shard._check_writable()
        start = 0
        while start < len(x):
            last = self.shards[-1]
            room = self.shard_size - len(last)
            if room <= 0:
                empty = faiss.clone_index(last.faiss_index)
                empty.reset()
                last = VectorIndex.from_trained(empty, self.metric, self.factory, x[:0], id_arr[:0],
                                                dict(last.info))
                last.search_knob = self.shards[-1].search_knob[1]
                self.shards.append(last)
                room = self.shard_size
            last.add(x[start:start + room], id_arr[start:start + room])
            start += room
        return id_arr

    def remove(self, ids: IdsLike) -> int:
        """Remove vectors by id from whichever shard holds them; unknown ids raise :class:`IdError`."""
        arr = np.unique(np.atleast_1d(np.asarray(ids, dtype=np.int64)))
        unknown = arr[~np.isin(arr, self.ids)]
        if len(unknown):
            raise IdError("cannot remove ids that are not in the index", unknown.tolist())
        for shard in self.shards:
            shard._check_writable()
        return sum(shard.remove(arr[np.isin(arr, shard.ids)]) for shard in self.shards
                   if np.isin(arr, shard.ids).any())

    # ------------------------------------------------------------------ persistence

    def save(self, directory: Path | str, overwrite: bool = True) -> None:
        """Write ``manifest.json`` and one sub-directory per shard, atomically as a whole."""
        with writing_index_dir(directory, overwrite=overwrite) as tmp:
            names = []
            for i, shard in enumerate(self.shards):
                name = f"shard_{i:04d}"
                sub = tmp / name
                sub.mkdir()
                extra = shard.write_files(sub)
                write_manifest(sub, SHARD_KIND, shard.dim, shard.metric.value, shard.factory, len(shard), extra)
                names.append({"name": name, "count": len(shard),
                              "manifest_sha256": sha256_file(sub / MANIFEST_NAME)})
            write_manifest(tmp, KIND, self.dim, self.metric.value, self.factory, len(self),
                           {"shards": names, "shard_size": self.shard_size, "info": self.info})

    @classmethod
    def load(cls, directory: Path | str, mmap: bool = False, verify: VerifyLike = Verify.CACHED) -> ShardedIndex:
        """Load what :meth:`save` wrote; each shard is checked against its own manifest, itself
        checked against the top manifest. Arguments as :meth:`VectorIndex.load`."""
        with reading_index_dir(directory) as d:
            m = read_manifest(d, KIND)
            files, shard_manifests = _shard_manifests(d, m)
            with verifying(d, files, verify):  # one pass over every shard's files, hashed in parallel
                shards = [VectorIndex.from_files(sub, sm.dim, sm.metric, sm.factory, sm.count, sm.extra, mmap)
                          for sub, sm in shard_manifests]
        out = cls(shards, int(m.extra.get("shard_size", DEFAULT_SHARD_SIZE)), m.extra.get("info"))
        if len(out) != m.count or out.dim != m.dim:
            raise ManifestError(d / MANIFEST_NAME, f"says {m.count} vectors of dimension {m.dim}, the shards hold "
                                f"{len(out)} of dimension {out.dim}", field="count")
        return out


def _shard_manifests(d: Path, m: Manifest) -> tuple[dict[str, FileEntry], list[tuple[Path, Manifest]]]:
    """The files of a sharded index at ``d`` (its own and every shard's, by path below ``d``) and each
    shard's folder and manifest, every shard manifest checked against the top manifest ``m``."""
    entries = m.extra.get("shards")
    top = d / MANIFEST_NAME
    if not isinstance(entries, list) or not entries:
        raise ManifestError(top, "lists no shards", field="extra.shards")
    files = dict(m.files)
    shard_manifests = []
    for entry in entries:
        name = entry.get("name") if isinstance(entry, dict) else None
        if not isinstance(name, str) or Path(name).name != name or name in ("", ".", "..") or \
                not isinstance(entry.get("manifest_sha256"), str):
            raise ManifestError(top, f"bad shard entry {entry!r}", field="extra.shards")
        sub = d / name
        if not (sub / MANIFEST_NAME).is_file():
            raise ManifestError(sub / MANIFEST_NAME, "shard manifest missing")
        # A shard manifest is a few hundred bytes: always compared with the top manifest.
        if sha256_file(sub / MANIFEST_NAME) != entry["manifest_sha256"]:
            raise ManifestError(sub / MANIFEST_NAME, "differs from the checksum in the top manifest")
        sm = read_manifest(sub, SHARD_KIND)
        require_files(sm, sub, files_of(sm.extra))
        files.update({f"{name}/{file}": e for file, e in sm.files.items()})
        shard_manifests.append((sub, sm))
    return files, shard_manifests


def merge_results(parts_d: list[np.ndarray], parts_i: list[np.ndarray], k: int,
                  metric: Metric) -> tuple[np.ndarray, np.ndarray]:
    """Merge per-shard (nq, k_s) results into the overall (nq, k) best, padding with −1.

    Args:
        parts_d: per shard, (nq, k_s) scores.
        parts_i: per shard, (nq, k_s) ids, −1 for padding.
        k: results wanted.
        metric: decides whether higher or lower scores are closer.
    """
    D = np.concatenate(parts_d, axis=1)
    I = np.concatenate(parts_i, axis=1)
    key = np.where(I >= 0, -D if metric.higher_is_closer else D, np.inf)
    order = np.argsort(key, axis=1, kind="stable")[:, :k]
    D = np.take_along_axis(D, order, axis=1)
    I = np.take_along_axis(I, order, axis=1)
    if I.shape[1] < k:
        pad = k - I.shape[1]
        D = np.pad(D, ((0, 0), (0, pad)), constant_values=metric.missing_score)
        I = np.pad(I, ((0, 0), (0, pad)), constant_values=-1)
    D[I < 0] = metric.missing_score
    return D, I
