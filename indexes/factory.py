"""Choosing a FAISS index for a collection: size and memory budget → factory string.

The rules follow FAISS's "Guidelines to choose an index":

* small collections: exact ``Flat`` (brute force is fast enough and never misses);
* mid-size collections with memory to spare: ``HNSW32`` (fastest search, cheap to build there);
* large collections: ``IVF{K},Flat`` with K a power of two near 4·√N (the guideline range is
  4·√N … 16·√N), trained on at least 39·K vectors; from 2^14 lists on the coarse quantizer itself is
  an HNSW graph (``IVF{K}_HNSW32``) so that assigning queries stays cheap;
* when the raw vectors do not fit the budget: ``OPQ{M},IVF{K},PQ{M}``, M bytes per vector.

Estimates are deliberately simple (bytes per vector plus fixed overheads) and documented beside
each kind, so that the choice can be predicted from the numbers in the manifest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from indexes.errors import ConfigError, MemoryBudgetError
from scenesearch_base.config import YamlConfig

# Bytes the id map takes per vector: the int64 id plus the hash-table entry that lets an IVF index
# reconstruct and remove by id.
ID_BYTES_PER_VECTOR = 8 + 24
# HNSW keeps 2·M neighbours of 4 bytes on level 0 plus ~10% for upper levels.
HNSW_LINK_BYTES_PER_NEIGHBOUR = 4 * 2 * 1.1


@dataclass(frozen=True)
class AutoConfig(YamlConfig):
    """Thresholds of the automatic choice; read and written as YAML through :mod:`scenesearch_base.config`.

    Attributes:
        flat_max_n: collections up to this many vectors use exact ``Flat``.
        hnsw_max_n: collections up to this many vectors use HNSW when memory allows; larger ones
            use IVF (HNSW builds slowly and cannot remove vectors in place).
        hnsw_m: neighbours per HNSW node.
        ivf_lists_per_sqrt_n: K ≈ this · √N, rounded to a power of two (guideline range 4 … 16).
        ivf_min_lists: smallest K used.
        ivf_hnsw_quantizer_min_lists: from this K on, the coarse quantizer is an HNSW graph.
        train_points_per_list: training vectors per list (FAISS warns below 39).
        max_train_points: cap on training vectors, bounding build time.
        target_recall: recall@10 against exact search that tuning must reach.
        tune_margin: tuning aims this much higher, because its held-out queries are vectors of the
            collection (list members, graph nodes), a little easier to find than unseen queries.
        tune_queries: held-out sample size used to tune ``nprobe``/``efSearch``.
        tune_k: the k of the recall that tuning measures.
        seed: seed of every sample drawn while building.
    """

    flat_max_n: int = 20_000
    hnsw_max_n: int = 300_000
    hnsw_m: int = 32
    ivf_lists_per_sqrt_n: float = 4.0
    ivf_min_lists: int = 16
    ivf_hnsw_quantizer_min_lists: int = 16_384
    train_points_per_list: int = 39
    max_train_points: int = 256 * 65_536
    target_recall: float = 0.95
    tune_margin: float = 0.01
    tune_queries: int = 500
    tune_k: int = 10
    seed: int = 1234

    config_error = ConfigError

    def __post_init__(self) -> None:
        if not 0.0 < self.target_recall <= 1.0:
            raise ConfigError(f"AutoConfig.target_recall must be in (0, 1], got {self.target_recall}")
        for name in ("flat_max_n", "hnsw_max_n", "hnsw_m", "ivf_min_lists", "train_points_per_list",
                     "max_train_points", "tune_queries", "tune_k"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"AutoConfig.{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class FactoryChoice:
    """The factory string chosen for a collection and why.

    Attributes:
        factory: FAISS ``index_factory`` string.
        reason: one sentence naming the rule that picked it.
        estimated_bytes: expected memory of the built index.
        train_points: how many vectors training uses (0 when the index needs none).
    """

    factory: str
    reason: str
    estimated_bytes: int
    train_points: int


def ivf_lists(n: int, config: AutoConfig) -> int:
    """Number of IVF lists K for ``n`` vectors: a power of two near ``ivf_lists_per_sqrt_n``·√n.

    Never more lists than ``n / train_points_per_list``, so every list gets enough training points.
    """
    target = config.ivf_lists_per_sqrt_n * math.sqrt(max(n, 1))
    k = 2 ** round(math.log2(max(target, 1.0)))
    most = max(config.ivf_min_lists, n // config.train_points_per_list)
    return int(max(config.ivf_min_lists, min(k, 2 ** int(math.log2(most)))))


def ivf_factory(k: int, config: AutoConfig, codec: str = "Flat") -> str:
    quantizer = f"IVF{k}_HNSW32" if k >= config.ivf_hnsw_quantizer_min_lists else f"IVF{k}"
    return f"{quantizer},{codec}"


def train_points(factory: str, n: int, config: AutoConfig) -> int:
    """Training vectors to sample for ``factory``: 39 per IVF list / PQ centroid, capped by n."""
    k = 0
    for part in factory.split(","):
        part = part.strip()
        if part.startswith("IVF"):
            digits = part[3:].split("_")[0]
            k = max(k, int(digits)) if digits.isdigit() else k
        if part.startswith(("PQ", "OPQ")):
            k = max(k, 256)  # 8-bit PQ sub-quantizers have 256 centroids each
    if k == 0:
        return 0
    return int(min(n, config.max_train_points, max(config.train_points_per_list * k, 10_000)))


def choose_factory(n: int, dim: int, memory_budget_bytes: int | None = None,
                   config: AutoConfig | None = None) -> FactoryChoice:
    """Pick a factory string for ``n`` vectors of dimension ``dim`` within a memory budget.

    Raises:
        MemoryBudgetError: even 4-byte PQ codes do not fit the budget.
    """
    config = config or AutoConfig()
    budget = math.inf if memory_budget_bytes is None else float(memory_budget_bytes)
    raw = n * (4 * dim + ID_BYTES_PER_VECTOR)
    if n <= config.flat_max_n and raw <= budget:
        return FactoryChoice("Flat", f"{n} ≤ flat_max_n={config.flat_max_n}: exact search", raw, 0)
    hnsw = int(n * (4 * dim + ID_BYTES_PER_VECTOR + config.hnsw_m * HNSW_LINK_BYTES_PER_NEIGHBOUR))
    if n <= config.hnsw_max_n and hnsw <= budget:
        return FactoryChoice(f"HNSW{config.hnsw_m}",
                             f"{n} ≤ hnsw_max_n={config.hnsw_max_n} and the graph fits the budget", hnsw, 0)
    k = ivf_lists(n, config)
    centroids = k * dim * 4
    ivf_flat = raw + centroids
    if ivf_flat <= budget:
        factory = ivf_factory(k, config)
        return FactoryChoice(factory, f"raw vectors fit the budget; K={k} lists ≈ "
                             f"{k / math.sqrt(max(n, 1)):.1f}·√N", ivf_flat, train_points(factory, n, config))
    # Memory is tight: compress to M bytes per vector with a rotation (OPQ) that balances the
    # sub-spaces. M must divide dim; use the largest that fits, at most dim / 2 bytes.
    per_vector = (budget - centroids - dim * dim * 4) / max(n, 1) - ID_BYTES_PER_VECTOR
    candidates = [m for m in range(min(dim // 2, 64), 3, -1) if dim % m == 0 and m <= per_vector]
    if not candidates:
        raise MemoryBudgetError(
            f"{n} vectors of dimension {dim} do not fit in {memory_budget_bytes} bytes even as 4-byte "
            f"PQ codes (needs about {int(n * (4 + ID_BYTES_PER_VECTOR) + centroids)} bytes)")
    m = candidates[0]
    factory = f"OPQ{m}," + ivf_factory(k, config, codec=f"PQ{m}")
    est = int(n * (m + ID_BYTES_PER_VECTOR) + centroids + dim * dim * 4)
    return FactoryChoice(factory, f"raw vectors ({raw} bytes) exceed the budget; {m}-byte OPQ+PQ codes",
                         est, train_points(factory, n, config))
