"""Clips from a synthetic log with camera, instance masks, sweeps and map: the highlighted object
and the marked BEV cell follow the right track, LiDAR is motion-compensated, bad input is reported."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from scipy.ndimage import binary_dilation

from encoders.clips.blocks import BlockArray
from encoders.clips.build import build_clips
from encoders.clips.config import BevSourceChoice, ClipsConfig, Split, SplitConfig
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.render import render_log
from encoders.clips.splits import assign_splits
from encoders.clips.table import ClipsInputError
from encoders.data import ClipDataset
from encoders.presets import preset
from scenes.bev import BevGrid
from scenes.log import Log
from tests.encoders.clip_fixtures import (
    EGO_SE3_CAMERA,
    FINE_CLIPS,
    INTRINSICS,
    synthetic_captions,
    write_synthetic_log,
)

CONFIG = FINE_CLIPS


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("clips_render")
    log_dir = write_synthetic_log(root / "logs", num_frames=40, ego_speed_mps=5.0)
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions([log_dir]), root / "captions" / "captions.parquet")
    build_clips([log_dir], root / "captions", root / "clips", CONFIG)
    return log_dir, root / "clips"


def _item(clips_dir: Path, track_id: str) -> dict:
    ds = ClipDataset(clips_dir)
    index = next(i for i, cid in enumerate(ds.clip_ids) if f":{track_id}:" in cid)
    return ds[index]


def _annotation_centres(log_dir: Path, track_id: str, frame_indices: np.ndarray) -> np.ndarray:
    dense = Log.open(log_dir).dense_tracks()
    k = list(dense.track_ids).index(track_id)
    return dense.center_ego_xyz_m[k, frame_indices]


def _project_small(centres_ego: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    cam = EGO_SE3_CAMERA.inverse().transform_points(centres_ego)
    small = INTRINSICS.scaled(width_px, height_px)
    uv, ok = small.project(cam)
    assert ok.all()
    return uv


def test_camera_mask_follows_the_track(built: tuple[Path, Path]) -> None:
    log_dir, clips_dir = built
    table = pq.read_table(clips_dir / "clips.parquet").to_pylist()
    lead_row = next(r for r in table if r["track_id"] == "lead")
    fi = np.asarray(lead_row["frame_indices"])
    item = _item(clips_dir, "lead")
    assert item["has_camera"]
    mask = item["camera"][:, 3].numpy() > 0.5  # (T, H, W)
    h, w = mask.shape[1:]
    lead_uv = _project_small(_annotation_centres(log_dir, "lead", fi), w, h)
    parked_uv = _project_small(_annotation_centres(log_dir, "parked", fi), w, h)
    t = np.arange(len(fi))
    # The lead car's own centre is inside the mask in every frame; the other car's is not.
    assert mask[t, lead_uv[:, 1].astype(int), lead_uv[:, 0].astype(int)].all()
    assert not mask[t, parked_uv[:, 1].astype(int), parked_uv[:, 0].astype(int)].any()
    # The mask moves right as the car changes from the left lane into the ego's lane.
    cols = np.array([np.nonzero(m)[1].mean() for m in mask])
    assert np.abs(cols - lead_uv[:, 0]).max() < 4.0
    assert cols[-1] - cols[0] > 15.0
    # Highlight: magenta over the object, the rest dimmed.
    rgb = item["camera"][:, :3].numpy()
    inside = rgb.transpose(1, 0, 2, 3)[:, mask]  # (3, N) colours of the masked pixels
    assert (inside[0] > inside[1] + 0.3).all() and (inside[2] > inside[1] + 0.3).all()
    sky = rgb[0, :, 2, 2]  # the synthetic sky is RGB (120, 170, 200), dimmed by 0.7
    np.testing.assert_allclose(sky, 0.7 * np.array([120, 170, 200]) / 255.0, atol=0.03)


def _crop_centres_and_colours(item: dict) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) the object mask's centroid in each crop and (T, 3) the mean RGB under it (0-255)."""
    crop = item["camera_crop"].numpy()  # (T, 4, H, W) in [0, 1]
    centres, colours = [], []
    for frame in crop:
        ys, xs = np.nonzero(frame[3] > 0.5)
        centres.append((xs.mean(), ys.mean()))
        colours.append(frame[:3, ys, xs].mean(axis=1) * 255.0)
    return np.array(centres), np.array(colours)


