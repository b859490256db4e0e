"""The batch commands on a development log: outputs never replace what is not theirs, sizes are
checked before they cost memory, damaged renderings are never reused, and exit codes follow one rule
(0 all done, 1 some skipped, 2 nothing done)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from encoders.clips.blocks import BlockArray
from encoders.clips.config import ClipsConfig
from encoders.clips.render import render_bytes
from encoders.run_folder import claim_run_dir
from retrieval.cli import main
from retrieval.demo import DEMO_FOLDER
from retrieval.index_folder import INDEX_FOLDER
from scenesearch_base.folders import FolderClaimError, claim_folder, mark_folder
from scenesearch_base.memory import MemoryBudgetError, check_memory
from tests.scenes.av2_fixtures import DEV_LOGS, require


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("outputs")
    log = root / "logs" / DEV_LOGS["7fab2350"].name
    log.parent.mkdir()
    log.symlink_to(require(DEV_LOGS["7fab2350"]), target_is_directory=True)
    assert main(["caption", str(log), "--out", str(root / "captions")]) == 0
    return {"root": root, "log": log, "captions": root / "captions"}


def _captions(folder: Path) -> int:
    return pq.read_metadata(folder / "captions.parquet").num_rows


def test_index_refuses_a_users_folder_and_its_own_input(work: dict[str, Path], capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    users = work["root"] / "users"
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    assert main(["index", "--captions", str(work["captions"]), "--out", str(users)]) == 2
    assert (users / "notes.txt").read_text() == "mine" and sorted(p.name for p in users.iterdir()) == ["notes.txt"]
    assert "notes.txt" in capsys.readouterr().err
    before = _captions(work["captions"])
    assert main(["index", "--captions", str(work["captions"]), "--out", str(work["captions"])]) == 2
    assert "is the input" in capsys.readouterr().err
    assert _captions(work["captions"]) == before


def test_clips_into_a_captions_folder_or_an_index_is_refused(work: dict[str, Path],
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    index = work["root"] / "index"
    mark_folder(index, INDEX_FOLDER, ["manifest.json"])
    (index / "manifest.json").write_text("{}")
    for out in (index, work["captions"]):
        assert main(["clips", str(work["log"]), "--captions", str(work["captions"]), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "is a scenesearch index folder" in err and "is the input" in err
    assert (index / "manifest.json").read_text() == "{}" and not (index / "clips.parquet").exists()


def test_sizes_are_refused_before_allocation_naming_the_option(work: dict[str, Path],
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = work["root"] / "clips_huge"
    assert main(["clips", str(work["log"]), "--captions", str(work["captions"]), "--out", str(out),
                 "--frames-per-clip", "1000000000"]) == 2
    assert "--frames-per-clip 1000000000: key 'frames_per_clip'" in capsys.readouterr().err
    assert not out.exists()


def test_a_damaged_rendering_is_rendered_again_and_said(work: dict[str, Path], capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    out = work["root"] / "clips"
    args = ["clips", str(work["log"]), "--captions", str(work["captions"]), "--out", str(out)]
    assert main(args) == 0
    folder = next((out / "logs").iterdir())
    reference = BlockArray(folder / "bev_map.blocks")[:]
    capsys.readouterr()
    assert main(args) == 0
    assert "reused (every file verified)" in capsys.readouterr().out
    with open(folder / "bev_map.blocks", "r+b") as fh:
        fh.truncate(1000)
    assert main(args) == 0
    assert "bev_map.blocks is 1000 bytes, render.json says" in capsys.readouterr().out
    (folder / "camera.blocks").unlink()
    assert main(args) == 0
    assert "camera.blocks is missing" in capsys.readouterr().out
    data = bytearray((folder / "track_boxes.blocks").read_bytes())
    data[-1] ^= 0xFF  # same size, other content
    (folder / "track_boxes.blocks").write_bytes(bytes(data))
    assert main(args) == 0
    assert "track_boxes.blocks differs from its checksum" in capsys.readouterr().out
    np.testing.assert_array_equal(BlockArray(folder / "bev_map.blocks")[:], reference)


def test_a_log_given_twice_is_processed_once_and_reported(work: dict[str, Path],
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = work["root"] / "captions_twice"
    assert main(["caption", str(work["log"]), str(work["log"]), "--out", str(out)]) == 1
    assert "log given twice" in capsys.readouterr().out
    assert _captions(out) == _captions(work["captions"])
    clips = work["root"] / "clips_twice"
    assert main(["clips", str(work["log"]), str(work["log"]), "--captions", str(out), "--out", str(clips)]) == 1
    assert "log given twice" in capsys.readouterr().out


def test_nothing_done_exits_2_and_keeps_the_previous_output(work: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "captions"
    shutil.copytree(work["captions"], out, symlinks=True)
    not_a_log = tmp_path / "empty_log"
    not_a_log.mkdir()
    assert main(["caption", str(not_a_log), "--out", str(out)]) == 2
    assert _captions(out) == _captions(work["captions"])


def test_a_run_folder_and_a_demo_folder_refuse_a_users_files(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(FolderClaimError, match="not a scenesearch run folder"):
        claim_run_dir(tmp_path, tmp_path.parent / "clips")
    with pytest.raises(FolderClaimError, match="not a scenesearch demo folder"):
        claim_folder(tmp_path, DEMO_FOLDER)
    with pytest.raises(FolderClaimError, match="holds the input"):
        claim_run_dir(tmp_path.parent, tmp_path)


def test_memory_is_checked_before_rendering() -> None:
    assert render_bytes(ClipsConfig(), 150, 100) < 2**30  # a development log's size
    with pytest.raises(MemoryBudgetError, match=r"rendering log L needs about .* GiB of memory, .* available; "
                                                 "lower camera"):
        check_memory(2**60, "rendering log L", "camera sizes")
