"""Vectors in ``.npy`` files, read in row ranges without holding them in memory.

A collection too large for memory arrives as several ``.npy`` files of (n_i, d) float vectors
(float32, or float16/float64 converted on reading), optionally each with an (n_i,) int64 ``.npy``
of ids beside it; without id files, rows get the ids 0 … N−1 in file order.

Rows are read with plain file reads (``readinto`` at the row's offset) rather than through a
memory map: the bytes pass through the page cache, which the kernel reclaims at will, instead of
staying mapped into the process, where they would count as its resident memory for as long as the
map lives. Only the headers are read when the files are opened; every problem is an
:class:`~indexes.errors.IndexFileError` naming the file (and the row, for bad values).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format

from indexes.errors import IdError, IndexFileError


@dataclass(frozen=True)
class NpyHeader:
    """Where an ``.npy`` file's array lives.

    Attributes:
        path: the file.
        shape: the array's shape.
        dtype: its element type.
        offset: byte position of the first element.
    """

    path: Path
    shape: tuple[int, ...]
    dtype: np.dtype
    offset: int

    @property
    def rows(self) -> int:
        return self.shape[0]

    @property
    def row_bytes(self) -> int:
        return int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize


def read_npy_header(path: Path) -> NpyHeader:
    """The header of ``path``, checked against the file's size.

    Raises:
        IndexFileError: missing, not an ``.npy`` file, Fortran-ordered, of an object dtype, or
            shorter than its header says (truncated).
    """
    try:
        with path.open("rb") as f:
            version = npy_format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = npy_format.read_array_header_1_0(f)
            else:
                shape, fortran, dtype = npy_format.read_array_header_2_0(f)
            offset = f.tell()
    except FileNotFoundError:
        raise IndexFileError(path, "missing") from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise IndexFileError(path, f"not a readable .npy file: {exc}") from None
    if fortran or dtype.hasobject:
        raise IndexFileError(path, "holds a Fortran-ordered or object array; save it with np.save from a C-ordered "
                                   "numeric array")
    header = NpyHeader(path, tuple(int(s) for s in shape), np.dtype(dtype), offset)
    expected = offset + header.rows * header.row_bytes if header.shape else offset + dtype.itemsize
    size = path.stat().st_size
    if size < expected:
        raise IndexFileError(path, f"is {size} bytes, its header promises {expected} (truncated)")
    return header


def read_rows(header: NpyHeader, start: int, stop: int) -> np.ndarray:
    """Rows ``start … stop−1`` of the file, read (not mapped) into a new array of the file's dtype."""
    shape = (max(0, stop - start), *header.shape[1:])
    count = int(np.prod(shape, dtype=np.int64))
    if count == 0:
        return np.empty(shape, dtype=header.dtype)
    flat = np.fromfile(header.path, dtype=header.dtype, count=count, offset=header.offset + start * header.row_bytes)
    if len(flat) != count:
        raise IndexFileError(header.path, f"ended while reading rows {start}…{stop - 1} (truncated)")
    return flat.reshape(shape)


def read_row_set(header: NpyHeader, rows: np.ndarray) -> np.ndarray:
    """The (M, …) rows at the ascending positions ``rows`` (M,), one positioned read each."""
    out = np.empty((len(rows), *header.shape[1:]), dtype=header.dtype)
    size = header.row_bytes
    fd = os.open(header.path, os.O_RDONLY)
    try:
        flat = out.reshape(len(rows), -1).view(np.uint8)
        for i, r in enumerate(rows.tolist()):
            data = os.pread(fd, size, header.offset + r * size)
            if len(data) != size:
                raise IndexFileError(header.path, f"ended while reading row {r} (truncated)")
            flat[i] = np.frombuffer(data, dtype=np.uint8)
    finally:
        os.close(fd)
    return out


@dataclass(frozen=True)
class RowSpan:
    """Rows ``start … stop−1`` of one vector file (and the same rows of its id file, if any).

    A span is the unit of parallel work: small, picklable, and read by whichever process gets it.

    Attributes:
        vectors: the (n, d) ``.npy`` vector file.
        start: first row.
        stop: one past the last row.
        ids: the (n,) int64 ``.npy`` id file of ``vectors``, or None.
        first_id: without an id file, row r has id ``first_id + r − start``.
    """

    vectors: Path
    start: int
    stop: int
    ids: Path | None = None
    first_id: int = 0

    def __len__(self) -> int:
        return self.stop - self.start

    def read_ids(self) -> np.ndarray:
        """(n,) int64 ids of the span's rows."""
        if self.ids is None:
            return np.arange(self.first_id, self.first_id + len(self), dtype=np.int64)
        return np.ascontiguousarray(read_rows(read_npy_header(self.ids), self.start, self.stop), dtype=np.int64)


