from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from indexes.clip_index import ClipIndex
from indexes.errors import FilterError, IdError, InvalidKError, MetadataError

N = 600


def metadata_rows(n: int, offset: int = 0) -> list[dict]:
    categories = ["car", "truck", "pedestrian", "bicycle"]
    return [
        {
            "clip_id": f"clip-{i + offset:05d}",
            "log_id": f"log{(i + offset) % 5}",
            "category": categories[(i + offset) % 4],
            "start_ns": 1_000 * (i + offset),
            "time_of_day": "night" if (i + offset) % 7 == 0 else "day",
            "tags": ["left:approach"] if (i + offset) % 3 == 0 else ["host:stop"],
        }
        for i in range(n)
    ]


@pytest.fixture
def vectors(clustered: Callable[..., np.ndarray]) -> np.ndarray:
    return clustered(N + 20, 32, seed=11)


@pytest.fixture
def index(vectors: np.ndarray) -> ClipIndex:
    return ClipIndex.build(vectors[:N], metadata_rows(N), factory="Flat")


def test_search_returns_clip_ids_scores_and_metadata(index: ClipIndex, vectors: np.ndarray) -> None:
    res = index.search(vectors[:3], 5)
    assert res.I.shape == (3, 5) and len(res.hits) == 3
    hit = res.hits[0][0]
    assert hit.clip_id == "clip-00000" and hit.id == 0 and hit.score == pytest.approx(1.0, abs=1e-5)
    assert hit.metadata["category"] == "car" and hit.metadata["tags"] == ["left:approach"]
    assert [h.score for h in res.hits[1]] == sorted((h.score for h in res.hits[1]), reverse=True)


def test_filters_return_only_matching_clips(index: ClipIndex, vectors: np.ndarray) -> None:
    table = pa.Table.from_pylist(metadata_rows(N))
    cases = [
        "category in {car, truck}",
        'tags contains "left:approach" and log_id == log2',
        "start_ns >= 100000 and start_ns < 120000",
        "time_of_day == night and category == pedestrian",
        {"category": ["bicycle"], "log_id": "log3"},
    ]
    for spec in cases:
        res = index.search(vectors[N:], 10, filter=spec)
        allowed = set(index.select(spec).tolist())
        assert allowed, spec
        for hits in res.hits:
            assert len(hits) == min(10, len(allowed))
            assert all(h.id in allowed for h in hits)
        # The filter agrees with a direct reading of the metadata.
        expected = {i for i, row in enumerate(table.to_pylist()) if _matches(row, spec)}
        assert allowed == expected, spec


def _matches(row: dict, spec: object) -> bool:
    if spec == "category in {car, truck}":
        return row["category"] in ("car", "truck")
    if spec == 'tags contains "left:approach" and log_id == log2':
        return "left:approach" in row["tags"] and row["log_id"] == "log2"
    if spec == "start_ns >= 100000 and start_ns < 120000":
        return 100_000 <= row["start_ns"] < 120_000
    if spec == "time_of_day == night and category == pedestrian":
        return row["time_of_day"] == "night" and row["category"] == "pedestrian"
    return row["category"] == "bicycle" and row["log_id"] == "log3"


def test_selective_filter_pads_with_minus_one(index: ClipIndex, vectors: np.ndarray) -> None:
    res = index.search(vectors[:2], 10, filter='clip_id in {"clip-00003", "clip-00100"}')
    assert [len(h) for h in res.hits] == [2, 2]
    assert (res.I[:, 2:] == -1).all()
    assert {h.clip_id for h in res.hits[0]} == {"clip-00003", "clip-00100"}


def test_clip_to_clip_excludes_itself(index: ClipIndex) -> None:
    res = index.search_clip("clip-00010", 5)
    assert "clip-00010" not in [h.clip_id for h in res.hits[0]] and len(res.hits[0]) == 5
    with_self = index.search_clip("clip-00010", 5, exclude_self=False)
    assert with_self.hits[0][0].clip_id == "clip-00010"
    res = index.search_clip("clip-00010", 3, filter="category == truck")
    assert all(h.metadata["category"] == "truck" for h in res.hits[0])