def test_object_crops_centre_each_track_in_its_own_colours(built: tuple[Path, Path]) -> None:
    _, clips_dir = built
    for track_id, colour_bgr in (("lead", (40, 40, 220)), ("parked", (220, 120, 30))):
        item = _item(clips_dir, track_id)
        box = item["camera_box"].numpy()  # (T, 4)
        assert (box[:, 3] == 1).all()  # seen in every frame
        centres, colours = _crop_centres_and_colours(item)
        h, w = item["camera_crop"].shape[-2:]
        assert np.abs(centres - [(w - 1) / 2, (h - 1) / 2]).max() < 0.05 * w  # a hull is not symmetric in its box
        np.testing.assert_allclose(colours, np.broadcast_to(colour_bgr[::-1], colours.shape), atol=25)
    # The lead car moves from the left lane into the ego's: its crop's centre moves right in the image.
    lead_box = _item(clips_dir, "lead")["camera_box"].numpy()
    assert lead_box[-1, 0] - lead_box[0, 0] > 0.2
    # The follower is behind the camera: no crop, all zeros.
    follower = _item(clips_dir, "follower")
    assert not follower["camera_crop"].any() and not follower["camera_box"].any()


def test_clips_without_their_crops_are_named_and_a_crop_model_refuses_clips_from_before_crops(
        built: tuple[Path, Path], tmp_path: Path) -> None:
    from encoders.train import TrainingError, train

    _, clips_dir = built
    damaged = tmp_path / "damaged"
    shutil.copytree(clips_dir, damaged)
    log_folder = next((damaged / "logs").iterdir())
    (log_folder / "camera_crop_index.blocks").unlink()
    with pytest.raises(FileNotFoundError, match=rf"{log_folder.name}.*camera_crop_index\.blocks is missing"):
        _item(damaged, "lead")
    # A clips folder from before crops (no manifest flag): no crop views, and a model that reads them says why.
    old = tmp_path / "old"
    shutil.copytree(clips_dir, old)
    manifest = json.loads((old / "manifest.json").read_text())
    del manifest["camera"]["object_crops"]
    (old / "manifest.json").write_text(json.dumps(manifest))
    assert "camera_crop" not in _item(old, "lead") and "camera_box" not in _item(old, "lead")
    tiny = preset("tiny").train
    crop_config = replace(tiny, model=replace(tiny.model, camera=replace(tiny.model.camera, object_crop=True)))
    with pytest.raises(TrainingError, match="object_crop.*render them again"):
        train(old, tmp_path / "run", crop_config)


def test_bev_marks_the_track_over_time(built: tuple[Path, Path]) -> None:
    log_dir, clips_dir = built
    row = next(r for r in pq.read_table(clips_dir / "clips.parquet").to_pylist() if r["track_id"] == "lead")
    fi = np.asarray(row["frame_indices"])
    item = _item(clips_dir, "lead")
    obj = item["bev_object"][:, 0].numpy()  # (T, H, W)
    centres = _annotation_centres(log_dir, "lead", fi)
    expected = BevGrid().ego_to_pixel(centres[:, :2])  # (T, 2) col, row; integers are cell centres
    for t in range(len(fi)):
        rows, cols = np.nonzero(obj[t])
        assert rows.size >= 10
        assert abs(cols.mean() - expected[t, 0]) < 1.0
        assert abs(rows.mean() - expected[t, 1]) < 1.0
    # Left lane (y = +3.5 m → column 33) into the ego lane (y = 0 → column 40).
    assert np.nonzero(obj[0])[1].mean() < 35 and np.nonzero(obj[-1])[1].mean() > 38
    # The follower is behind the ego, outside the camera: no camera view, marked below the ego.
    follower = _item(clips_dir, "follower")
    assert not follower["has_camera"] and float(follower["camera"].abs().sum()) == 0.0
    rows = np.nonzero(follower["bev_object"][0, 0].numpy())[0]
    assert rows.mean() > (60.0 + 10.0) / 0.5
    # Ego motion: 5 m/s straight ahead over the sampled frames.
    motion = item["ego_motion"].numpy()
    dt_s = (fi - fi[0]) * 0.1
    np.testing.assert_allclose(motion[:, 0], 5.0 * dt_s, atol=1e-3)
    np.testing.assert_allclose(motion[:, 1:3], 0.0, atol=1e-6)
    np.testing.assert_allclose(motion[:, 3], 5.0, atol=1e-3)


