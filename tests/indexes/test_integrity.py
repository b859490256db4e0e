"""Checksums verified on open: flipped bytes found, stamps that save the work, explicit skips that say so."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import indexes.integrity as integrity
from indexes.clip_index import ClipIndex
from indexes.errors import IndexFileError, ManifestError, UnsupportedFormatError
from indexes.integrity import STAMP_NAME, IntegrityWarning, PendingVerification, Verify, as_verify, seal
from indexes.persistence import load_array, read_manifest
from indexes.sharded import ShardedIndex
from indexes.vector_index import VectorIndex

Data = tuple[np.ndarray, np.ndarray]


def flip_bytes(path: Path, count: int = 64, keep_times: bool = True) -> None:
    """Invert ``count`` bytes in the middle of ``path``; same size, and (by default) the same timestamps."""
    st = path.stat()
    raw = bytearray(path.read_bytes())
    mid = len(raw) // 2
    for i in range(mid, min(len(raw), mid + count)):
        raw[i] ^= 0xFF
    with path.open("r+b") as f:  # in place: the same inode, as a disk fault or a careless tool would
        f.write(bytes(raw))
    if keep_times:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def _clip_index(tmp_path: Path, xb: np.ndarray) -> Path:
    rows = [{"clip_id": f"c{i}", "category": "car" if i % 2 else "bus"} for i in range(len(xb))]
    ClipIndex.build(xb, rows, factory="Flat").save(tmp_path / "clips")
    return tmp_path / "clips"


@pytest.mark.parametrize("name", ["index.faiss", "metadata.parquet", "ids.npy"])
def test_flipped_bytes_are_refused_naming_the_file(tmp_path: Path, data: Data, name: str) -> None:
    directory = _clip_index(tmp_path, data[0][:500])
    ClipIndex.load(directory)  # a first open writes a stamp; it must not hide the damage
    flip_bytes(directory / name)
    for mmap in (False, True):
        with pytest.raises(IndexFileError, match=rf"{name}: checksum differs"):
            ClipIndex.load(directory, mmap=mmap)


def test_a_flip_that_still_parses_changes_results_unless_verified(tmp_path: Path, data: Data) -> None:
    # What an unverified open would serve: FAISS reads the damaged vectors and answers differently.
    xb, xq = data
    directory = _clip_index(tmp_path, xb[:500])
    before = ClipIndex.load(directory).search(xq, 5).I
    flip_bytes(directory / "index.faiss", count=4096)
    with pytest.warns(IntegrityWarning, match="checksums not verified"):
        damaged = ClipIndex.load(directory, verify="off")
    assert not np.array_equal(damaged.search(xq, 5).I, before)
    with pytest.raises(IndexFileError, match="checksum"):
        ClipIndex.load(directory, verify="full")


def test_stamp_skips_files_already_verified(tmp_path: Path, data: Data, monkeypatch: pytest.MonkeyPatch) -> None:
    directory = _clip_index(tmp_path, data[0][:300])
    manifest = read_manifest(directory)
    # Files written a moment ago are "racy" (changed within the margin of the hashing): hashed again.
    first = PendingVerification(directory, manifest.files, Verify.CACHED)
    first.wait()
    assert sorted(first.hashed) == sorted(manifest.files)
    assert sorted(PendingVerification(directory, manifest.files, Verify.CACHED).hashed) == sorted(manifest.files)
    monkeypatch.setattr(integrity, "STAMP_MARGIN_NS", 0)  # as if the files were older than the margin
    PendingVerification(directory, manifest.files, Verify.CACHED).wait()
    assert PendingVerification(directory, manifest.files, Verify.CACHED).hashed == []
    assert sorted(PendingVerification(directory, manifest.files, Verify.FULL).hashed) == sorted(manifest.files)
    stamp = json.loads((directory / STAMP_NAME).read_text())
    assert set(stamp["files"]) == set(manifest.files)
    # A change with the times put back still changes the inode's change time: hashed, and refused.
    flip_bytes(directory / "index.faiss")
    assert PendingVerification(directory, manifest.files, Verify.CACHED).hashed == ["index.faiss"]
    with pytest.raises(IndexFileError, match="index.faiss: checksum differs"):
        ClipIndex.load(directory)
    # A damaged stamp is ignored, never trusted.
    (directory / STAMP_NAME).write_text("{broken")
    with pytest.raises(IndexFileError, match="checksum differs"):
        ClipIndex.load(directory)


def test_stamp_is_not_listed_in_a_new_manifest(tmp_path: Path, data: Data) -> None:
    directory = _clip_index(tmp_path, data[0][:100])
    loaded = ClipIndex.load(directory)
    assert (directory / STAMP_NAME).exists()
    loaded.save(tmp_path / "copy")
    assert STAMP_NAME not in read_manifest(tmp_path / "copy").files


def _manifest_to_edit(tmp_path: Path, data: Data) -> tuple[Path, dict[str, Any]]:
    """A saved 100-clip index's manifest: its path, and its content to edit and write back."""
    path = _clip_index(tmp_path, data[0][:100]) / "manifest.json"
    return path, json.loads(path.read_text())