def test_clip_to_clip_leaves_out_the_clips_named(index: ClipIndex, vectors: np.ndarray) -> None:
    # Exact search as the reference: the clip's nearest neighbours by cosine, the named ones dropped.
    xb = vectors[:N] / np.linalg.norm(vectors[:N], axis=1, keepdims=True)
    k = 5
    order = np.argsort(-(xb @ xb[10]), kind="stable")
    nearest = [f"clip-{i:05d}" for i in order]
    left_out = [nearest[1], nearest[3], "no-such-clip"]  # two of its own neighbours, and an id not held
    res = index.search_clip("clip-00010", k, exclude=left_out)
    assert [h.clip_id for h in res.hits[0]] == [c for c in nearest if c not in {"clip-00010", *left_out}][:k]
    kept = index.search_clip("clip-00010", k, exclude=left_out, exclude_self=False)
    assert [h.clip_id for h in kept.hits[0]] == [c for c in nearest if c not in left_out][:k]
    trucks = index.search_clip("clip-00010", k, filter="category == truck", exclude=left_out)
    truck_ids = [c for c in nearest if int(c[5:]) % 4 == 1 and c not in {"clip-00010", *left_out}]
    assert [h.clip_id for h in trucks.hits[0]] == truck_ids[:k]
    # Fewer than k left: fewer come back, as with a filter.
    few = index.search_clip("clip-00010", 10, exclude=[f"clip-{i:05d}" for i in range(N) if i not in (10, 20, 30)])
    assert sorted(h.clip_id for h in few.hits[0]) == ["clip-00020", "clip-00030"]
    assert few.I.shape == (1, 10) and (few.I[0, 2:] == -1).all() and np.isneginf(few.D[0, 2:]).all()
    with pytest.raises(TypeError, match="sequence of clip ids"):
        index.search_clip("clip-00010", k, exclude="clip-00011")


def test_add_remove_and_stable_ids(index: ClipIndex, vectors: np.ndarray) -> None:
    removed = [f"clip-{i:05d}" for i in range(0, 30)]
    assert index.remove(removed) == 30
    assert "clip-00000" not in index and len(index) == N - 30
    res = index.search(vectors[:30], 20)
    assert not any(h.clip_id in removed for hits in res.hits for h in hits)
    new_ids = index.add(vectors[N:N + 5], metadata_rows(5, offset=N))
    assert new_ids.tolist() == list(range(N, N + 5))  # ids keep growing; removed ones are not reused
    assert index.get(f"clip-{N + 2:05d}")["id"] == N + 2
    np.testing.assert_allclose(index.reconstruct(f"clip-{N:05d}"),
                               vectors[N] / np.linalg.norm(vectors[N]), rtol=1e-5)
    with pytest.raises(MetadataError, match="already in the index"):
        index.add(vectors[:1], [{"clip_id": "clip-00050"}])
    with pytest.raises(MetadataError, match="unknown clip ids"):
        index.remove(["nope"])


def test_round_trip(tmp_path: Path, index: ClipIndex, vectors: np.ndarray) -> None:
    index.remove(["clip-00001"])
    index.save(tmp_path / "clips")
    loaded = ClipIndex.load(tmp_path / "clips")
    a = index.search(vectors[N:], 7, filter="category == car")
    b = loaded.search(vectors[N:], 7, filter="category == car")
    np.testing.assert_array_equal(a.I, b.I)
    assert a.hits == b.hits
    assert loaded.fields == index.fields and "clip-00001" not in loaded


def test_bad_input(index: ClipIndex, vectors: np.ndarray) -> None:
    with pytest.raises(MetadataError, match="row 2.*clip_id"):
        ClipIndex.build(vectors[:3], [{"clip_id": "a"}, {"clip_id": "b"}, {"log_id": "x"}])
    with pytest.raises(MetadataError, match="duplicate clip ids"):
        ClipIndex.build(vectors[:2], [{"clip_id": "a"}, {"clip_id": "a"}])
    with pytest.raises(MetadataError, match="2 metadata rows for 3 vectors"):
        ClipIndex.build(vectors[:3], [{"clip_id": "a"}, {"clip_id": "b"}])
    with pytest.raises(FilterError, match="valid fields"):
        index.search(vectors[:1], 3, filter="colour == red")
    with pytest.raises(InvalidKError):
        index.search(vectors[:1], N + 1)
    with pytest.raises(IdError):
        index.vectors.remove([10**6])


def test_build_from_a_table(vectors: np.ndarray) -> None:
    table = pa.Table.from_pylist(metadata_rows(50))
    index = ClipIndex.build(vectors[:50], table, factory="Flat")
    assert index.search(vectors[:1], 1).hits[0][0].clip_id == "clip-00000"
