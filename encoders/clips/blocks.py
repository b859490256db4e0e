"""Frame-blocked compressed arrays: a log's per-frame rasters stored in zstd blocks of a few frames.

A rendered log's arrays are mostly zeros (instance rasters, LiDAR occupancy), the static map and
sparse tag targets: compressed, they take a small fraction of their size as plain ``.npy`` files
(``docs/research/ingest-profile.md``). Readers take frames at random (a training window, a clip), so
the frames are compressed in blocks of :data:`BLOCK_FRAMES` and a read decompresses only the blocks it
touches. Decoded blocks are kept per process up to :data:`DECODED_CACHE_BYTES`, shared by every reader
of a file: the clips of one log cover its frames many times over (a clip's 12 frames spread over a
window of up to the whole log), so without the shared cache an index build would decompress each block
many times.

Blocks are zstd (level 3, pyarrow's codec): about as small as zlib's level 1 on rendered logs, and
several times cheaper to write and read (docs/research/ingest-profile.md). zstd frames carry no checksum, so
the header keeps each compressed block's CRC-32 and a damaged block is refused, never read as other
values. Files written with zlib blocks (no ``codec`` in the header) still read.

RGB images (the camera frames, the object crops) are stored with PNG's Sub filter (``filter: sub``
in the header): each byte is kept as its difference, modulo 256, from the byte one pixel to its left,
and the reader adds them up again, to the same bytes. Neighbouring pixels of a photograph are alike,
so the differences are small numbers that zstd packs tighter, at next to no cost; on the sparse
rasters it would cost bytes, so they are stored as they are (docs/research/ingest-profile.md, "Images
stored as differences").

File layout (little-endian)::

    MAGIC (8 bytes)  header length (4 bytes)  header (JSON: dtype, shape, block_frames, offsets, codec, crc32[,
    filter])  blocks

:class:`BlockArray` reads like the memory-mapped array it replaces for what the readers do with one:
``shape``, ``dtype``, ``len``, and indexing whose first key picks frames (an int, a slice or an index
array), the rest applying within them.
"""

from __future__ import annotations

import json
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from scenesearch_base.atomic import atomic_path
from scenesearch_base.lru import Lru

MAGIC = b"SSBLOCK1"
#: Frames per compressed block: a training window of 8 frames touches one or two blocks.
BLOCK_FRAMES = 8
#: The blocks' codec and its level.
CODEC, CODEC_LEVEL = "zstd", 3
#: The filter of RGB images ((F, H, W, 3) uint8): each byte less the byte one pixel to its left.
SUB_FILTER = "sub"


#: Decoded blocks kept per process, in bytes: a demo log's decoded arrays take a small share of it
#: (``docs/research/ingest-profile.md``), so a pass that reads log after log (an index build) decompresses
#: each block about once, and training's random draws find most of a few dozen logs decoded.
DECODED_CACHE_BYTES = 256 << 20
#: Logs whose opened arrays a reader keeps (a few kilobytes each: their headers), least recently used
#: going first: a pass over a fleet's logs would otherwise keep every one.
LOGS_KEPT = 4096


#: The process's most recently used decoded blocks: (file identity, block) → frames.
_DECODED: Lru[tuple[Any, ...], NDArray[Any]] = Lru(DECODED_CACHE_BYTES, lambda block: block.nbytes)


class BlockFileError(ValueError):
    """A block file that is not one, or whose bytes fail their checksum; the message names it."""


def write_blocks(path: Path, array: NDArray[Any], block_frames: int = BLOCK_FRAMES, image: bool = False) -> None:
    """Write ``array`` (F, ...) to ``path`` atomically, in compressed blocks of ``block_frames`` frames;
    ``image``: (F, H, W, 3) uint8 RGB images, stored with the Sub filter (see the module docstring)."""
    array = np.ascontiguousarray(array)
    info: dict[str, Any] = {}
    if image:
        if array.dtype != np.uint8 or array.ndim != 4 or array.shape[-1] != 3:
            raise ValueError(f"{path}: images are (F, H, W, 3) uint8, got {array.shape} {array.dtype}")
        left = array[:, :, :-1]
        array = array.copy()
        array[:, :, 1:] -= left  # wraps modulo 256, as the reader's sum does
        info["filter"] = SUB_FILTER
    codec = pa.Codec(CODEC, compression_level=CODEC_LEVEL)
    blocks = [codec.compress(array[i:i + block_frames], asbytes=True) for i in range(0, array.shape[0], block_frames)]
    offsets = np.concatenate([[0], np.cumsum([len(b) for b in blocks])]).astype(int).tolist()
    header = json.dumps({"dtype": array.dtype.str, "shape": list(array.shape), "block_frames": block_frames,
                         "offsets": offsets, "codec": CODEC, "crc32": [zlib.crc32(b) for b in blocks],
                         **info}).encode()
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(MAGIC + len(header).to_bytes(4, "little") + header)
        for block in blocks:
            fh.write(block)


