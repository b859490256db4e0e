"""Rule-caption search: text variants, persistence, filters, and real AV2 logs (tracks only)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from retrieval_fakes import HashTextEncoder, hash_embed

from captioning.text import OBJECT_HALF, caption_halves
from indexes.integrity import seal, sha256_file
from retrieval.captions_search import CaptionSearch, caption_rows, is_caption_index, text_variants
from retrieval.errors import EmptyQueryError, FilterSyntaxError, IndexDirError, InvalidKError
from retrieval.logs_search import caption_logs
from tests.realdata import REALDATA

AV2 = REALDATA / "av2"
DEV_LOGS = ("7fab2350-7eaf-3b7e-a39d-6937a4c1bede", "adcf7d18-0510-35b0-a2fa-b4cea13a6d76")


def _table() -> pa.Table:
    rows = [
        ("L1", "t1", "car", "The ego vehicle is cruising straight. A car in the left lane approaches.",
         ["A car in the left lane comes closer."]),
        ("L1", "t2", "car", "The ego vehicle is cruising straight. A car in the ego lane is stationary.",
         ["The ego vehicle is cruising. A car in the ego lane is stopped."]),
        ("L2", "t3", "pedestrian", "The ego vehicle is stationary. A pedestrian crossing on the left moves away.",
         []),
        ("L2", "ego", "ego", "The ego vehicle is stationary.", ["The ego vehicle is stopped."]),
        ("L2", "t4", "car", "", []),
    ]
    return pa.table({
        "log_id": [r[0] for r in rows], "track_id": [r[1] for r in rows], "category": [r[2] for r in rows],
        "start_ns": [100 * i for i in range(len(rows))], "end_ns": [100 * i + 50 for i in range(len(rows))],
        "caption": [r[3] for r in rows], "canonical_caption": [r[3] for r in rows],
        "paraphrases": [r[4] for r in rows], "tags": [["x:y"]] * len(rows),
    })


def test_text_variants() -> None:
    row = _table().to_pylist()[1]
    full, objects = text_variants(row)
    assert full == [row["caption"], "The ego vehicle is cruising. A car in the ego lane is stopped."]
    assert objects == ["A car in the ego lane is stationary.", "A car in the ego lane is stopped."]
    host = _table().to_pylist()[3]
    assert text_variants(host) == (["The ego vehicle is stationary.", "The ego vehicle is stopped."],) * 2
    assert objects == [caption_halves(t)[OBJECT_HALF] for t in full]  # each caption without its ego sentence


def test_build_search_round_trip(tmp_path: Path) -> None:
    encoder = HashTextEncoder()
    search = CaptionSearch.build(_table(), tmp_path / "cap", encoder=encoder)
    assert len(search) == 4 and [s.reason for s in search.skipped] == ["no caption"]
    assert encoder.calls == 1  # every distinct text embedded in one call
    hits = search.search("A car in the ego lane is stopped.", k=2)
    assert hits[0].track_id == "t2" and hits[0].score > max(0.6, hits[1].score)
    assert hits[0].clip_id == "L1:t2:100" and hits[0].view == "captions"
    reopened = CaptionSearch.open(tmp_path / "cap", encoder=HashTextEncoder())
    again = reopened.search("A car in the ego lane is stopped.", k=2)
    assert [h.clip_id for h in again] == [h.clip_id for h in hits]
    assert [h.category for h in reopened.search("stopped", k=4, filters={"category": "ego"})] == ["ego"]
    peds = reopened.search("crossing", k=4, filters="category == pedestrian")
    assert [h.track_id for h in peds] == ["t3"]
    with pytest.raises(EmptyQueryError):
        reopened.search("")
    with pytest.raises(InvalidKError, match=r"1 … 10000"):
        reopened.search("car", k=0)
    assert len(reopened.search("car", k=50)) == 4
    with pytest.raises(FilterSyntaxError, match="valid fields: clip_id"):
        reopened.search("car", filters={"lane": "left"})
    with pytest.raises(IndexDirError, match="not a caption index"):
        CaptionSearch.open(tmp_path)


@pytest.mark.skipif(not all((AV2 / d).is_dir() for d in DEV_LOGS), reason="../shared/realdata/av2 is absent")
def test_stopped_car_on_real_av2_logs() -> None:
    """Acceptance: a short query finds the right moments on real logs that have tracks but no sensors."""
    # One development log keeps the test short (its ~700 distinct texts take seconds to embed).
    table, skipped = caption_logs([AV2 / DEV_LOGS[0]])
    assert skipped == []
    search = CaptionSearch.build(table)
    results = search.search("stopped car", k=6)
    assert len(results) == 6 and {r.log_id for r in results} == {DEV_LOGS[0]}
    # Every hit is a stopped vehicle: the host itself, or a car whose own sentence says it stands still.
    assert all(r.category in ("car", "ego") for r in results)
    still = ("stationary", "stands", "is stopped", "is parked")
    stopped = [any(w in r.caption.split(". ", 1)[-1] for w in still) for r in results]
    assert all(stopped[:3]) and sum(stopped) >= 4
    assert sum(r.category == "car" for r in results) >= 3
    cars = search.search("stopped car", k=4, filters={"category": "car"})
    assert all(r.category == "car" for r in cars)
    assert all(any(w in r.caption.split(". ", 1)[1] for w in still) for r in cars[:2])
    peds = search.search("a pedestrian approaching", k=3)
    assert all(r.category == "pedestrian" and "approaches" in r.caption for r in peds)


# ---------------------------------------------------------------------- integrity


def _rewrite(directory: Path, name: str, arr: np.ndarray) -> None:
    """Replace ``name`` and update the manifest to match, as a buggy but consistent writer would."""
    np.save(directory / name, arr)
    manifest = json.loads((directory / "manifest.json").read_text())
    manifest["files"][name] = {"size_bytes": (directory / name).stat().st_size,
                               "sha256": sha256_file(directory / name)}
    (directory / "manifest.json").write_text(json.dumps(seal(manifest)))


def _built(tmp_path: Path) -> Path:
    CaptionSearch.build(_table(), tmp_path / "cap", encoder=HashTextEncoder())
    return tmp_path / "cap"


def test_permuted_embeddings_and_corrupt_offsets_are_refused(tmp_path: Path) -> None:
    directory = _built(tmp_path)
    emb = np.load(directory / "text_embeddings.npy")
    np.save(directory / "text_embeddings.npy", emb[::-1])
    with pytest.raises(IndexDirError, match=r"text_embeddings\.npy: checksum differs"):
        CaptionSearch.open(directory, encoder=HashTextEncoder())
    directory = _built(tmp_path / "again")
    path = directory / "full_offsets.npy"
    path.write_bytes(b"\x00" * path.stat().st_size)
    with pytest.raises(IndexDirError, match=r"full_offsets\.npy: checksum differs"):
        CaptionSearch.open(directory, encoder=HashTextEncoder())
    with pytest.warns(UserWarning, match="checksums not verified"), \
            pytest.raises(IndexDirError, match=r"full_offsets\.npy: not a readable \.npy file.*int64 array of shape"):
        CaptionSearch.open(directory, encoder=HashTextEncoder(), verify="off")


def _set(index: tuple[int, ...], value: float) -> Callable[[np.ndarray], np.ndarray]:
    def change(arr: np.ndarray) -> np.ndarray:
        arr = arr.copy()
        arr[index] = value
        return arr
    return change


@pytest.mark.parametrize(("name", "change", "pattern"), [
    ("full_offsets.npy", lambda a: a.astype(np.float64),
     r"full_offsets\.npy: expected a int64 array of shape \(5,\), got float64"),
    ("full_offsets.npy", _set((1,), 0), r"full_offsets\.npy: expected offsets rising strictly from 0"),
    ("object_texts.npy", _set((-1,), 99), r"object_texts\.npy: expected indices into the \d+ texts"),
    ("text_embeddings.npy", lambda a: a[:3], r"text_embeddings\.npy: expected a float32 array "
                                             r"of shape \(\d+, 64\), got float32 \(3, 64\)"),
    ("text_embeddings.npy", _set((0, 0), np.nan), r"text_embeddings\.npy: holds NaN"),
])
def test_sidecar_errors_name_file_and_expectation(tmp_path: Path, name: str,
                                                  change: Callable[[np.ndarray], np.ndarray], pattern: str) -> None:
    directory = _built(tmp_path)
    _rewrite(directory, name, change(np.load(directory / name)))
    with pytest.raises(IndexDirError, match=pattern):
        CaptionSearch.open(directory, encoder=HashTextEncoder())


def test_an_older_caption_index_is_refused_with_what_to_do(tmp_path: Path) -> None:
    directory = _built(tmp_path)
    manifest = json.loads((directory / "manifest.json").read_text())
    for key in ("files", "content_sha256"):
        manifest.pop(key)
    (directory / "manifest.json").write_text(json.dumps({**manifest, "format_version": 1}))
    with pytest.raises(IndexDirError, match="built by an older version.*build it again"):
        CaptionSearch.open(directory, encoder=HashTextEncoder())


def test_cli_reports_a_corrupt_caption_index_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from retrieval.cli import main

    directory = _built(tmp_path)
    (directory / "manifest.json").write_text("{truncated")
    assert main(["search", str(directory), "stopped car"]) == 2
    err = capsys.readouterr().err
    assert "manifest.json: unreadable" in err and "Traceback" not in err


def test_interrupted_swap_of_a_caption_index_is_recovered(tmp_path: Path) -> None:
    directory = _built(tmp_path)
    directory.rename(tmp_path / ".cap.old")  # killed between the swap's two renames
    assert is_caption_index(directory)
    assert len(CaptionSearch.open(directory, encoder=HashTextEncoder())) == 4


def test_queries_are_embedded_as_the_index_embedded_its_texts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                              ) -> None:
    # The default query encoder, standing in for SentenceEncoder at the test encoder's width.
    monkeypatch.setattr("retrieval.captions_search.SentenceEncoder", HashTextEncoder)
    directory = tmp_path / "cap"
    CaptionSearch.build(_table(), directory, encoder=HashTextEncoder(whole_text="sentences"))
    manifest = json.loads((directory / "manifest.json").read_text())
    assert manifest["whole_text"] == "sentences"
    assert CaptionSearch.open(directory).encoder.whole_text == "sentences"  # type: ignore[attr-defined]
    # An encoder that embeds queries otherwise than the index embedded its texts is refused.
    with pytest.raises(IndexDirError, match=r"manifest.json, field 'whole_text': the index embedded its texts as "
                                            r"'sentences', the given encoder embeds a text as 'text'"):
        CaptionSearch.open(directory, encoder=HashTextEncoder())
    assert CaptionSearch.open(directory, encoder=HashTextEncoder("sentences")).whole_text == "sentences"
    # An index that does not say how it embedded its texts was built by an older version.
    manifest.pop("whole_text")
    (directory / "manifest.json").write_text(json.dumps(seal(manifest)))
    with pytest.raises(IndexDirError, match=r"field 'whole_text': missing \(built by an older version"):
        CaptionSearch.open(directory)
    (directory / "manifest.json").write_text(json.dumps(seal({**manifest, "whole_text": "words"})))
    with pytest.raises(IndexDirError, match=r"manifest.json, field 'whole_text': must be one of"):
        CaptionSearch.open(directory)


class _WiderEncoder(HashTextEncoder):
    """A query encoder whose embeddings are wider than the index's texts (another sentence encoder)."""

    name = "wider-test"
    dim = 512

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        return hash_embed(list(texts), dim=self.dim)


