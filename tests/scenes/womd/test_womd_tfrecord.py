"""TFRecord framing: CRC-32C against published check values and a byte loop, framing round trips,
and corrupt or truncated files named by file and record."""

from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest

from scenes.womd.tfrecord import (
    WomdFormatError,
    _raw_crc_small,
    crc32c,
    encode_record,
    iter_records,
    masked_crc32c,
    read_records,
)
from tests.realdata import REALDATA

DEV_FILE = REALDATA / "womd" / "womd_scenario_input.tfrecord"


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (b"", 0x00000000),
        (b"123456789", 0xE3069283),  # the CRC-32C check value
        (bytes(32), 0x8A9136AA),  # RFC 3720, B.4
        (b"\xff" * 32, 0x62A8AB43),
        (bytes(range(32)), 0x46DD794E),
        (bytes(range(31, -1, -1)), 0x113FDB5C),
    ],
)
def test_crc32c_check_values(data: bytes, expected: int) -> None:
    assert crc32c(data) == expected


@pytest.mark.parametrize("size", [2047, 2048, 2049, 4096, 10_007, 65_536, 300_001])
def test_vectorised_crc_equals_the_byte_loop(size: int) -> None:
    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    assert crc32c(data) == _raw_crc_small(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


def test_masked_crc_of_known_value() -> None:
    crc = 0xE3069283
    expected = ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + 0xA282EAD8) & 0xFFFFFFFF
    assert masked_crc32c(b"123456789") == expected


def _write(path: Path, payloads: list[bytes]) -> Path:
    path.write_bytes(b"".join(encode_record(p) for p in payloads))
    return path


def test_round_trip(tmp_path: Path) -> None:
    payloads = [b"first", b"", bytes(range(256)) * 20]
    records = list(read_records(_write(tmp_path / "a.tfrecord", payloads)))
    assert [r.data for r in records] == payloads
    assert [r.index for r in records] == [0, 1, 2]
    assert records[1].offset == 16 + len(b"first")


def test_empty_file_has_no_records(tmp_path: Path) -> None:
    (tmp_path / "e.tfrecord").write_bytes(b"")
    assert list(read_records(tmp_path / "e.tfrecord")) == []


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nope\.tfrecord"):
        list(read_records(tmp_path / "nope.tfrecord"))


def test_flipped_data_byte_is_a_crc_error_naming_file_and_record(tmp_path: Path) -> None:
    path = _write(tmp_path / "f.tfrecord", [b"a" * 40, b"b" * 40, b"c" * 40])
    raw = bytearray(path.read_bytes())
    second = len(encode_record(b"a" * 40))
    raw[second + 12 + 7] ^= 0x01  # a data byte of record 1
    path.write_bytes(bytes(raw))
    with pytest.raises(WomdFormatError, match=r"f\.tfrecord, record 1: corrupt record data .*CRC mismatch") as err:
        list(read_records(path))
    assert err.value.record == 1 and err.value.path == path
    # The length was intact, so the next record can still be read.
    items = list(iter_records(path))
    assert isinstance(items[1], WomdFormatError)
    assert [getattr(i, "data", None) for i in items] == [b"a" * 40, None, b"c" * 40]


def test_flipped_length_byte_stops_the_file(tmp_path: Path) -> None:
    path = _write(tmp_path / "g.tfrecord", [b"a" * 40, b"b" * 40])
    raw = bytearray(path.read_bytes())
    raw[len(encode_record(b"a" * 40))] ^= 0x02  # the length of record 1
    path.write_bytes(bytes(raw))
    items = iter_records(path)
    assert next(items).data == b"a" * 40  # type: ignore[union-attr]
    with pytest.raises(WomdFormatError, match=r"record 1: corrupt record length"):
        next(items)


def test_flipped_data_crc_byte(tmp_path: Path) -> None:
    path = _write(tmp_path / "h.tfrecord", [b"payload"])
    raw = bytearray(path.read_bytes())
    raw[-1] ^= 0x80
    path.write_bytes(bytes(raw))
    with pytest.raises(WomdFormatError, match=r"record 0: corrupt record data"):
        list(read_records(path))


