"""The files of an IVF index whose inverted lists stay on disk, and reading them back.

FAISS keeps such lists in ``OnDiskInvertedLists``: one file of codes and ids (``index.ivfdata``)
that searches memory-map, so only the lists a query probes are paged in, and the kernel may drop
them again. ``index.faiss`` then holds the quantizer, the codec and each list's place in that file,
and names the file. Two things around FAISS's format are handled here:

* **Where the data file is.** FAISS stores the data file's path as written and opens exactly that
  path. Its ``IO_FLAG_ONDISK_SAME_DIR`` looks beside ``index.faiss`` instead, but prints a line on
  standard output at every open (which would corrupt ``--json`` output). So ``index.faiss`` names
  the data file by its bare name, and reading substitutes the full path in memory before FAISS
  parses the bytes: a saved directory can be moved or copied as a whole.
* **Stored vectors by id.** An IVF index finds a vector by id through a hash table in memory
  (8–16 bytes a vector, more with the table's own overhead); here ``ivf_locations.npy`` holds, for
  each id of ``ids.npy`` (same order), its list and the byte offset of its code in the data file.
  It is memory-mapped too, and reconstructing decodes the codes read from the mapped data file.

Such an index is read-only: it is opened without write access, so no search can change a byte the
manifest's checksums cover.
"""

from __future__ import annotations

import struct
from pathlib import Path

import faiss
import numpy as np

from indexes.errors import IndexFileError, faiss_message

IVFDATA_FILE = "index.ivfdata"
LOCATIONS_FILE = "ivf_locations.npy"
#: ``storage`` value in a manifest's extra fields for an index with on-disk lists.
ON_DISK = "on_disk"


def _name_record(name: str) -> bytes:
    """How FAISS serialises a file name: its length as a little-endian 64-bit integer, then the bytes."""
    raw = name.encode()
    return struct.pack("<Q", len(raw)) + raw


def ondisk_lists(index: faiss.Index) -> faiss.OnDiskInvertedLists:
    """The ``OnDiskInvertedLists`` of ``index``.

    Raises:
        ValueError: ``index`` keeps its lists elsewhere.
    """
    ivf = faiss.try_extract_index_ivf(index)
    lists = None if ivf is None or ivf.invlists is None else faiss.downcast_InvertedLists(ivf.invlists)
    if not isinstance(lists, faiss.OnDiskInvertedLists):
        raise ValueError("the index does not keep its inverted lists on disk")
    return lists


def write_ondisk_index(index: faiss.Index, path: Path) -> None:
    """Write ``index.faiss`` naming its data file by bare name (see the module docstring)."""
    lists = ondisk_lists(index)
    actual = lists.filename
    lists.filename = IVFDATA_FILE  # only read when the lists are mapped again or resized
    try:
        faiss.write_index(index, str(path))
    finally:
        lists.filename = actual


def read_ondisk_index(path: Path) -> faiss.Index:
    """Read ``index.faiss`` written by :func:`write_ondisk_index`, its lists mapped read-only from
    the data file beside it.

    Raises:
        IndexFileError: unreadable, or not naming its data file as expected.
    """
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise IndexFileError(path, f"unreadable: {exc}") from None
    record = _name_record(IVFDATA_FILE)
    if raw.count(record) != 1:
        raise IndexFileError(path, f"does not name its list data as {IVFDATA_FILE!r}; rebuild the index")
    data = path.parent.resolve() / IVFDATA_FILE
    patched = raw.replace(record, _name_record(str(data)))
    try:
        index = faiss.deserialize_index(np.frombuffer(patched, dtype=np.uint8), faiss.IO_FLAG_READ_ONLY)
    except RuntimeError as exc:
        raise IndexFileError(path, f"FAISS cannot read it (truncated or corrupt?): {faiss_message(exc)}") from None
    # By default every search starts threads that read the probed lists ahead. Starting them costs
    # more than the reads they overlap, warm or with the data evicted from the page cache
    # (docs/research/index-beyond-memory.md).
    ondisk_lists(index).prefetch_nthread = 0
    return index


def list_locations(index: faiss.Index) -> tuple[np.ndarray, np.ndarray]:
    """Every stored id and where its code is, sorted by id.

    Returns:
        ids: (N,) int64, ascending.
        locations: (N, 2) int64: list number, byte offset of the code in the data file.
    """
    lists = ondisk_lists(index)
    code_size = int(lists.code_size)
    parts_ids, parts_loc = [], []
    for list_no in range(int(lists.nlist)):
        n = int(lists.list_size(list_no))
        if n == 0:
            continue
        offset = int(lists.lists.at(list_no).offset)  # type: ignore[attr-defined]  # a SWIG vector
        parts_ids.append(faiss.rev_swig_ptr(lists.get_ids(list_no), n).copy())
        loc = np.empty((n, 2), dtype=np.int64)
        loc[:, 0] = list_no
        loc[:, 1] = offset + code_size * np.arange(n, dtype=np.int64)
        parts_loc.append(loc)
    if not parts_ids:
        return np.empty(0, np.int64), np.empty((0, 2), np.int64)
    ids = np.concatenate(parts_ids)
    order = np.argsort(ids, kind="stable")
    return ids[order], np.concatenate(parts_loc)[order]


class CodeLocator:
    """Stored vectors of an on-disk index by position in its sorted ids (see the module docstring)."""

    def __init__(self, directory: Path, index: faiss.Index, count: int) -> None:
        path = directory / LOCATIONS_FILE
        try:
            self._locations = np.load(path, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise IndexFileError(path, f"not a readable .npy file ({exc}); expected int64 ({count}, 2)") from None
        if self._locations.dtype != np.int64 or self._locations.shape != (count, 2):
            raise IndexFileError(path, f"expected int64 ({count}, 2), got {self._locations.dtype} "
                                       f"{self._locations.shape}")
        self._data_path = directory / IVFDATA_FILE
        self._data: np.ndarray | None = None  # mapped on first use: most searches never reconstruct
        self._index = index
        ivf = faiss.extract_index_ivf(index)
        self._code_size = int(ivf.code_size)
        self._coarse_size = int(ivf.coarse_code_size())  # type: ignore[attr-defined]  # missing from the stubs

    def reconstruct(self, positions: np.ndarray) -> np.ndarray:
        """(M, d) decoded vectors of the ids at ``positions`` (M,) of the sorted ids."""
        if self._data is None:
            self._data = np.memmap(self._data_path, dtype=np.uint8, mode="r")
        loc = np.asarray(self._locations[positions])
        codes = np.empty((len(loc), self._coarse_size + self._code_size), dtype=np.uint8)
        # FAISS's standalone code of an IVF entry: the list number (little-endian), then the code.
        codes[:, :self._coarse_size] = loc[:, :1].astype("<u8").view(np.uint8)[:, :self._coarse_size]
        codes[:, self._coarse_size:] = self._data[loc[:, 1:2] + np.arange(self._code_size)]
        return np.asarray(self._index.sa_decode(codes), dtype=np.float32)

    @property
    def files(self) -> tuple[Path, Path]:
        """The data and location files (copied when the index is saved elsewhere)."""
        return self._data_path, self._data_path.parent / LOCATIONS_FILE
