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