@dataclass(frozen=True)
class VectorFiles:
    """A collection spread over ``.npy`` files; see the module docstring.

    Attributes:
        headers: one per vector file, in order.
        id_headers: one per id file (same order), or None for ids 0 … N−1 in file order.
    """

    headers: tuple[NpyHeader, ...]
    id_headers: tuple[NpyHeader, ...] | None = None

    @classmethod
    def open(cls, vectors: Sequence[Path | str], ids: Sequence[Path | str] | None = None) -> VectorFiles:
        """Check the headers of every vector file (and id file); read no data.

        Args:
            vectors: ``.npy`` files of (n_i, d) float vectors, all of one dimension d.
            ids: ``.npy`` files of (n_i,) int64 ids, one per vector file, or None.

        Raises:
            IndexFileError: a file missing, unreadable or truncated, not 2-D floats, of another
                dimension than the first file, or an id file of the wrong dtype or length.
            ValueError: no files, or not one id file per vector file.
        """
        paths = [Path(p) for p in vectors]
        if not paths:
            raise ValueError("no vector files given")
        headers = tuple(read_npy_header(p) for p in paths)
        first = headers[0]
        for h in headers:
            if len(h.shape) != 2 or h.dtype.kind != "f" or h.shape[1] == 0:
                raise IndexFileError(h.path, f"expected a 2-D float array (n, d), got {h.dtype} {h.shape}")
            if h.shape[1] != first.shape[1]:
                raise IndexFileError(h.path, f"has dimension {h.shape[1]}, {first.path.name} has "
                                             f"{first.shape[1]}", field="shape")
        id_headers = None
        if ids is not None:
            id_paths = [Path(p) for p in ids]
            if len(id_paths) != len(paths):
                raise ValueError(f"{len(id_paths)} id files for {len(paths)} vector files")
            id_headers = tuple(read_npy_header(p) for p in id_paths)
            for h, v in zip(id_headers, headers):
                if h.shape != (v.rows,) or h.dtype != np.dtype(np.int64):
                    raise IndexFileError(h.path, f"expected int64 ids of shape ({v.rows},) for {v.path.name}, "
                                                 f"got {h.dtype} {h.shape}")
        return cls(headers, id_headers)

    @property
    def dim(self) -> int:
        return self.headers[0].shape[1]

    def __len__(self) -> int:
        return sum(h.rows for h in self.headers)

    @property
    def starts(self) -> np.ndarray:
        """(F + 1,) first global row of each file, then the total."""
        return np.concatenate([[0], np.cumsum([h.rows for h in self.headers])]).astype(np.int64)

    def spans(self, max_rows: int) -> list[RowSpan]:
        """The collection cut into spans of at most ``max_rows`` rows, never across files."""
        out = []
        starts = self.starts
        for i, h in enumerate(self.headers):
            ids = None if self.id_headers is None else self.id_headers[i].path
            n_parts = max(1, -(-h.rows // max(1, max_rows)))
            bounds = np.linspace(0, h.rows, n_parts + 1).astype(np.int64)
            out += [RowSpan(h.path, int(a), int(b), ids, int(starts[i] + a))
                    for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        return out

    def all_ids(self) -> np.ndarray:
        """(N,) int64 ids in file order, checked to be unique and ≥ 0.

        Raises:
            IdError: negative ids, or ids that appear more than once (within or across files).
        """
        if self.id_headers is None:
            return np.arange(len(self), dtype=np.int64)
        ids = np.concatenate([read_rows(h, 0, h.rows) for h in self.id_headers]).astype(np.int64, copy=False)
        if len(ids) and ids.min() < 0:
            bad = np.flatnonzero(ids < 0)
            raise IdError(f"ids must be ≥ 0; negative ids in {self._file_of(int(bad[0]), ids=True)}",
                          ids[bad].tolist())
        order = np.argsort(ids, kind="stable")
        repeated = order[1:][ids[order[1:]] == ids[order[:-1]]]
        if len(repeated):
            raise IdError(f"ids repeat (first in {self._file_of(int(repeated[0]), ids=True)})",
                          np.unique(ids[repeated]).tolist())
        return ids

    def _file_of(self, row: int, ids: bool = False) -> Path:
        i = int(np.searchsorted(self.starts, row, side="right") - 1)
        headers = self.id_headers if ids and self.id_headers is not None else self.headers
        return headers[i].path

    def locate(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M,) file numbers and (M,) rows within each file, of the global ``rows`` (M,)."""
        file_no = np.searchsorted(self.starts, rows, side="right") - 1
        return file_no, rows - self.starts[file_no]

    def read_global_rows(self, rows: np.ndarray) -> np.ndarray:
        """(M, d) vectors at the ascending global ``rows`` (M,), in the files' dtype converted to float32."""
        out = np.empty((len(rows), self.dim), dtype=np.float32)
        file_no, local = self.locate(rows)
        for f in np.unique(file_no):
            here = file_no == f
            out[here] = read_row_set(self.headers[int(f)], local[here])
        return out

    def chunks(self, chunk_rows: int) -> Iterator[tuple[RowSpan, np.ndarray]]:
        """Every row in order, as (span, (n, d) float32 array) pieces of at most ``chunk_rows`` rows."""
        for span in self.spans(len(self)):
            yield from span_chunks(span, chunk_rows)


def span_chunks(span: RowSpan, chunk_rows: int) -> Iterator[tuple[RowSpan, np.ndarray]]:
    """The rows of ``span`` as (sub-span, (n, d) float32) pieces of at most ``chunk_rows`` rows."""
    header = read_npy_header(span.vectors)
    for a in range(span.start, span.stop, max(1, chunk_rows)):
        b = min(span.stop, a + chunk_rows)
        sub = RowSpan(span.vectors, a, b, span.ids, span.first_id + a - span.start)
        yield sub, np.ascontiguousarray(read_rows(header, a, b), dtype=np.float32)
