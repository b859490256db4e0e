"""SceneSearch on a synthetic clips directory with a stand-in model."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from retrieval_fakes import FakeEmbedder, HashTextEncoder, caption_of, make_clips_dir, make_run_dir

from indexes.integrity import seal
from retrieval.embedding import ModelEmbedder, model_hash
from retrieval.errors import (
    EmptyQueryError,
    FilterSyntaxError,
    IndexDirError,
    InvalidKError,
    ModelMismatchError,
    NoCameraError,
    OtherMomentsError,
    UnknownClipError,
    UnknownViewError,
)
from retrieval.querying import parse_cli_filters
from retrieval.records import SearchResult
from retrieval.result_table import format_table
from retrieval.scenesearch import SceneSearch
from scenesearch_base.atomic import sweep_stale


def _open(built: dict[str, Any]) -> SceneSearch:
    return SceneSearch.open(built["index"], embedder=built["embedder"], text_encoder=HashTextEncoder())


def test_layout_and_manifest(built: dict[str, Any]) -> None:
    index_dir: Path = built["index"]
    for name in ("fused", "camera", "bev", "captions", "run/config.json", "manifest.json"):
        assert (index_dir / name).exists(), name
    manifest = json.loads((index_dir / "manifest.json").read_text())
    assert manifest["model_sha256"] == model_hash(built["run"])
    assert manifest["views"] == ["fused", "camera", "bev"]
    assert manifest["counts"]["fused"] == 84 and manifest["counts"]["captions"] == 84
    assert manifest["embed_dim"] == 64
    assert any("view bev" in line for line in built["progress"])


def test_search_text_finds_matching_caption(built: dict[str, Any]) -> None:
    search = _open(built)
    query = caption_of(["left:approach", "left:cut_in"])
    results = search.search_text(query, k=5)
    assert [r.rank for r in results] == [1, 2, 3, 4, 5]
    assert len(search.search_text(query, k=500)) == 84  # k beyond the index: every clip once
    assert all(isinstance(r, SearchResult) for r in results)
    assert all(r.caption == query for r in results)
    assert all(a.score >= b.score for a, b in zip(results, results[1:]))
    top = results[0]
    assert top.preview_path is not None and top.preview_path.startswith(str(built["clips"]))
    assert top.clip_id == f"{top.log_id}:{top.track_id}:{top.start_ns}"
    assert set(search.last_timings_s) == {"encode_text", "search_and_records"}
    assert "caption" in format_table(results)


def test_search_text_filters(built: dict[str, Any]) -> None:
    search = _open(built)
    query = caption_of(["host:constant", "host:stop"])
    cars = search.search_text(query, k=10, filters={"category": "car"})
    assert cars and all(r.category == "car" for r in cars)
    both = search.search_text(query, k=10, filters="category in {car, truck} and time_of_day == night")
    assert both and all(r.category in ("car", "truck") for r in both)
    cli = parse_cli_filters(["category=pedestrian", "split=test,val"])
    assert cli == {"category": "pedestrian", "split": ["test", "val"]}
    peds = search.search_text(query, k=10, filters=cli, view="bev")
    assert peds and all(r.category == "pedestrian" and r.view == "bev" for r in peds)


def test_bad_input(built: dict[str, Any]) -> None:
    search = _open(built)
    with pytest.raises(EmptyQueryError):
        search.search_text("   ")
    for bad_k in (0, -1, 10_001, 2.5):
        with pytest.raises(InvalidKError, match="k must be an integer in 1"):
            search.search_text("a car", k=bad_k)  # type: ignore[arg-type]
    with pytest.raises(FilterSyntaxError, match=r"valid fields: .*category"):
        search.search_text("a car", filters={"colour": "red"})
    with pytest.raises(FilterSyntaxError, match="valid fields"):
        search.search_text("a car", filters="colour == red")
    with pytest.raises(UnknownClipError, match=r"unknown clip id 'nope'.*log00"):
        search.search_clip("nope")
    with pytest.raises(UnknownViewError, match="valid views: fused, camera, bev"):
        search.search_text("a car", view="radar")


def test_search_clip_excludes_itself_and_prefers_same_action(built: dict[str, Any]) -> None:
    search = _open(built)
    table = pq.read_table(built["clips"] / "clips.parquet").to_pylist()
    query = table[0]
    for view in ("fused", "camera", "bev"):
        results = search.search_clip(query["clip_id"], k=5, view=view)
        assert len(results) == 5
        assert query["clip_id"] not in {r.clip_id for r in results}
    fused = search.search_clip(query["clip_id"], k=5)
    assert sum(r.caption == query["caption"] for r in fused) >= 4
    arrays = search.search_clip({"caption": query["caption"], "camera": np.zeros((16, 4, 8, 8), np.float32)}, k=3)
    assert arrays[0].caption == query["caption"]


def test_search_clip_from_other_moments_leaves_out_the_objects_seen_at_the_same_time(built: dict[str, Any]) -> None:
    search = _open(built)
    table = pq.read_table(built["clips"] / "clips.parquet").to_pylist()
    query = table[5]  # windows of 1.5 s a second apart: it overlaps the clips before and after it in its log
    same_time = {r["clip_id"] for r in table if r["log_id"] == query["log_id"]
                 and r["start_ns"] < query["end_ns"] and r["end_ns"] > query["start_ns"]}
    assert len(same_time) == 3
    everywhere = [r.clip_id for r in search.search_clip(query["clip_id"], k=83)]
    assert same_time - {query["clip_id"]} <= set(everywhere)
    others = [r.clip_id for r in search.search_clip(query["clip_id"], k=83, other_moments=True)]
    assert others == [c for c in everywhere if c not in same_time]  # the rest in the same order
    in_its_log = search.search_clip(query["clip_id"], k=20, filters={"log_id": query["log_id"]}, other_moments=True)
    assert len(in_its_log) == 14 - 3 and not same_time & {r.clip_id for r in in_its_log}
    with pytest.raises(OtherMomentsError, match="needs an indexed clip id"):
        search.search_clip({"caption": query["caption"], "camera": np.zeros((16, 4, 8, 8), np.float32)},
                           other_moments=True)


def test_the_camera_view_searches_the_clips_the_camera_saw(tmp_path: Path) -> None:
    import pyarrow as pa

    clips = make_clips_dir(tmp_path / "clips")
    table = pq.read_table(clips / "clips.parquet")
    seen = [i % 3 != 0 for i in range(table.num_rows)]  # a third of the clips without camera frames
    table = table.set_column(table.column_names.index("has_camera"), "has_camera", pa.array(seen))
    pq.write_table(table, clips / "clips.parquet")
    run = make_run_dir(tmp_path / "run")
    embedder = FakeEmbedder(model_hash(run))
    search = SceneSearch.build(run, clips, tmp_path / "index", embedder=embedder, text_encoder=HashTextEncoder())
    rows = {r["clip_id"]: r for r in table.to_pylist()}
    n, n_seen = table.num_rows, sum(seen)

    everything = search.search_text("a car", k=n, view="camera")
    assert len(everything) == n_seen and all(rows[r.clip_id]["has_camera"] for r in everything)
    assert len(search.search_text("a car", k=n, view="fused")) == n  # other views show every clip
    assert len(search.search_text("a car", k=n, view="bev")) == n
    cars = search.search_text("a car", k=n, view="camera", filters="category == car")  # with the user's filter
    assert cars and len(cars) == sum(s and r["category"] == "car" for s, r in zip(seen, rows.values()))
    assert all(rows[r.clip_id]["has_camera"] and r.category == "car" for r in cars)

    with_camera, without = table.column("clip_id")[1].as_py(), table.column("clip_id")[0].as_py()
    neighbours = search.search_clip(with_camera, k=n, view="camera")
    assert len(neighbours) == n_seen - 1 and all(rows[r.clip_id]["has_camera"] for r in neighbours)
    with pytest.raises(NoCameraError, match=f"{without!r} has no camera frames.*fused or bev"):
        search.search_clip(without, k=5, view="camera")
    assert len(search.search_clip(without, k=n, view="fused")) == n - 1


def test_search_captions(built: dict[str, Any]) -> None:
    search = _open(built)
    results = search.search_captions("stops ahead of the host", k=5)
    assert len(results) == 5 and all("stops ahead" in r.caption for r in results)
    assert all(r.view == "captions" for r in results)


def test_model_version_mismatch(built: dict[str, Any], tmp_path: Path) -> None:
    with pytest.raises(ModelMismatchError, match="index built by another model version"):
        SceneSearch.open(built["index"], embedder=FakeEmbedder("another-model"), text_encoder=HashTextEncoder())
    # The run directory's weights change after the index was built: text queries refuse.
    index_copy = tmp_path / "index"
    shutil.copytree(built["index"], index_copy)
    run_copy = tmp_path / "run"
    shutil.copytree(built["run"], run_copy)
    manifest = json.loads((index_copy / "manifest.json").read_text())
    manifest["run_dir"] = str(run_copy)
    (index_copy / "manifest.json").write_text(json.dumps(seal(manifest)))  # as if built from run_copy
    (run_copy / "model.safetensors").write_bytes(b"weights-v2")
    search = SceneSearch.open(index_copy, text_encoder=HashTextEncoder())
    with pytest.raises(ModelMismatchError, match="index built by another model version"):
        search.search_text("a car")
    with pytest.raises(ModelMismatchError):
        ModelEmbedder(run_copy, expected_model_id=manifest["model_sha256"])
    # Clip → clip still works without the model.
    assert len(search.search_clip(search.get(manifest_first_clip(index_copy)).clip_id, k=2)) == 2


def manifest_first_clip(index_dir: Path) -> str:
    return str(pq.read_table(index_dir / "fused" / "metadata.parquet").column("clip_id")[0])


def test_not_an_index(tmp_path: Path) -> None:
    with pytest.raises(IndexDirError, match="no index directory"):
        SceneSearch.open(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(IndexDirError, match=r"manifest.json: missing"):
        SceneSearch.open(tmp_path / "empty")


def test_export_parquet_and_npy(built: dict[str, Any], tmp_path: Path) -> None:
    search = _open(built)
    out = search.export(tmp_path / "emb.parquet")
    table = pq.read_table(out)
    assert {"clip_id", "category", "tags", "embedding", "embedding_camera", "embedding_bev"} <= set(table.column_names)
    x = np.asarray(table.column("embedding").to_pylist(), np.float32)
    assert x.shape == (84, 64)
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, rtol=1e-4)
    _, expected = search.embeddings("fused")
    np.testing.assert_allclose(x, expected, rtol=1e-5)
    npy = search.export(tmp_path / "emb.npy", views=("bev",))
    assert np.load(npy).shape == (84, 64)
    side = json.loads((tmp_path / "emb.json").read_text())
    assert side["view"] == "bev" and len(side["rows"]) == 84
    with pytest.raises(ValueError, match=r"use .parquet or .npy"):
        search.export(tmp_path / "emb.csv")


# ---------------------------------------------------------------------- integrity and faults

ROOT = Path(__file__).resolve().parents[2]


def _flip(path: Path, count: int = 64) -> None:
    """Invert ``count`` bytes in the middle of ``path``, in place (same size)."""
    raw = bytearray(path.read_bytes())
    mid = len(raw) // 2
    raw[mid:mid + count] = bytes(b ^ 0xFF for b in raw[mid:mid + count])
    with path.open("r+b") as f:
        f.write(bytes(raw))


def _copy(built: dict[str, Any], tmp_path: Path) -> Path:
    shutil.copytree(built["index"], tmp_path / "index")
    return tmp_path / "index"


@pytest.mark.parametrize("name", ["fused/index.faiss", "bev/metadata.parquet", "captions/text_embeddings.npy",
                                  "captions/full_offsets.npy", "camera/manifest.json", "run/config.json"])
def test_corrupt_file_is_refused_naming_it(built: dict[str, Any], tmp_path: Path, name: str) -> None:
    index = _copy(built, tmp_path)
    _flip(index / name, count=min(64, (index / name).stat().st_size // 4))
    with pytest.raises(IndexDirError, match=rf"{name}.*(checksum|differs)"):
        SceneSearch.open(index, embedder=built["embedder"], text_encoder=HashTextEncoder())


def test_permuted_caption_embeddings_are_refused(built: dict[str, Any], tmp_path: Path) -> None:
    index = _copy(built, tmp_path)
    path = index / "captions" / "text_embeddings.npy"
    emb = np.load(path)
    np.save(path, emb[np.random.default_rng(0).permutation(len(emb))])  # same shape, size and dtype
    with pytest.raises(IndexDirError, match=r"text_embeddings\.npy: checksum differs"):
        SceneSearch.open(index, text_encoder=HashTextEncoder())


def test_skipping_verification_says_so_once(built: dict[str, Any], tmp_path: Path) -> None:
    from indexes.integrity import IntegrityWarning

    index = _copy(built, tmp_path)
    with pytest.warns(IntegrityWarning, match="checksums not verified") as record:
        search = SceneSearch.open(index, text_encoder=HashTextEncoder(), verify="off")
    assert len([w for w in record if issubclass(w.category, IntegrityWarning)]) == 1
    assert len(search) == 84


def test_edited_top_manifest_is_refused(built: dict[str, Any], tmp_path: Path) -> None:
    index = _copy(built, tmp_path)
    manifest = json.loads((index / "manifest.json").read_text())
    (index / "manifest.json").write_text(json.dumps({**manifest, "clips_dir": "/elsewhere"}))
    with pytest.raises(IndexDirError, match="content differs from its checksum"):
        SceneSearch.open(index, text_encoder=HashTextEncoder())


def test_check_command_reports_the_corrupt_file(built: dict[str, Any], tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    from retrieval.cli import main

    index = _copy(built, tmp_path)
    assert main(["index", "--check", str(index)]) == 0
    assert "every file matches its checksum" in capsys.readouterr().out
    _flip(index / "bev" / "index.faiss")
    assert main(["index", "--check", str(index)]) == 2
    assert "bev/index.faiss: checksum differs" in capsys.readouterr().err


_KILLED_BUILD = textwrap.dedent("""
    import sys
    sys.path[:0] = [{root!r}, {fakes!r}, {root!r} + "/tests/scenesearch_base"]
    import kill_points
    from retrieval_fakes import FakeEmbedder, HashTextEncoder
    from retrieval.scenesearch import SceneSearch
    kill_points.install({target!r}, {point!r})
    embedder = FakeEmbedder({model_id!r}, seed=1)  # another training of the same model: other vectors
    SceneSearch.build({run!r}, {clips!r}, {target!r}, embedder=embedder, text_encoder=HashTextEncoder())
