# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import faiss
import numpy as np
import pytest

from indexes.errors import IndexFileError, ManifestError, ReadOnlyIndexError, UnsupportedFormatError
from indexes.integrity import seal
from indexes.persistence import FORMAT_VERSION
from indexes.vector_index import VectorIndex
from scenesearch_base.atomic import sweep_stale

Data = tuple[np.ndarray, np.ndarray]
ROOT = Path(__file__).resolve().parents[2]


def _write_sealed(path: Path, manifest: dict) -> None:
    """Write an edited manifest with a matching content checksum (as a consistent writer would)."""
    path.write_text(json.dumps(seal(manifest)))


def _saved_file(tmp_path: Path, xb: np.ndarray, name: str) -> Path:
    """Save a Flat index of ``xb`` (N, d) to ``tmp_path/idx``; the path of its file ``name``."""
    VectorIndex.build(xb, factory="Flat").save(tmp_path / "idx")
    return tmp_path / "idx" / name


@pytest.mark.parametrize("factory", ["Flat", "HNSW16", "IVF32,Flat"])
def test_round_trip_gives_identical_results(tmp_path: Path, data: Data, factory: str) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, np.arange(len(xb)) + 100, factory=factory)
    index.remove([100, 101, 150])  # tombstones for HNSW, in place otherwise
    D, I = index.search(xq, 10)
    index.save(tmp_path / "idx")
    manifest = json.loads((tmp_path / "idx" / "manifest.json").read_text())
    assert manifest["format_version"] == FORMAT_VERSION and manifest["dim"] == 32
    assert manifest["metric"] == "cosine" and manifest["factory"] == factory and manifest["count"] == len(xb) - 3
    assert all(len(e["sha256"]) == 64 for e in manifest["files"].values())
    loaded = VectorIndex.load(tmp_path / "idx")
    assert len(loaded) == len(index) and loaded.search_knob == index.search_knob
    assert loaded.info == json.loads(json.dumps(index.info))
    D2, I2 = loaded.search(xq, 10)
    np.testing.assert_array_equal(I, I2)
    np.testing.assert_allclose(D, D2)
    assert not np.isin(I2, [100, 101, 150]).any()
    loaded.add(xb[:1])  # still writable
    assert loaded.add(xb[:1])[0] > len(xb) + 100


@pytest.mark.parametrize("factory", ["IVF32,Flat", "Flat"])
def test_mmap_load_is_read_only_and_equal(tmp_path: Path, data: Data, factory: str) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, factory=factory)
    index.save(tmp_path / "idx")
    mapped = VectorIndex.load(tmp_path / "idx", mmap=True)
    np.testing.assert_array_equal(mapped.search(xq, 5)[1], index.search(xq, 5)[1])
    ivf = faiss.try_extract_index_ivf(mapped.faiss_index)
    if ivf is not None:  # the lists are a read-only view of the file, not a copy in memory
        assert isinstance(faiss.downcast_InvertedLists(ivf.invlists), faiss.OnDiskInvertedLists)
    with pytest.raises(ReadOnlyIndexError):
        mapped.add(xb[:1])
    with pytest.raises(ReadOnlyIndexError):
        mapped.remove([0])


def test_truncated_index_file_is_refused(tmp_path: Path, data: Data) -> None:
    path = _saved_file(tmp_path, data[0], "index.faiss")
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(IndexFileError, match=r"index\.faiss.*truncated"):
        VectorIndex.load(tmp_path / "idx")
    with pytest.raises(IndexFileError, match="truncated"):
        VectorIndex.load(tmp_path / "idx", mmap=True)


def test_truncated_file_without_manifest_check_fails_clearly(tmp_path: Path, data: Data) -> None:
    path = _saved_file(tmp_path, data[0], "index.faiss")
    path.write_bytes(path.read_bytes()[:1000])
    manifest = json.loads((tmp_path / "idx" / "manifest.json").read_text())
    manifest["files"]["index.faiss"]["size_bytes"] = 1000  # a manifest that agrees with the damage
    _write_sealed(tmp_path / "idx" / "manifest.json", manifest)
    with pytest.warns(UserWarning, match="checksums not verified"), \
            pytest.raises(IndexFileError, match=r"index\.faiss"):
        VectorIndex.load(tmp_path / "idx", verify=False)


def test_corrupt_bytes_fail_the_checksum(tmp_path: Path, data: Data) -> None:
    path = _saved_file(tmp_path, data[0], "ids.npy")
    raw = bytearray(path.read_bytes())
    raw[-3] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(IndexFileError, match="checksum"):
        VectorIndex.load(tmp_path / "idx")


def test_manifest_mismatches_are_refused(tmp_path: Path, data: Data) -> None:
    path = _saved_file(tmp_path, data[0][:100], "manifest.json")
    good = json.loads(path.read_text())
    for key, value, error, pattern in [
        ("dim", 64, ManifestError, "dimension"), ("count", 7, ManifestError, "vectors"),
        ("kind", "clip_index", ManifestError, "kind"), ("metric", "l2", ManifestError, "metric"),
        ("metric", "hamming", ManifestError, "metric"),
        ("format_version", FORMAT_VERSION + 1, UnsupportedFormatError, "newer"),
    ]:
        _write_sealed(path, {**good, key: value})
        with pytest.raises(error, match=pattern):
            VectorIndex.load(tmp_path / "idx")
    path.write_text("{not json")
    with pytest.raises(ManifestError, match="unreadable"):
        VectorIndex.load(tmp_path / "idx")
    path.unlink()
    with pytest.raises(ManifestError, match="missing"):
        VectorIndex.load(tmp_path / "idx")
    with pytest.raises(IndexFileError, match="no index"):
        VectorIndex.load(tmp_path / "nothing")