class BlockArray:
    """A block file opened for reading (see the module docstring); blocks are read when indexed."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        try:
            with self.path.open("rb") as fh:
                head = fh.read(len(MAGIC) + 4)
                if len(head) < len(MAGIC) + 4 or head[:len(MAGIC)] != MAGIC:
                    raise BlockFileError(f"{self.path}: not a block file")
                info = json.loads(fh.read(int.from_bytes(head[len(MAGIC):], "little")))
                self._data_start = fh.tell()
            self.dtype = np.dtype(info["dtype"])
            self.shape: tuple[int, ...] = tuple(int(n) for n in info["shape"])
            self.block_frames = int(info["block_frames"])
            self._offsets = [int(o) for o in info["offsets"]]
            self._codec = str(info.get("codec", "zlib"))
            self._crc32: list[int] | None = [int(c) for c in info["crc32"]] if "crc32" in info else None
            self._filter = info.get("filter")
        except FileNotFoundError:
            raise
        except (OSError, ValueError, KeyError, TypeError) as exc:
            if isinstance(exc, BlockFileError):
                raise
            raise BlockFileError(f"{self.path}: unreadable block file ({exc})") from None
        if self._codec not in ("zlib", CODEC):
            raise BlockFileError(f"{self.path}: blocks compressed with {self._codec!r}, not zlib or {CODEC}")
        if self._filter not in (None, SUB_FILTER) or (self._filter == SUB_FILTER and (
                self.dtype != np.uint8 or len(self.shape) != 4)):
            raise BlockFileError(f"{self.path}: blocks stored with filter {self._filter!r} for "
                                 f"{self.dtype} {list(self.shape)}; this release reads {SUB_FILTER!r} on "
                                 "(F, H, W, C) uint8 images")
        expected_blocks = -(-self.shape[0] // self.block_frames) if self.shape else 0
        stat = self.path.stat()
        if self._crc32 is not None and len(self._crc32) != expected_blocks:
            raise BlockFileError(f"{self.path}: {len(self._crc32)} checksums for {expected_blocks} blocks")
        if len(self._offsets) != expected_blocks + 1 or stat.st_size != self._data_start + self._offsets[-1]:
            raise BlockFileError(f"{self.path}: {stat.st_size} bytes, its header says "
                                 f"{self._data_start + self._offsets[-1]} (truncated or extended)")
        # The file as opened: a file written again since (a log rendered anew) never serves old blocks.
        self._identity = (str(self.path.resolve()), stat.st_ino, stat.st_mtime_ns, stat.st_size)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def _block(self, b: int) -> NDArray[Any]:
        key = (*self._identity, b)
        block = _DECODED.get(key)
        if block is None:
            start, stop = self._offsets[b], self._offsets[b + 1]
            with self.path.open("rb") as fh:
                fh.seek(self._data_start + start)
                data = fh.read(stop - start)
            frames = min(self.block_frames, self.shape[0] - b * self.block_frames)
            block = np.frombuffer(self._decompress(b, data, frames), self.dtype).reshape(frames, *self.shape[1:])
            if self._filter == SUB_FILTER:  # the differences summed along each row, modulo 256
                block = np.cumsum(block, axis=2, dtype=np.uint8)
            _DECODED.put(key, block)
        return block

    def _decompress(self, b: int, data: bytes, frames: int) -> bytes:
        """Block ``b``'s bytes, decompressed; :class:`BlockFileError` when its checksum or codec says damaged."""
        size = frames * int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
        try:
            if self._crc32 is not None and zlib.crc32(data) != self._crc32[b]:
                raise ValueError("checksum mismatch")
            raw = (zlib.decompress(data) if self._codec == "zlib"
                   else pa.Codec(CODEC).decompress(data, decompressed_size=size, asbytes=True))
            if len(raw) != size:
                raise ValueError(f"{len(raw)} bytes, expected {size}")
        except (ValueError, zlib.error, pa.ArrowException) as exc:
            raise BlockFileError(f"{self.path}: block {b} is damaged ({exc})") from None
        return raw

    def _frames(self, frames: NDArray[np.int64]) -> NDArray[Any]:
        out = np.empty((frames.shape[0], *self.shape[1:]), self.dtype)
        # Runs of consecutive frames in one block, each copied by one slice: a clip's frames are in order,
        # so it reads one run per block it touches (a mask per block cost half again as much).
        block_of = frames // self.block_frames
        cuts = (np.flatnonzero(block_of[1:] != block_of[:-1]) + 1).tolist()
        for start, stop in zip([0, *cuts], [*cuts, frames.shape[0]], strict=True):
            if start < stop:
                b = int(block_of[start])
                out[start:stop] = self._block(b)[frames[start:stop] - b * self.block_frames]
        return out

    def __getitem__(self, key: Any) -> Any:
        first, rest = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        if first is Ellipsis or first is None:  # indexes other axes first: read every frame
            return self[:][key]
        if isinstance(first, int | np.integer):
            return self._frames(np.array([int(first) % self.shape[0]]))[0][rest]
        frames = np.arange(self.shape[0])[first]  # a slice or an index array, checked by numpy
        return self._frames(np.asarray(frames, dtype=np.int64))[(slice(None), *rest)]

    def __array__(self, dtype: Any = None, copy: Any = None) -> NDArray[Any]:
        out = self[:]
        return out if dtype is None else out.astype(dtype)


#: What a reader of a rendered log's arrays takes: a block file, or an array in memory (tests, callers
#: that rendered it themselves).
FrameArray = BlockArray | NDArray[Any]