def test_map_channels_and_clip_table(built: tuple[Path, Path]) -> None:
    _, clips_dir = built
    table = pq.read_table(clips_dir / "clips.parquet")
    assert sorted(table.column("track_id").to_pylist()) == ["follower", "lead", "parked"]  # no host row
    row = table.to_pylist()[0]
    assert row["bev_source"] == "lidar" and row["time_of_day"] == "night" and row["weather"] == "rain"
    assert len(row["frame_indices"]) == CONFIG.frames_per_clip
    item = _item(clips_dir, "lead")
    bev_map = item["bev_map"][0].numpy()
    drivable = bev_map[MAP_CHANNELS.index("drivable_area")] > 0.5
    # Road from y = −6 m to +8 m: columns (20 − 8)/0.5 = 24 … (20 + 6)/0.5 = 52.
    assert drivable[:, 26:50].all() and not drivable[:, :22].any() and not drivable[:, 54:].any()
    # Lanes span y = −1.75 … 5.25 m (columns 30 … 43); their direction in the ego frame is +x:
    # x encoded 128 + 127, y 128 inside lanes, 0 outside.
    dx = bev_map[MAP_CHANNELS.index("lane_direction_x")] * 255
    dy = bev_map[MAP_CHANNELS.index("lane_direction_y")] * 255
    assert np.abs(dx[:, 31:43] - 255).max() <= 1.0 and np.abs(dy[:, 31:43] - 128).max() <= 1.0
    assert dx[:, :28].max() == 0 and dx[:, 46:].max() == 0
    # Crossing at city x = 40–44 m; at the first sampled frame (frame 5) the ego is at x = 2.5 m.
    crossing = bev_map[MAP_CHANNELS.index("crossing")] > 0.5
    rows = np.nonzero(crossing.any(axis=1))[0]
    assert abs((60.0 - rows.mean() * 0.5) - (42.0 - 2.5)) < 1.0


def test_lidar_sweeps_are_motion_compensated(tmp_path: Path) -> None:
    log_dir = write_synthetic_log(tmp_path / "logs", num_frames=8, ego_speed_mps=10.0, with_camera=False)
    log = Log.open(log_dir)
    dense = log.dense_tracks()
    parked = list(dense.track_ids).index("parked") + 1

    def spill(num_sweeps: int) -> tuple[float, float]:
        config = replace(CONFIG, bev=replace(CONFIG.bev, num_sweeps=num_sweeps, source=BevSourceChoice.LIDAR))
        out = tmp_path / f"clips_{num_sweeps}"
        render_log(log, config, out, dense)
        occ = BlockArray(out / "logs" / log_dir.name / "bev_lidar.blocks")[:][6, 1:].max(axis=0) > 0  # above ground
        inst = BlockArray(out / "logs" / log_dir.name / "bev_instances.blocks")[:][6] == parked
        rows, cols = np.nonzero(inst)
        window = np.zeros_like(inst)
        window[rows.min() - 8 : rows.max() + 9, cols.min() - 3 : cols.max() + 4] = True
        grown = np.zeros_like(inst)
        grown[rows.min() - 1 : rows.max() + 2, cols.min() - 1 : cols.max() + 2] = True
        others = BlockArray(out / "logs" / log_dir.name / "bev_instances.blocks")[:][6] > 0
        grown |= binary_dilation(others & ~inst, iterations=2)
        return float(occ[inst].mean()), float((occ & window & ~grown).sum())

    fill_1, spill_1 = spill(1)
    fill_3, spill_3 = spill(3)
    # The ego drives 1 m per frame: without compensation a parked car would smear 2 m (4 cells).
    assert spill_1 == 0 and spill_3 == 0
    assert fill_3 > fill_1


