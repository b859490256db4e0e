"""Kinds of bad input a robustness probe found, each refused clearly (or answered right) now."""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from retrieval.cli import main
from scenarios.compiler import DescriptionError, compile_description
from scenes.categories import Category, category_from_label
from scenes.errors import LogFormatError
from scenes.log import Log
from tests.scenes.av2_fixtures import DEV_LOGS, require, rewritten_log


@pytest.fixture
def log(tmp_path: Path) -> Path:
    source = require(DEV_LOGS["7fab2350"])
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / source.name).symlink_to(source, target_is_directory=True)
    return tmp_path / "logs" / source.name


@pytest.mark.parametrize("kind", ["folder", "device", "parent_is_a_file"])
def test_file_outputs_that_cannot_be_written_are_refused_before_any_work(
        kind: str, log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if kind == "folder":
        out = tmp_path / "a_folder"
        out.mkdir()
    elif kind == "device":
        out = tmp_path / "null"
        try:
            os.mknod(out, 0o666 | 0o020000, os.makedev(1, 3))
        except PermissionError:
            pytest.skip("cannot make a device node here")
    else:
        (tmp_path / "a_file").write_text("mine")
        out = tmp_path / "a_file" / "pred.pkl"
    assert main(["mine", str(log), "--description", "vehicle", "--out", str(out)]) == 2
    said = capsys.readouterr()
    assert f"{out}:" in said.err and "program:" not in said.out  # refused before anything was computed
    assert kind != "device" or out.is_char_device()


def test_a_repeated_log_is_mined_once_and_reported(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                   ) -> None:
    assert main(["mine", str(log), str(log), "--description", "vehicle", "--out", str(tmp_path / "p.pkl")]) == 1
    assert "log given twice" in capsys.readouterr().out


def test_a_program_parameter_its_call_does_not_take_is_refused_when_compiled() -> None:
    with pytest.raises(DescriptionError, match="turning: unknown parameter 'speed' .known: direction."):
        compile_description("turning(vehicle, direction=left, speed=5)")


def test_columns_named_twice_and_categorical_columns(log: Path, tmp_path: Path) -> None:
    def twice(table: pa.Table) -> pa.Table:
        return table.append_column("tx_m", table.column("tx_m"))

    with pytest.raises(LogFormatError, match="field 'tx_m': column appears 2 times"):
        Log.open(rewritten_log(log, tmp_path / "twice" / log.name, twice))

    def categorical(table: pa.Table) -> pa.Table:
        i = table.column_names.index("category")
        return table.set_column(i, "category", table.column("category").dictionary_encode())

    opened = Log.open(rewritten_log(log, tmp_path / "categorical" / log.name, categorical))
    assert opened.dense_tracks().track_ids.shape[0] == Log.open(log).dense_tracks().track_ids.shape[0]


def test_labels_in_another_case_are_read_as_the_dataset_means() -> None:
    assert category_from_label("regular_vehicle") is Category.CAR
    assert category_from_label("Box_Truck") is Category.TRUCK
    assert category_from_label("PEDESTRIAN ") is Category.PEDESTRIAN  # a trailing space: the label it plainly is
    assert category_from_label(" Car") is Category.CAR
    assert category_from_label("   ") is None


def test_a_track_whose_category_changes(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    def flip(table: pa.Table) -> pa.Table:
        track = table.column("track_uuid")[0].as_py()
        rows = [i for i, t in enumerate(table.column("track_uuid").to_pylist()) if t == track]
        cats = table.column("category").to_pylist()
        cats[rows[-1]] = "PEDESTRIAN" if cats[rows[-1]] != "PEDESTRIAN" else "BICYCLIST"
        return table.set_column(table.column_names.index("category"), "category", pa.array(cats))

    changed = rewritten_log(log, tmp_path / "flip" / log.name, flip)
    assert main(["validate", str(changed)]) == 0
    assert "a track keeps one category" in capsys.readouterr().out


def test_an_empty_caption_row_is_refused_by_clips(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                  ) -> None:
    assert main(["caption", str(log), "--out", str(tmp_path / "captions")]) == 0
    table = pq.read_table(tmp_path / "captions" / "captions.parquet")
    texts = table.column("caption").to_pylist()
    row = next(i for i, t in enumerate(table.column("track_id").to_pylist()) if t != "ego")
    texts[row] = ""
    (tmp_path / "bad").mkdir()
    pq.write_table(table.set_column(table.column_names.index("caption"), "caption", pa.array(texts)),
                   tmp_path / "bad" / "captions.parquet")
    assert main(["clips", str(log), "--captions", str(tmp_path / "bad"), "--out", str(tmp_path / "clips")]) == 2
    assert f"row {row}, field 'caption': empty" in capsys.readouterr().err


def test_a_descriptions_file_with_none_is_refused(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                  ) -> None:
    descriptions = tmp_path / "descriptions.txt"
    descriptions.write_text("# only a comment\n\n")
    assert main(["mine", str(log), "--descriptions-file", str(descriptions), "--out", str(tmp_path / "p.pkl")]) == 2
    assert f"--descriptions-file {descriptions}: holds no descriptions" in capsys.readouterr().err
    assert not (tmp_path / "p.pkl").exists()


def test_a_cache_folder_that_is_not_one_is_named_as_the_cache(log: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    cache = tmp_path / "mine"
    cache.mkdir()
    (cache / "notes.txt").write_text("mine")
    assert main(["mine", str(log), "--description", "vehicle", "--cache", str(cache),
                 "--out", str(tmp_path / "p.pkl")]) == 2
    err = capsys.readouterr().err
    assert f"--cache {cache}" in err and "--out" not in err
    assert (cache / "notes.txt").read_text() == "mine"


def test_a_write_that_fails_without_a_file_name_names_the_output(log: Path, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str],
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A full disk inside a library's writer (pyarrow: "[errno 28] No space left on device", no path): the
    one line names the output being written."""
    import errno

    def full_disk(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("captioning.outputs.CaptionsWriter.add", full_disk)
    out = tmp_path / "captions"
    assert main(["caption", str(log), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"writing {out}: No space left on device" in err and "Traceback" not in err
    assert not (out / "captions.parquet").exists()  # nothing published