""")


@pytest.mark.parametrize("point", ["after_write:text_embeddings.npy", "before_swap", "between_renames",
                                   "after_swap"])
def test_kill_during_an_index_build_keeps_a_searchable_index(built: dict[str, Any], tmp_path: Path,
                                                             point: str) -> None:
    index = _copy(built, tmp_path)
    query = caption_of(["left:approach", "left:cut_in"])
    before = [r.clip_id for r in _open_at(index, built).search_text(query, k=10)]
    code = _KILLED_BUILD.format(root=str(ROOT), fakes=str(Path(__file__).parent), target=str(index), point=point,
                                model_id=built["embedder"].model_id, run=str(built["run"]), clips=str(built["clips"]))
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == -signal.SIGKILL
    assert any(p.name.startswith(".index.") for p in tmp_path.iterdir())
    after = [r.clip_id for r in _open_at(index, built).search_text(query, k=10)]
    if point == "after_swap":
        assert after != before  # the new build is complete and in place
    else:
        assert after == before
    assert (index / "manifest.json").is_file()  # opening moved an aside copy back
    # The next build replaces the index and removes what the killed one left.
    sweep_stale(tmp_path, force=True)
    SceneSearch.build(built["run"], built["clips"], index, embedder=built["embedder"], text_encoder=HashTextEncoder())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["index"]
    assert [r.clip_id for r in _open_at(index, built).search_text(query, k=10)] == before


def _open_at(index: Path, built: dict[str, Any]) -> SceneSearch:
    return SceneSearch.open(index, embedder=built["embedder"], text_encoder=HashTextEncoder())


def test_opening_a_clips_folder_as_an_index_says_what_it_is(built: dict[str, Any], tmp_path: Path) -> None:
    """A clips folder holds a ``manifest.json`` too: its marker says what it is."""
    from encoders.clips.layout import CLIPS_FOLDER
    from retrieval.errors import IndexDirError
    from retrieval.scenesearch import SceneSearch
    from scenesearch_base.folders import mark_folder

    clips = tmp_path / "clips"
    shutil.copytree(built["clips"], clips)
    mark_folder(clips, CLIPS_FOLDER)
    with pytest.raises(IndexDirError, match=r"clips: a clips folder, not an index \(build one from it with "
                                            r"`scenesearch index RUN_DIR CLIPS_DIR --out INDEX`\)"):
        SceneSearch.open(clips)