def test_bad_input_is_named_or_reported(built: tuple[Path, Path], tmp_path: Path) -> None:
    log_dir, _ = built
    captions = synthetic_captions([log_dir]).to_pylist()
    bad = [*captions, {**captions[0], "log_id": "no_such_log"}, {**captions[0], "track_id": "ghost"}]
    (tmp_path / "c").mkdir()
    pq.write_table(pa.Table.from_pylist(bad), tmp_path / "c" / "captions.parquet")
    with pytest.raises(ClipsInputError, match=r"no_such_log.*row 4.*ghost|no_such_log") as info:
        build_clips([log_dir], tmp_path / "c", tmp_path / "out", CONFIG)
    assert "ghost" in str(info.value) and "captions.parquet" in str(info.value)
    # Lenient: skipped and reported; windows outside the log are skipped too.
    outside = {**captions[1], "start_ns": 10**18, "end_ns": 10**18 + 1}
    pq.write_table(pa.Table.from_pylist([*bad, outside]), tmp_path / "c" / "captions.parquet")
    report = build_clips([log_dir], tmp_path / "c", tmp_path / "out", replace(CONFIG, strict=False))
    reasons = " | ".join(s["reason"] for s in report.skipped)
    assert "log not given" in reasons and "track not in log" in reasons and "outside the log's time range" in reasons
    assert report.num_clips == 3
    # A category outside the vocabulary the model reads is refused, named by file, row and field.
    pq.write_table(pa.Table.from_pylist([*captions, {**captions[0], "category": "lorry"}]),
                   tmp_path / "c" / "captions.parquet")
    with pytest.raises(ClipsInputError, match=rf"captions.parquet, row {len(captions)}, field 'category': 'lorry' is "
                                              "not one of"):
        build_clips([log_dir], tmp_path / "c", tmp_path / "out2", replace(CONFIG, strict=False))
    assert not (tmp_path / "out2" / "clips.parquet").exists()


def test_corrupt_sweep_is_skipped_counted_and_reported(tmp_path: Path) -> None:
    log_dir = write_synthetic_log(tmp_path / "logs", num_frames=12, with_camera=False)
    sweeps = sorted((log_dir / "sensors" / "lidar").glob("*.feather"))
    sweeps[6].write_bytes(b"not a feather file")
    (tmp_path / "c").mkdir()
    pq.write_table(synthetic_captions([log_dir], 1, 10), tmp_path / "c" / "captions.parquet")
    report = build_clips([log_dir], tmp_path / "c", tmp_path / "clips", CONFIG)
    stats = report.logs[log_dir.name]
    assert len(stats["corrupt_sweeps"]) == 1 and sweeps[6].name in stats["corrupt_sweeps"][0]
    assert stats["frames_without_sweep"] == 1 and stats["bev_source"] == "lidar"
    occ = BlockArray(tmp_path / "clips" / "logs" / log_dir.name / "bev_lidar.blocks")[:]
    assert occ[6].max() == 0 and occ[5].max() > 0 and occ[7].max() > 0
    # A second run reuses the rendered log.
    again = build_clips([log_dir], tmp_path / "c", tmp_path / "clips", CONFIG)
    assert again.reused_logs == 1 and again.num_clips == report.num_clips


def test_a_log_written_anew_is_rendered_again(tmp_path: Path) -> None:
    log_dir = write_synthetic_log(tmp_path / "logs", num_frames=12, with_camera=False, ego_speed_mps=5.0)
    (tmp_path / "c").mkdir()
    pq.write_table(synthetic_captions([log_dir], 1, 10), tmp_path / "c" / "captions.parquet")
    build_clips([log_dir], tmp_path / "c", tmp_path / "clips", CONFIG)
    # The same log id, simulated again with other content (a longer log, another ego speed).
    shutil.rmtree(log_dir)
    write_synthetic_log(tmp_path / "logs", num_frames=16, with_camera=False, ego_speed_mps=8.0)
    again = build_clips([log_dir], tmp_path / "c", tmp_path / "clips", CONFIG)
    assert again.reused_logs == 0 and again.logs[log_dir.name]["frames"] == 16


