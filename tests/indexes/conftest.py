"""Shared data for the index tests: small, seeded, clustered vectors like real embeddings."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import faiss
import numpy as np
import pytest

# The tests import the package from the working tree when it is not installed.
_ROOT = Path(__file__).resolve().parents[2]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

# One FAISS thread: the tests use small data, and on shared cores OpenMP barriers between busy
# threads cost far more than they save.
faiss.omp_set_num_threads(1)


def make_clustered(n: int, d: int, seed: int, n_clusters: int = 40, spread: float = 0.35) -> np.ndarray:
    """(n, d) float32 vectors around ``n_clusters`` random centres."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(n_clusters, d))
    x = centres[rng.integers(0, n_clusters, n)] + spread * rng.normal(size=(n, d))
    return x.astype(np.float32)


def normalise(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


# Test modules are imported by path (importlib mode), so helpers reach them as fixtures.
@pytest.fixture(scope="session")
def clustered() -> Callable[..., np.ndarray]:
    return make_clustered


@pytest.fixture(scope="session")
def normalised() -> Callable[[np.ndarray], np.ndarray]:
    return normalise


@pytest.fixture(scope="session")
def data() -> tuple[np.ndarray, np.ndarray]:
    """xb (3000, 32) and xq (50, 32), from the same clusters."""
    x = make_clustered(3050, 32, seed=7)
    return x[:3000], x[3000:]