def test_edited_manifest_is_refused(tmp_path: Path, data: Data) -> None:
    path, raw = _manifest_to_edit(tmp_path, data)
    path.write_text(json.dumps({**raw, "count": 99}))
    with pytest.raises(ManifestError, match="content differs from its checksum"):
        ClipIndex.load(path.parent)
    raw.pop("content_sha256")
    path.write_text(json.dumps(raw))  # a version-2 manifest must carry its checksum
    with pytest.raises(ManifestError, match="content_sha256"):
        ClipIndex.load(path.parent)


def test_an_older_format_is_refused_with_what_to_do(tmp_path: Path, data: Data) -> None:
    path, raw = _manifest_to_edit(tmp_path, data)
    raw.pop("content_sha256")
    path.write_text(json.dumps({**raw, "format_version": 1}))
    with pytest.raises(UnsupportedFormatError, match="version 1 was built by an older version.*build it again"):
        ClipIndex.load(path.parent)


def test_manifest_must_list_every_file_it_reads(tmp_path: Path, data: Data) -> None:
    path, raw = _manifest_to_edit(tmp_path, data)
    del raw["files"]["metadata.parquet"]
    path.write_text(json.dumps(seal(raw)))
    with pytest.raises(ManifestError, match="does not list metadata.parquet"):
        ClipIndex.load(path.parent)


def test_sharded_index_verifies_every_shard(tmp_path: Path, data: Data) -> None:
    xb, _ = data
    ShardedIndex.build(xb[:600], factory="Flat", shard_size=250).save(tmp_path / "s")
    assert len(ShardedIndex.load(tmp_path / "s")) == 600
    flip_bytes(tmp_path / "s" / "shard_0002" / "index.faiss")
    with pytest.raises(IndexFileError, match=r"shard_0002/index\.faiss: checksum differs"):
        ShardedIndex.load(tmp_path / "s")


def test_vector_index_refuses_corruption_in_any_file(tmp_path: Path, data: Data) -> None:
    VectorIndex.build(data[0][:200], factory="Flat").save(tmp_path / "v")
    flip_bytes(tmp_path / "v" / "removed.npy", count=1)
    with pytest.raises(IndexFileError, match=r"removed\.npy: checksum differs"):
        VectorIndex.load(tmp_path / "v")


def test_verify_values() -> None:
    assert as_verify(True) is Verify.FULL and as_verify(False) is Verify.OFF and as_verify("cached") is Verify.CACHED
    with pytest.raises(ValueError, match="cached, full, off"):
        as_verify("sometimes")


def test_no_warning_when_verifying(tmp_path: Path, data: Data) -> None:
    directory = _clip_index(tmp_path, data[0][:100])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ClipIndex.load(directory)
        ClipIndex.load(directory, verify="full")


@pytest.mark.parametrize(("content", "pattern"), [
    (b"not an npy file at all", r"ids\.npy: not a readable \.npy file .*expected a int64 array of shape \(N,\)"),
    ("float", r"ids\.npy: expected a int64 array of shape \(N,\), got float64 \(3,\)"),
    ("2d", r"ids\.npy: expected a int64 array of shape \(N,\), got int64 \(2, 2\)"),
])
def test_npy_parse_errors_name_file_and_expectation(tmp_path: Path, content: bytes | str, pattern: str) -> None:
    path = tmp_path / "ids.npy"
    if content == "float":
        np.save(path, np.zeros(3))
    elif content == "2d":
        np.save(path, np.zeros((2, 2), np.int64))
    else:
        assert isinstance(content, bytes)
        path.write_bytes(content)
    with pytest.raises(IndexFileError, match=pattern):
        load_array(path, np.int64, ("N",))
    np.save(path, np.zeros(4, np.int64))
    with pytest.raises(IndexFileError, match=r"shape \(5,\), got int64 \(4,\)"):
        load_array(path, np.int64, (5,))