def test_cli_writes_clips_and_previews(built: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from PIL import Image

    from retrieval.cli import main

    log_dir, _ = built
    (tmp_path / "c").mkdir()
    pq.write_table(synthetic_captions([log_dir]), tmp_path / "c" / "captions.parquet")
    plain = tmp_path / "plain"
    assert main(["clips", str(log_dir), "--captions", str(tmp_path / "c"), "--out", str(plain),
                 "--frames-per-clip", "8"]) == 0
    # Without --previews none is stored: they are drawn when shown.
    assert not (plain / "previews").exists()
    assert all(r["preview_path"] is None for r in pq.read_table(plain / "clips.parquet").to_pylist())
    out = tmp_path / "clips"
    assert main(["clips", str(log_dir), "--captions", str(tmp_path / "c"), "--out", str(out),
                 "--frames-per-clip", "8", "--previews"]) == 0
    assert "wrote 3 clips" in capsys.readouterr().out
    rows = pq.read_table(out / "clips.parquet").to_pylist()
    assert all(len(r["frame_indices"]) == 8 for r in rows)
    with Image.open(out / rows[0]["preview_path"]) as gif:
        assert gif.n_frames == 8 and gif.size[0] > gif.size[1]
    # The build opens each log once for all its previews; a preview on its own opens it itself.
    from encoders.clips.preview import write_preview

    alone = write_preview(out, rows[-1]["clip_id"], tmp_path / "alone.gif")
    assert alone.read_bytes() == (out / rows[-1]["preview_path"]).read_bytes()


def test_cli_train_val_and_test_only_logs_keep_their_split(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from retrieval.cli import main

    # Three logs to evaluate on fill the three splits; each extra log, hashed alone, would land elsewhere.
    logs = [write_synthetic_log(tmp_path / "logs", log_id=f"eval_{i}", num_frames=40, with_camera=False, seed=i)
            for i in range(3)]
    extra, val, test = (write_synthetic_log(tmp_path / folder, log_id=name, num_frames=40, with_camera=False, seed=9)
                        for folder, name in (("extra", "extra_0"), ("val", "val_0"), ("test", "test_0")))
    splits = SplitConfig(train_fraction=0.01, val_fraction=0.5)
    assert [assign_splits([n], splits)[n] for n in ("extra_0", "val_0", "test_0")] == [Split.VAL, Split.TEST, Split.VAL]
    (tmp_path / "c").mkdir()
    pq.write_table(synthetic_captions([*logs, extra, val, test]), tmp_path / "c" / "captions.parquet")
    config = tmp_path / "clips.yaml"
    ClipsConfig(previews=False, split=splits).to_yaml(config)
    out = tmp_path / "clips"
    assert main(["clips", *map(str, logs), "--train-only", str(extra), "--val-only", str(val), "--test-only",
                 str(test), "--captions", str(tmp_path / "c"), "--out", str(out), "--frames-per-clip", "4",
                 "--config", str(config)]) == 0
    split_of = dict(zip(*pq.read_table(out / "clips.parquet", columns=["log_id", "split"]).to_pydict().values()))
    assert (split_of["extra_0"], split_of["val_0"], split_of["test_0"]) == ("train", "val", "test")
    assert {split_of[p.name] for p in logs} == {"train", "val", "test"}
    # A log given for two splits is refused before anything is rendered.
    capsys.readouterr()
    assert main(["clips", *map(str, logs), "--val-only", str(val), "--test-only", str(val), "--captions",
                 str(tmp_path / "c"), "--out", str(tmp_path / "refused"), "--config", str(config)]) == 2
    assert "log(s) val_0 named more than once in train_only / val_only / test_only" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()


def test_camera_without_instance_masks_projects_the_boxes(tmp_path: Path) -> None:
    import shutil

    log_dir = write_synthetic_log(tmp_path / "logs", num_frames=20, with_lidar=False)
    shutil.rmtree(log_dir / "sensors" / "cameras" / "ring_front_center_instance")
    (tmp_path / "c").mkdir()
    pq.write_table(synthetic_captions([log_dir], 2, 18), tmp_path / "c" / "captions.parquet")
    report = build_clips([log_dir], tmp_path / "c", tmp_path / "clips", CONFIG)
    assert report.logs[log_dir.name]["camera_mask_source"] == "projected_boxes"
    assert report.logs[log_dir.name]["bev_source"] == "boxes"
    row = next(r for r in pq.read_table(tmp_path / "clips" / "clips.parquet").to_pylist() if r["track_id"] == "lead")
    fi = np.asarray(row["frame_indices"])
    mask = _item(tmp_path / "clips", "lead")["camera"][:, 3].numpy() > 0.5
    uv = _project_small(_annotation_centres(log_dir, "lead", fi), mask.shape[2], mask.shape[1])
    assert mask[np.arange(len(fi)), uv[:, 1].astype(int), uv[:, 0].astype(int)].all()
    assert not _item(tmp_path / "clips", "follower")["has_camera"]
    # The crops come from the projected boxes: the lead car in the middle, in its colour.
    lead = _item(tmp_path / "clips", "lead")
    centres, colours = _crop_centres_and_colours(lead)
    h, w = lead["camera_crop"].shape[-2:]
    assert np.abs(centres - [(w - 1) / 2, (h - 1) / 2]).max() < 0.05 * w  # a hull is not symmetric in its box
    assert (colours[:, 0] > colours[:, 1] + 100).all()  # red (BGR 40, 40, 220)


def test_track_footprints_match_scenes_bev_and_highlight_blends() -> None:
    from encoders.clips.raster import rasterize_track
    from encoders.clips.views import highlight_camera
    from scenes.bev import rasterize_boxes

    grid, rng = BevGrid(), np.random.default_rng(0)
    boxes = np.c_[rng.uniform(-15, 55, (12, 1)), rng.uniform(-15, 15, (12, 1)), rng.uniform(0.4, 12, (12, 1)),
                  rng.uniform(0.4, 3, (12, 1)), rng.uniform(-3, 3, (12, 1))]
    boxes[3] = np.nan
    fast = rasterize_track(grid, boxes)
    assert fast[3].sum() == 0 and fast.sum() > 100
    for t in [0, 1, 2, *range(4, 12)]:
        np.testing.assert_array_equal(fast[t], rasterize_boxes(grid, boxes[t : t + 1, :2], boxes[t : t + 1, 2:4],
                                                               boxes[t : t + 1, 4]) > 0)
    rgb = rng.integers(0, 256, (2, 6, 7, 3)).astype(np.uint8)
    mask = rng.random((2, 6, 7)) > 0.5
    shown = highlight_camera(rgb, mask, (255, 0, 255), 0.5, 0.7).astype(float)
    expected = np.where(mask[..., None], 0.5 * rgb + 0.5 * np.array([255, 0, 255]), 0.7 * rgb)
    assert np.abs(shown - expected).max() <= 1.0


def test_a_log_with_a_bad_map_is_skipped_and_an_all_failed_batch_keeps_the_old_output(tmp_path: Path) -> None:
    good = write_synthetic_log(tmp_path / "logs", num_frames=12, with_camera=False, log_id="good")
    bad = write_synthetic_log(tmp_path / "logs", num_frames=12, with_camera=False, log_id="bad")
    (tmp_path / "c").mkdir()
    pq.write_table(synthetic_captions([good, bad], 1, 10), tmp_path / "c" / "captions.parquet")
    first = build_clips([good], tmp_path / "c", tmp_path / "clips", replace(CONFIG, strict=False))
    table_before = (tmp_path / "clips" / "clips.parquet").read_bytes()
    for map_file in (bad / "map").glob("log_map_archive_*.json"):
        map_file.write_text("[]")
    report = build_clips([bad, good], tmp_path / "c", tmp_path / "clips2", replace(CONFIG, strict=False))
    assert report.num_clips == first.num_clips > 0
    assert any(s.get("log_id") == "bad" and "map" in s["reason"] for s in report.skipped)
    with pytest.raises(ClipsInputError,
                       match=r"no clip could be made from 1 log\(s\);.*bad: log could not be rendered: .*map JSON"):
        build_clips([bad], tmp_path / "c", tmp_path / "clips", replace(CONFIG, strict=False))
    assert (tmp_path / "clips" / "clips.parquet").read_bytes() == table_before


def test_captions_of_a_log_per_row_group_give_the_same_clips_and_an_unopened_log_names_its_clips(
        tmp_path: Path) -> None:
    """As ``caption`` writes them, each log's task reads its own caption rows: the same table as from
    captions written at once; a log that cannot be opened names each of its clips as skipped."""
    logs = [write_synthetic_log(tmp_path / "logs", num_frames=12, with_camera=False, log_id=name)
            for name in ("b", "a", "broken")]
    (logs[2] / "annotations.feather").write_bytes(b"not a feather file")
    captions = synthetic_captions(logs, 1, 10)
    (tmp_path / "whole").mkdir()
    pq.write_table(captions, tmp_path / "whole" / "captions.parquet")
    (tmp_path / "grouped").mkdir()
    with pq.ParquetWriter(tmp_path / "grouped" / "captions.parquet", captions.schema) as writer:
        for name in ("b", "a", "broken"):
            writer.write_table(captions.filter(pc.equal(captions.column("log_id"), name)))
    config = replace(CONFIG, strict=False)
    reports = {kind: build_clips(logs, tmp_path / kind, tmp_path / f"clips_{kind}", config)
               for kind in ("whole", "grouped")}
    tables = {kind: pq.read_table(tmp_path / f"clips_{kind}" / "clips.parquet") for kind in reports}
    assert tables["grouped"].equals(tables["whole"]) and tables["whole"].num_rows == 6
    assert tables["whole"].column("log_id").to_pylist() == ["b"] * 3 + ["a"] * 3  # the captions' order
    for report in reports.values():
        unopened = sorted(s["clip"] for s in report.skipped if s["reason"] == "log could not be opened")
        assert unopened == ["broken:follower:" + str(captions.column("start_ns")[0]),
                            "broken:lead:" + str(captions.column("start_ns")[0]),
                            "broken:parked:" + str(captions.column("start_ns")[0])]
