"""TFRecord framing, read and checked without TensorFlow.

A TFRecord file is a sequence of records, each::

    uint64 length            little-endian
    uint32 masked_crc32c(length bytes)
    byte   data[length]
    uint32 masked_crc32c(data)

Both checksums are verified; a mismatch, a file that ends inside a record, or a length that claims
more bytes than the file has left raises :class:`WomdFormatError` naming the file and the 0-based
record index. Gzip-compressed files are read transparently.

CRC-32C (Castagnoli) is not in the standard library. :func:`crc32c` computes it with numpy: the
data is cut into equal rows whose CRCs advance together one byte column at a time, and the row
CRCs are then merged pairwise with the GF(2) operator that shifts a CRC over a run of zero bytes.
A record costs far less than a byte loop in Python would (``docs/research/ingest-profile.md``).
"""

from __future__ import annotations

import functools
import gzip
import os
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scenes.errors import ImportFormatError
from scenes.schema import why_not_a_file

#: Reflected CRC-32C polynomial.
_POLY = 0x82F63B78
_MASK_DELTA = 0xA282EAD8
_HEADER = struct.Struct("<QI")
_FOOTER = struct.Struct("<I")
#: Below this many bytes a plain byte loop is faster than the vectorised path.
_SMALL_BYTES = 2048

U32Array = NDArray[np.uint32]


class WomdFormatError(ImportFormatError):
    """A Waymo Open Motion Dataset file cannot be converted; names the file, the 0-based record
    and, where it applies, the field (``tracks[3].states``)."""

    unit = "record"

    def __init__(self, path: Path | str, message: str, record: int | None = None, field: str | None = None) -> None:
        super().__init__(path, message, record, field)
        self.record = record


def _make_table() -> U32Array:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ (_POLY if c & 1 else 0)
        table[i] = c
    return table


_TABLE = _make_table()
_TABLE_LIST = [int(v) for v in _TABLE]
_BITS = np.arange(32, dtype=np.uint32)


def _apply(columns: U32Array, values: U32Array) -> U32Array:
    """A 32×32 GF(2) operator applied to many registers.

    Args:
        columns: (32,) the operator's image of each single bit ``1 << j``.
        values: (N,) registers.

    Returns:
        (N,) the images of the registers.
    """
    bits = ((values[:, None] >> _BITS) & 1).astype(bool)  # (N, 32)
    return np.bitwise_xor.reduce(np.where(bits, columns, np.uint32(0)), axis=1).astype(np.uint32)


@functools.cache
def _zeros_operator(log2_bytes: int) -> U32Array:
    """(32,) columns of the operator that runs a raw CRC register over ``2**log2_bytes`` zero bytes."""
    if log2_bytes == 0:
        single = np.uint32(1) << _BITS  # (32,)
        return (_TABLE[single & 0xFF] ^ (single >> 8)).astype(np.uint32)
    half = _zeros_operator(log2_bytes - 1)
    return _apply(half, half)


def _shift_zeros(register: int, num_bytes: int) -> int:
    """A raw CRC register after ``num_bytes`` zero bytes."""
    values = np.array([register], dtype=np.uint32)
    k = 0
    while num_bytes:
        if num_bytes & 1:
            values = _apply(_zeros_operator(k), values)
        num_bytes >>= 1
        k += 1
    return int(values[0])


def _raw_crc_small(data: bytes | memoryview, register: int = 0) -> int:
    table = _TABLE_LIST
    for byte in bytes(data):
        register = table[(register ^ byte) & 0xFF] ^ (register >> 8)
    return register