def test_save_refuses_to_overwrite_when_asked(tmp_path: Path, data: Data) -> None:
    index = VectorIndex.build(data[0][:100], factory="Flat")
    index.save(tmp_path / "idx")
    with pytest.raises(FileExistsError):
        index.save(tmp_path / "idx", overwrite=False)


_CHILD = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {root!r})
    import numpy as np
    import faiss
    from indexes.vector_index import VectorIndex
    index = VectorIndex.load({target!r})
    index.add(np.random.default_rng(0).normal(size=(50, 32)).astype(np.float32))
    real_write = faiss.write_index
    def slow_write(ix, path):
        real_write(ix, path)
        print("writing", flush=True)
        time.sleep(60)  # killed here, with the new index half written
    faiss.write_index = slow_write
    index.save({target!r})
""")


def test_kill_during_save_leaves_the_previous_index_loadable(tmp_path: Path, data: Data) -> None:
    xb, xq = data
    target = tmp_path / "idx"
    before = VectorIndex.build(xb[:500], factory="Flat")
    before.save(target)
    code = _CHILD.format(root=str(ROOT), target=str(target))
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "writing"
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.wait(timeout=30)
    loaded = VectorIndex.load(target)
    assert len(loaded) == 500
    np.testing.assert_array_equal(loaded.search(xq, 5)[1], before.search(xq, 5)[1])


def test_kill_at_random_moments_of_repeated_saves(tmp_path: Path, data: Data) -> None:
    xb, _ = data
    target = tmp_path / "idx"
    VectorIndex.build(xb, factory="Flat").save(target)
    loop = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from indexes.vector_index import VectorIndex
        index = VectorIndex.load({str(target)!r})
        print("ready", flush=True)
        while True:
            index.save({str(target)!r})
    """)
    rng = np.random.default_rng(1)
    for _ in range(3):
        child = subprocess.Popen([sys.executable, "-c", loop], stdout=subprocess.PIPE, text=True)
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        time.sleep(float(rng.uniform(0.05, 0.3)))
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=30)
        loaded = VectorIndex.load(target)
        assert len(loaded) == len(xb)


def test_kill_between_the_two_renames_of_a_save(tmp_path: Path, data: Data) -> None:
    # A save moves the old directory aside, then moves the new one in; a kill between the two
    # leaves only the aside copy, which loading still finds.
    index = VectorIndex.build(data[0][:200], factory="Flat")
    index.save(tmp_path / "idx")
    (tmp_path / "idx").rename(tmp_path / ".idx.old")
    assert len(VectorIndex.load(tmp_path / "idx")) == 200


_KILLED_SAVE = textwrap.dedent("""
    import sys
    sys.path[:0] = [{root!r}, {root!r} + "/tests/scenesearch_base"]
    import kill_points
    import numpy as np
    from indexes.clip_index import ClipIndex
    kill_points.install({target!r}, {point!r})
    index = ClipIndex.load({target!r})
    x = np.random.default_rng(5).normal(size=(40, 32)).astype(np.float32)
    index.add(x, [{{"clip_id": f"new{{i}}", "category": "car"}} for i in range(40)])
    index.save({target!r})
""")


@pytest.mark.parametrize("point", ["after_write:index.faiss", "before_swap", "between_renames", "after_swap"])
def test_kill_at_each_point_of_a_clip_index_save(tmp_path: Path, data: Data, point: str) -> None:
    """A save killed anywhere leaves an index that loads and answers as before (or as after, once swapped)."""
    from indexes.clip_index import ClipIndex

    xb, xq = data
    target = tmp_path / "clips"
    ClipIndex.build(xb[:300], [{"clip_id": f"c{i}", "category": "bus"} for i in range(300)],
                    factory="Flat").save(target)
    before = ClipIndex.load(target).search(xq, 5)
    code = _KILLED_SAVE.format(root=str(ROOT), target=str(target), point=point)
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == -signal.SIGKILL
    assert any(p.name.startswith(".clips.") for p in tmp_path.iterdir())  # the kill left debris
    loaded = ClipIndex.load(target)
    assert len(loaded) == (340 if point == "after_swap" else 300)
    if point != "after_swap":
        np.testing.assert_array_equal(loaded.search(xq, 5).I, before.I)
    # The next save (here: a new process's first write into the folder) leaves only the index.
    sweep_stale(tmp_path, force=True)
    loaded.save(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clips"]
    assert len(ClipIndex.load(target)) == len(loaded)


def test_concurrent_writers_and_readers_of_one_index_never_break_each_other(tmp_path: Path, data: Data) -> None:
    """Two processes saving the same index over and over while a third loads it: every save and
    every load succeeds (a load never meets the gap between a swap's renames, nor files of two
    versions), no writer removes the other's temporary folder, and what is left is one complete index."""
    target = tmp_path / "idx"
    VectorIndex.build(data[0][:200], factory="Flat").save(target)
    loop = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        import scenesearch_base.atomic
        from indexes.vector_index import VectorIndex
        scenesearch_base.atomic.SWEEP_INTERVAL_S = 0.0  # sweep on every write: the hardest case for the other writer
        index = VectorIndex.load({str(target)!r})
        for _ in range(25):
            index.save({str(target)!r})
    """)
    reads = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from indexes.vector_index import VectorIndex
        for _ in range(50):
            assert len(VectorIndex.load({str(target)!r})) == 200
    """)
    processes = [subprocess.Popen([sys.executable, "-c", code]) for code in (loop, loop, reads)]
    assert [p.wait(timeout=120) for p in processes] == [0, 0, 0]
    assert len(VectorIndex.load(target)) == 200
    assert sorted(p.name for p in tmp_path.iterdir()) == ["idx"]
