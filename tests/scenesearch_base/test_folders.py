"""Output folders belong to scenesearch or are refused: kinds, markers, inputs, legacy folders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scenesearch_base.folders import (
    MARKER_FILE,
    FolderClaimError,
    FolderKind,
    check_inputs,
    claim_folder,
    claimed_directory,
    mark_folder,
    read_marker,
)

INDEX = FolderKind("index", signature="manifest.json", entries=("manifest.json", "*.npy"))
CLIPS = FolderKind("clips", signature="clips.parquet", entries=("clips.parquet", "logs"))


def test_missing_and_empty_folders_are_taken(tmp_path: Path) -> None:
    claim_folder(tmp_path / "new", INDEX, whole=True)
    (tmp_path / "empty").mkdir()
    claim_folder(tmp_path / "empty", INDEX, whole=True)


def test_a_users_folder_is_refused_naming_what_it_holds(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(FolderClaimError, match=r"not empty and not a scenesearch index folder .*notes\.txt"):
        claim_folder(tmp_path, INDEX, whole=True)


def test_a_file_is_refused(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(FolderClaimError, match="is a file"):
        claim_folder(tmp_path / "f", INDEX)


def test_another_kind_is_refused_and_the_same_kind_taken(tmp_path: Path) -> None:
    mark_folder(tmp_path, CLIPS, CLIPS.entries)
    (tmp_path / "clips.parquet").write_bytes(b"x")
    with pytest.raises(FolderClaimError, match="scenesearch clips folder .*not a index folder"):
        claim_folder(tmp_path, INDEX, whole=True)
    claim_folder(tmp_path, CLIPS)
    assert read_marker(tmp_path).kind == "clips"  # type: ignore[union-attr]


def test_whole_replacement_refuses_entries_no_writer_made(tmp_path: Path) -> None:
    with claimed_directory(tmp_path / "ix", INDEX) as tmp:
        (tmp / "manifest.json").write_text("{}")
        (tmp / "x.npy").write_bytes(b"0")
    marker = json.loads((tmp_path / "ix" / MARKER_FILE).read_text())
    assert marker["kind"] == "index" and marker["entries"] == ["manifest.json", "x.npy"]
    (tmp_path / "ix" / "notes.txt").write_text("mine")
    with pytest.raises(FolderClaimError, match=r"holds notes\.txt, which scenesearch did not write"), \
            claimed_directory(tmp_path / "ix", INDEX) as tmp:
        (tmp / "manifest.json").write_text("{}")
    assert (tmp_path / "ix" / "notes.txt").read_text() == "mine"
    claim_folder(tmp_path / "ix", INDEX, whole=False)  # a writer that adds files loses nothing: taken


def test_a_folder_written_before_markers_is_recognised_by_its_names(tmp_path: Path) -> None:
    (tmp_path / "manifest.json").write_text("{}")
    (tmp_path / "a.npy").write_bytes(b"0")
    claim_folder(tmp_path, INDEX, whole=True)
    (tmp_path / "a.npy").unlink()
    (tmp_path / "manifest.json").unlink()
    (tmp_path / "a.npy").write_bytes(b"0")  # the names, without the signature file
    with pytest.raises(FolderClaimError, match="not a scenesearch index folder"):
        claim_folder(tmp_path, INDEX, whole=True)


def test_temporary_entries_of_killed_writes_are_not_content(tmp_path: Path) -> None:
    (tmp_path / ".notes.123@0123abcd.abcdefgh.tmp").write_text("")
    (tmp_path / ".ix.old").mkdir()
    claim_folder(tmp_path, INDEX, whole=True)


@pytest.mark.parametrize("relation", ["same", "inside", "holding"])
def test_an_output_that_is_an_input_is_refused(tmp_path: Path, relation: str) -> None:
    given = tmp_path / "captions"
    given.mkdir()
    out = {"same": given, "inside": given / "sub", "holding": tmp_path}[relation]
    word = {"same": "is the input", "inside": "lies inside the input", "holding": "holds the input"}[relation]
    with pytest.raises(FolderClaimError, match=word):
        check_inputs(out, [given])
    with pytest.raises(FolderClaimError, match=word):
        claim_folder(out, INDEX, [given], whole=True)


def test_uris_are_not_checked(tmp_path: Path) -> None:
    check_inputs("s3://bucket/out", [tmp_path])
    claim_folder("s3://bucket/out", INDEX, ["s3://bucket/out"])


def test_an_unreadable_marker_is_refused(tmp_path: Path) -> None:
    (tmp_path / MARKER_FILE).write_text("{not json")
    (tmp_path / "manifest.json").write_text("{}")
    with pytest.raises(FolderClaimError, match="unreadable folder marker"):
        claim_folder(tmp_path, INDEX)


def test_marking_adds_to_what_earlier_writers_recorded(tmp_path: Path) -> None:
    mark_folder(tmp_path / "c", CLIPS, ["clips.parquet"])
    mark_folder(tmp_path / "c", CLIPS, ["logs"])
    assert read_marker(tmp_path / "c") is not None
    assert read_marker(tmp_path / "c").entries == ("clips.parquet", "logs")  # type: ignore[union-attr]
