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

import numpy as np
import pytest

from indexes.errors import IndexFileError, ManifestError, ReadOnlyIndexError, UnsupportedFormatError
from indexes.persistence import FORMAT_VERSION
from indexes.vector_index import VectorIndex

Data = tuple[np.ndarray, np.ndarray]
ROOT = Path(__file__).resolve().parents[2]


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
    (tmp_path / "idx" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(IndexFileError, match=r"index\.faiss"):
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
        path.write_text(json.dumps({**good, key: value}))
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