def test_an_index_of_another_encoders_width_is_refused_at_the_query(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from retrieval.cli import main

    directory = _built(tmp_path)
    dim = json.loads((directory / "manifest.json").read_text())["dim"]
    with pytest.raises(IndexDirError, match=rf"the index's texts were embedded in {dim} dimensions \(text encoder "
                                            r"'hash-test'\); the query encoder 'wider-test' gives 512: build"):
        CaptionSearch.open(directory, encoder=_WiderEncoder()).search("stopped car")
    # The default encoder (384-D) meets the index of the 64-D test encoder on the command line: one line.
    assert main(["search", str(directory), "stopped car"]) == 2
    err = capsys.readouterr().err
    assert f"the index's texts were embedded in {dim} dimensions" in err and "Traceback" not in err


def test_a_row_that_ends_before_it_starts_is_skipped_and_said() -> None:
    table = _table()
    ends = table.column("end_ns").to_pylist()
    ends[0] = -1  # a hand-edited row
    rows, skipped = caption_rows(table.set_column(table.column_names.index("end_ns"), "end_ns", pa.array(ends)))
    assert rows.num_rows == 3  # the empty caption is skipped too
    assert [s.reason for s in skipped] == ["field 'end_ns' (-1) is before field 'start_ns' (0)", "no caption"]



def test_a_caption_table_behind_a_dangling_link_is_named_as_one(tmp_path: Path) -> None:
    """A captions folder whose published generation is gone: the link is named, not "run caption first"."""
    folder = tmp_path / "captions"
    folder.mkdir()
    (folder / "captions.parquet").symlink_to(folder / ".generations" / "g2" / "captions.parquet")
    with pytest.raises(FileNotFoundError, match=r"captions.parquet: a broken link \(to .*g2/captions.parquet, "
                                                r"which leads nowhere"):
        CaptionSearch.build(folder, encoder=HashTextEncoder())
