"""Frame-blocked compressed arrays read back as the array they store, by any frame selection."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from encoders.clips.blocks import BlockArray, BlockFileError, write_blocks


@pytest.fixture
def stored(tmp_path: Path) -> tuple[np.ndarray, BlockArray]:
    rng = np.random.default_rng(0)
    x = np.where(rng.random((21, 3, 5, 4)) < 0.05, rng.random((21, 3, 5, 4)), 0).astype(np.float16)
    write_blocks(tmp_path / "x.blocks", x, block_frames=8)  # blocks of 8, 8 and 5 frames
    return x, BlockArray(tmp_path / "x.blocks")


@pytest.mark.parametrize("key", [0, 20, -1, slice(None), slice(5, 13), slice(None, None, 3),
                                 np.array([20, 0, 7, 8, 8]), (slice(None), [0, 2]), (np.array([3, 17]), 1, 2)],
                         ids=str)
def test_every_selection_reads_what_numpy_reads(stored: tuple[np.ndarray, BlockArray], key: object) -> None:
    x, blocks = stored
    assert np.array_equal(blocks[key], x[key])  # type: ignore[index]
    assert blocks.shape == x.shape and blocks.dtype == x.dtype and len(blocks) == 21


def test_sparse_rasters_shrink(tmp_path: Path) -> None:
    x = np.zeros((40, 15, 64, 32), np.float16)
    x[:, 3, 10:14, 5:9] = 0.5
    write_blocks(tmp_path / "x.blocks", x)
    assert (tmp_path / "x.blocks").stat().st_size < x.nbytes / 50


def _photo(frames: int, seed: int = 0) -> np.ndarray:
    """(F, 32, 64, 3) uint8 images whose neighbouring pixels are alike, as in a photograph."""
    rng = np.random.default_rng(seed)
    steps = rng.integers(-3, 4, (frames, 32, 64, 3))
    return np.clip(128 + np.cumsum(steps, axis=2) + rng.integers(0, 60, (frames, 32, 1, 3)), 0, 255).astype(np.uint8)


def test_images_stored_as_differences_read_back_byte_for_byte_and_take_fewer_bytes(tmp_path: Path) -> None:
    x = _photo(21)
    x[3, :, 10:] = 255  # wrapping differences (0 - 255) too
    write_blocks(tmp_path / "plain.blocks", x)
    write_blocks(tmp_path / "image.blocks", x, image=True)
    image = BlockArray(tmp_path / "image.blocks")
    assert np.array_equal(image[:], x) and np.array_equal(image[np.array([20, 3, 9])], x[[20, 3, 9]])
    assert b'"filter": "sub"' in (tmp_path / "image.blocks").read_bytes()[:4096]
    assert (tmp_path / "image.blocks").stat().st_size < 0.8 * (tmp_path / "plain.blocks").stat().st_size
    assert np.array_equal(BlockArray(tmp_path / "plain.blocks")[:], x)  # files without the filter read as before
    with pytest.raises(ValueError, match=r"bad.blocks: images are \(F, H, W, 3\) uint8"):
        write_blocks(tmp_path / "bad.blocks", x.astype(np.float32), image=True)


def test_an_unknown_filter_is_refused_naming_the_file(tmp_path: Path) -> None:
    write_blocks(tmp_path / "x.blocks", _photo(4), image=True)
    data = (tmp_path / "x.blocks").read_bytes().replace(b'"filter": "sub"', b'"filter": "up!"')
    (tmp_path / "x.blocks").write_bytes(data)
    with pytest.raises(BlockFileError, match=r"x.blocks: blocks stored with filter 'up!'"):
        BlockArray(tmp_path / "x.blocks")


def test_damaged_and_truncated_files_are_named(stored: tuple[np.ndarray, BlockArray], tmp_path: Path) -> None:
    path = tmp_path / "x.blocks"
    data = bytearray(path.read_bytes())
    data[-20] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(BlockFileError, match=r"x.blocks: block 2 is damaged"):
        BlockArray(path)[20]
    path.write_bytes(bytes(data[:-10]))
    with pytest.raises(BlockFileError, match=r"x.blocks: \d+ bytes, its header says \d+ \(truncated or extended\)"):
        BlockArray(path)
    path.write_bytes(b"\x93NUMPY")
    with pytest.raises(BlockFileError, match="x.blocks: not a block file"):
        BlockArray(path)


def test_zlib_blocks_of_earlier_files_still_read(tmp_path: Path) -> None:
    import json
    import zlib

    from encoders.clips.blocks import MAGIC

    x = np.arange(20 * 6, dtype=np.uint16).reshape(20, 6)
    blocks = [zlib.compress(x[i:i + 8].tobytes(), 1) for i in range(0, 20, 8)]
    header = json.dumps({"dtype": x.dtype.str, "shape": list(x.shape), "block_frames": 8,
                         "offsets": np.cumsum([0] + [len(b) for b in blocks]).tolist()}).encode()
    (tmp_path / "x.blocks").write_bytes(MAGIC + len(header).to_bytes(4, "little") + header + b"".join(blocks))
    assert np.array_equal(BlockArray(tmp_path / "x.blocks")[:], x)


def test_a_block_is_decompressed_once_for_every_reader_of_its_file(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    from encoders.clips import blocks as blocks_module

    x = np.arange(24 * 6, dtype=np.uint8).reshape(24, 6)
    write_blocks(tmp_path / "x.blocks", x, block_frames=8)
    calls = []
    real = blocks_module.BlockArray._decompress
    monkeypatch.setattr(blocks_module.BlockArray, "_decompress",
                        lambda self, *args: calls.append(1) or real(self, *args))
    for _ in range(3):  # a clip table reading windows of one log: each reader opens the file anew
        reader = BlockArray(tmp_path / "x.blocks")
        assert np.array_equal(reader[np.array([0, 9, 23, 1])], x[[0, 9, 23, 1]])
    assert len(calls) == 3  # the three blocks, once each


def test_a_file_written_again_never_serves_its_old_blocks(tmp_path: Path) -> None:
    path = tmp_path / "x.blocks"
    write_blocks(path, np.zeros((10, 4), np.int32))
    assert BlockArray(path)[3].sum() == 0
    write_blocks(path, np.ones((10, 4), np.int32))
    assert BlockArray(path)[3].sum() == 4


def test_decoded_blocks_stay_within_their_budget(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from encoders.clips import blocks
    from scenesearch_base.lru import Lru

    monkeypatch.setattr(blocks, "_DECODED", Lru(1000, lambda block: block.nbytes))
    path = tmp_path / "x.blocks"
    write_blocks(path, np.arange(80 * 10, dtype=np.int32).reshape(80, 10), block_frames=8)  # 320-byte blocks
    array = BlockArray(path)
    assert np.array_equal(array[:], np.arange(800).reshape(80, 10))
    assert len(blocks._DECODED) == 3 and blocks._DECODED.total == 960  # the last 3 blocks read
    assert np.array_equal(array[5], np.arange(50, 60))  # an evicted block is read again