@pytest.mark.parametrize(("cut", "message"), [(5, "inside a record header"), (30, "declares 40 bytes"),
                                              (2, "declares 40 bytes")])
def test_truncated_file(tmp_path: Path, cut: int, message: str) -> None:
    one = encode_record(b"x" * 40)
    path = tmp_path / "t.tfrecord"
    # cut counts bytes kept of the second record (5: in its header; 30: in its data; 2 from its end: in its CRC).
    keep = cut if cut != 2 else len(one) - 2
    path.write_bytes(one + one[:keep])
    items = iter_records(path)
    assert next(items).data == b"x" * 40  # type: ignore[union-attr]
    with pytest.raises(WomdFormatError, match=rf"t\.tfrecord, record 1: truncated.*{message}"):
        next(items)


def test_development_file_frames_and_checks() -> None:
    if not DEV_FILE.is_file():
        pytest.skip(f"WOMD development file not found at {DEV_FILE} (the shared realdata folder is absent)")
    records = list(read_records(DEV_FILE))
    assert len(records) == 1
    assert 16 + len(records[0].data) == DEV_FILE.stat().st_size


def test_length_beyond_the_file_is_refused_before_reading(tmp_path: Path) -> None:
    """A header claiming 2^40 bytes, with a valid CRC: named with the bytes left, nothing allocated."""
    length = struct.pack("<Q", 2**40)
    path = tmp_path / "huge.tfrecord"
    path.write_bytes(encode_record(b"ok") + length + struct.pack("<I", masked_crc32c(length)) + b"x" * 100)
    items = iter_records(path)
    assert next(items).data == b"ok"  # type: ignore[union-attr]
    with pytest.raises(WomdFormatError, match=r"huge\.tfrecord, record 1: truncated: the record at byte 18 declares "
                       r"1099511627776 bytes of data, but only 100 bytes are left in the file") as err:
        next(items)
    assert err.value.record == 1


def test_gzip_compressed_file_is_read_transparently(tmp_path: Path) -> None:
    payloads = [b"first", bytes(range(256)) * 20]
    path = tmp_path / "z.tfrecord"
    path.write_bytes(gzip.compress(b"".join(encode_record(p) for p in payloads)))
    records = list(read_records(path))
    assert [r.data for r in records] == payloads
    assert records[1].offset == 16 + len(b"first")  # offsets count the decompressed stream


def test_gzip_file_with_a_huge_length_or_cut_short(tmp_path: Path) -> None:
    length = struct.pack("<Q", 2**40)
    huge = tmp_path / "huge.tfrecord.gz"
    huge.write_bytes(gzip.compress(length + struct.pack("<I", masked_crc32c(length)) + b"x" * 100))
    with pytest.raises(WomdFormatError, match=r"record 0: truncated: .*declares 1099511627776 bytes, the "
                       "decompressed stream ends 100 bytes into it"):
        list(read_records(huge))
    cut = tmp_path / "cut.tfrecord"
    cut.write_bytes(gzip.compress(encode_record(b"a" * 4000) * 3)[:-30])
    with pytest.raises(WomdFormatError, match=r"cut\.tfrecord, record \d: gzip-compressed file is corrupt"):
        list(read_records(cut))


def test_gzip_compressed_development_file_reads_the_same_records(tmp_path: Path) -> None:
    if not DEV_FILE.is_file():
        pytest.skip(f"WOMD development file not found at {DEV_FILE} (the shared realdata folder is absent)")
    path = tmp_path / "dev.tfrecord"
    path.write_bytes(gzip.compress(DEV_FILE.read_bytes(), compresslevel=1))
    assert [r.data for r in read_records(path)] == [r.data for r in read_records(DEV_FILE)]


def test_a_text_file_given_as_a_tfrecord_is_said_to_be_text(tmp_path: Path) -> None:
    path = tmp_path / "scenario.tfrecord"
    path.write_text("scenario_id,track_id,x,y\nee519cf571686d19,1,0.5,2.0\n")  # a decoded tracks CSV
    with pytest.raises(WomdFormatError, match=r"scenario.tfrecord, record 0: not a TFRecord file: it starts with "
                                              r"text \(b'scenario_id,'…\)"):
        list(read_records(path))