def _raw_crc(data: bytes | memoryview) -> int:
    """The CRC register after ``data``, starting from 0, without the final inversion.

    Starting from 0 makes leading zero bytes free, so the data is padded in front to a (rows × width)
    block with a power-of-two row count; the rows then merge pairwise in log2(rows) steps.
    """
    n = len(data)
    if n < _SMALL_BYTES:
        return _raw_crc_small(data)
    width_log2 = max(6, (n.bit_length() + 1) // 2)
    width = 1 << width_log2
    rows = 1 << max(0, (-(-n // width) - 1).bit_length())
    block = np.zeros(rows * width, dtype=np.uint8)
    block[rows * width - n :] = np.frombuffer(data, dtype=np.uint8)
    columns = np.ascontiguousarray(block.reshape(rows, width).T)  # (width, rows)
    registers = np.zeros(rows, dtype=np.uint32)
    for column in columns:
        registers = _TABLE[(registers ^ column) & 0xFF] ^ (registers >> 8)
    level = width_log2
    while registers.shape[0] > 1:
        registers = _apply(_zeros_operator(level), registers[0::2]) ^ registers[1::2]
        level += 1
    return int(registers[0])


def crc32c(data: bytes | memoryview) -> int:
    """CRC-32C (Castagnoli) of ``data``, as TFRecord uses it (``crc32c(b"123456789") == 0xE3069283``)."""
    # The standard CRC starts from 0xFFFFFFFF; by linearity that start contributes the all-ones
    # register shifted over len(data) zero bytes.
    start = _shift_zeros(0xFFFFFFFF, len(data))
    return (_raw_crc(data) ^ start ^ 0xFFFFFFFF) & 0xFFFFFFFF


def masked_crc32c(data: bytes | memoryview) -> int:
    """The masked CRC-32C that TFRecord stores (rotated right by 15 bits, plus a constant)."""
    crc = crc32c(data)
    return ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + _MASK_DELTA) & 0xFFFFFFFF


def encode_record(data: bytes) -> bytes:
    """One framed record: length, its masked CRC, ``data``, its masked CRC."""
    length = struct.pack("<Q", len(data))
    return length + struct.pack("<I", masked_crc32c(length)) + data + struct.pack("<I", masked_crc32c(data))


@dataclass(frozen=True)
class Record:
    """One record's payload and where it sits in its file.

    Attributes:
        index: 0-based record number in the file.
        offset: byte offset of the record's header (in the decompressed stream of a gzip file).
        data: the payload.
    """

    index: int
    offset: int
    data: bytes


def read_records(path: Path | str) -> Iterator[Record]:
    """Yield the records of a TFRecord file, each checked against both of its CRCs.

    Raises:
        FileNotFoundError: the file does not exist.
        WomdFormatError: a CRC does not match or the file ends inside a record; records before it
            have been yielded.
    """
    for item in iter_records(path):
        if isinstance(item, WomdFormatError):
            raise item
        yield item


def iter_records(path: Path | str) -> Iterator[Record | WomdFormatError]:
    """Like :func:`read_records`, but a record whose data fails its CRC is yielded as its error and
    reading goes on with the next one (its length was verified, so the framing still holds).

    A gzip-compressed file (it starts with the gzip magic bytes ``1f 8b``; TensorFlow writes these
    with ``compression_type="GZIP"``) is decompressed on the fly; record offsets then count bytes of
    the decompressed stream. A record length is checked against the bytes left in the file before
    anything is read, so a corrupt length never allocates more memory than the file holds.

    Raises:
        FileNotFoundError: the file does not exist.
        WomdFormatError: the file ends inside a record, a length fails its CRC or claims more bytes
            than the file has left (nothing after it can be framed), or the gzip stream is corrupt.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: {why_not_a_file(path)} (a TFRecord file is expected)")
    with path.open("rb") as raw:
        if raw.read(len(_GZIP_MAGIC)) == _GZIP_MAGIC:
            raw.seek(0)
            with gzip.GzipFile(fileobj=raw, mode="rb") as unzipped:
                yield from _frames(path, unzipped.read, None)
        else:
            raw.seek(0)
            yield from _frames(path, raw.read, os.fstat(raw.fileno()).st_size)


#: The first bytes of a gzip stream.
_GZIP_MAGIC = b"\x1f\x8b"
#: Bytes read at a time from a stream whose size is unknown (gzip), so that a corrupt record length
#: costs no more memory than the data actually there.
_CHUNK_BYTES = 1 << 24


def _read(path: Path, read: Callable[[int], bytes], num_bytes: int, index: int) -> bytes:
    """Up to ``num_bytes`` bytes from ``read`` (fewer at its end), read in chunks; a corrupt gzip
    stream is a :class:`WomdFormatError` of record ``index``."""
    parts = []
    try:
        while num_bytes > 0:
            part = read(min(num_bytes, _CHUNK_BYTES))
            if not part:
                break
            parts.append(part)
            num_bytes -= len(part)
    except (OSError, EOFError, zlib.error) as exc:
        raise WomdFormatError(path, f"gzip-compressed file is corrupt or truncated: {exc}", index) from exc
    return b"".join(parts)


def _looks_like_text(data: bytes) -> bool:
    """Whether ``data`` is printable UTF-8 text (a TFRecord's first bytes are a binary length and its CRC)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return all(ch.isprintable() or ch in "\r\n\t" for ch in text)


def _frames(path: Path, read: Callable[[int], bytes], size: int | None) -> Iterator[Record | WomdFormatError]:
    """The records of the stream that ``read`` reads; ``size``: the file's size in bytes, None when unknown (gzip)."""
    index = 0
    offset = 0
    where = "decompressed stream" if size is None else "file"
    while True:
        header = _read(path, read, _HEADER.size, index)
        if not header:
            return
        if len(header) < _HEADER.size:
            raise WomdFormatError(
                path, f"truncated: the {where} ends inside a record header at byte {offset + len(header)}", index
            )
        length, length_crc = _HEADER.unpack(header)
        if masked_crc32c(header[:8]) != length_crc:
            if index == 0 and _looks_like_text(header):  # a CSV, JSON or other text file given as a TFRecord
                raise WomdFormatError(path, f"not a TFRecord file: it starts with text ({header[:12]!r}…)", index)
            raise WomdFormatError(path, f"corrupt record length at byte {offset} (CRC mismatch)", index)
        if size is not None:
            left = size - offset - _HEADER.size
            if length + _FOOTER.size > left:
                raise WomdFormatError(
                    path, f"truncated: the record at byte {offset} declares {length} bytes of data, but only "
                    f"{left} bytes are left in the file (data and CRC need {length + _FOOTER.size})", index
                )
        data = _read(path, read, length, index)
        footer = _read(path, read, _FOOTER.size, index)
        if len(data) < length or len(footer) < _FOOTER.size:
            raise WomdFormatError(
                path, f"truncated: the record at byte {offset} declares {length} bytes, "
                f"the {where} ends {len(data) + len(footer)} bytes into it", index
            )
        (data_crc,) = _FOOTER.unpack(footer)
        if masked_crc32c(data) != data_crc:
            yield WomdFormatError(path, f"corrupt record data at byte {offset} (CRC mismatch)", index)
        else:
            yield Record(index, offset, data)
        offset += _HEADER.size + length + _FOOTER.size
        index += 1
