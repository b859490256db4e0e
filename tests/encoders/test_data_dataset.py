"""The clip dataset: tensors, seeded augmentation that moves the BEV consistently, collate, workers."""

from __future__ import annotations

import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch

from encoders.clips.build import build_clips
from encoders.clips.layout import parse_clip_id, read_clip_table, read_manifest
from encoders.clips.views import EGO_MOTION_FEATURES
from encoders.data import AugmentConfig, ClipDataset, collate_clips
from encoders.dense import DENSE_TASKS
from scenes.bev import BevGrid
from tests.encoders.clip_fixtures import FINE_CLIPS, synthetic_captions, synthetic_frame_tags, write_synthetic_log


@pytest.fixture(scope="module")
def clips_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("clips_data")
    logs = [
        write_synthetic_log(root / "logs", log_id=f"synthetic_{i}", num_frames=24, with_lidar=i != 1, seed=i)
        for i in range(3)
    ]
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions(logs, 2, 21), root / "captions" / "captions.parquet")
    pq.write_table(synthetic_frame_tags(logs, 24), root / "captions" / "frame_tags.parquet")
    config = replace(FINE_CLIPS, frames_per_clip=8)
    build_clips(logs, root / "captions", root / "clips", config)
    return root / "clips"


def test_items_have_the_interface_shapes_and_value_ranges(clips_dir: Path) -> None:
    manifest = read_manifest(clips_dir)
    table = read_clip_table(clips_dir)
    ds = ClipDataset(clips_dir)
    assert len(ds) == table.num_rows == 9
    item = ds[0]
    t = manifest["frames_per_clip"]
    hb, wb = manifest["bev"]["height_px"], manifest["bev"]["width_px"]
    assert (hb, wb) == (160, 80)
    assert item["camera"].shape == (t, 4, manifest["camera"]["height_px"], manifest["camera"]["width_px"])
    assert item["bev_lidar"].shape == (t, len(manifest["bev"]["lidar_channels"]), hb, wb)
    assert item["bev_map"].shape == (t, len(manifest["bev"]["map_channels"]), hb, wb)
    assert item["bev_object"].shape == (t, 1, hb, wb) and item["ego_motion"].shape == (t, EGO_MOTION_FEATURES)
    assert item["object_track"].shape == (t, 11) and item["object_track"].dtype == torch.float32
    for key in ("camera", "bev_lidar", "bev_map", "bev_object"):
        assert item[key].dtype == torch.float32 and float(item[key].min()) >= 0.0 and float(item[key].max()) <= 1.0
    assert item["caption"] == item["canonical_caption"]
    # The log without sweeps gets a BEV rendered from boxes, flagged in the table.
    sources = dict(zip(table.column("log_id").to_pylist(), table.column("bev_source").to_pylist()))
    assert sources["synthetic_1"] == "boxes" and sources["synthetic_0"] == "lidar"
    # The camera flags come from the table, as the items say.
    assert ds.camera_flags.tolist() == table.column("has_camera").to_pylist()
    assert ds.camera_flags.tolist() == [bool(ds[i]["has_camera"]) for i in range(len(ds))]


def test_splits_do_not_share_logs(clips_dir: Path) -> None:
    seen: dict[str, set[str]] = {}
    for split in ("train", "val", "test"):
        ds = ClipDataset(clips_dir, split=split)
        seen[split] = {parse_clip_id(cid)[0] for cid in ds.clip_ids}
        assert len(ds) >= 3  # three logs → every split gets one
    assert not (seen["train"] & seen["val"]) and not (seen["train"] & seen["test"]) and not (seen["val"] & seen["test"])
    with pytest.raises(ValueError, match="split"):
        ClipDataset(clips_dir, split="validation")


def test_augmentation_is_seeded_and_moves_the_bev_consistently(clips_dir: Path) -> None:
    plain = ClipDataset(clips_dir)
    index = next(i for i, c in enumerate(plain.clip_ids) if c.startswith("synthetic_0:lead"))
    aug_cfg = AugmentConfig(max_rotation_rad=0.3, max_translation_m=2.0, paraphrase_probability=1.0)
    a = ClipDataset(clips_dir, augment=True, seed=1, augment_config=aug_cfg)
    b = ClipDataset(clips_dir, augment=True, seed=1, augment_config=aug_cfg)
    x, y = a[index], b[index]
    assert x["caption"] == y["caption"] and "paraphrase" in x["caption"]
    assert torch.equal(x["bev_map"], y["bev_map"]) and torch.equal(x["camera"], y["camera"])
    a.set_epoch(1)
    assert not torch.equal(a[index]["bev_map"], x["bev_map"])
    # Recover the drawn rotation and shift, then check the object moved to R(θ)·p + shift.
    rng = np.random.default_rng([1, 0, index])
    rng.random()
    rng.integers(2)
    rng.uniform(size=3)  # colour jitter draws (brightness, contrast, saturation)
    theta = rng.uniform(-0.3, 0.3)
    shift = rng.uniform(-2.0, 2.0, size=2)
    grid = BevGrid()
    base = plain[index]["bev_object"][:, 0].numpy()
    moved = x["bev_object"][:, 0].numpy()
    for t in (0, base.shape[0] - 1):
        r, c = np.nonzero(base[t])
        p = np.stack([grid.x_max_m - (r.mean() + 0.5) * 0.5, grid.y_max_m - (c.mean() + 0.5) * 0.5])
        rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
        expected = grid.ego_to_pixel(rot @ p + shift)[0]  # integers are cell centres
        r2, c2 = np.nonzero(moved[t])
        assert abs(c2.mean() - expected[0]) < 1.0 and abs(r2.mean() - expected[1]) < 1.0
    # Ego motion rotates with the BEV; speed is unchanged.
    m0, m1 = plain[index]["ego_motion"].numpy(), x["ego_motion"].numpy()
    np.testing.assert_allclose(np.linalg.norm(m1[:, :2], axis=1), np.linalg.norm(m0[:, :2], axis=1), atol=1e-4)
    np.testing.assert_allclose(np.arctan2(m1[-1, 1], m1[-1, 0]), theta, atol=1e-4)
    np.testing.assert_allclose(m1[:, 3:], m0[:, 3:])  # speed and rates: the rotation changes none of them
    # The object's track turns with them: positions and headings, relative and ground-fixed alike.
    k0, k1 = plain[index]["object_track"].numpy(), x["object_track"].numpy()
    rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    for first in (0, 2, 4, 6):
        np.testing.assert_allclose(k1[:, first:first + 2], k0[:, first:first + 2] @ rot.T, atol=1e-5)
    np.testing.assert_array_equal(k1[:, 8:], k0[:, 8:])  # size and observed flag
    # Colour jitter changes the RGB but never the mask channel.
    assert torch.equal(x["camera"][:, 3], plain[index]["camera"][:, 3])
    assert not torch.allclose(x["camera"][:, :3], plain[index]["camera"][:, :3])


def test_collate_and_worker_loading(clips_dir: Path) -> None:
    ds = ClipDataset(clips_dir, augment=True)
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, collate_fn=collate_clips, shuffle=False)
    batches = list(loader)
    assert sum(len(b["clip_id"]) for b in batches) == len(ds)
    batch = batches[0]
    assert batch["camera"].shape[:2] == (4, 8) and batch["bev_lidar"].dim() == 5
    assert batch["has_camera"].dtype == torch.bool and batch["has_camera"].shape == (4,)
    assert isinstance(batch["caption"], list) and isinstance(batch["tags"][0], list)
    # Rows without a camera view carry zeros; rows with one carry the highlighted object.
    cam = batch["camera"].flatten(1).abs().sum(dim=1)
    assert bool(((cam > 0) == batch["has_camera"]).all())
    same = ClipDataset(clips_dir, augment=True)
    np.testing.assert_allclose(batch["bev_map"][1].numpy(), same[1]["bev_map"].numpy())


def test_uint8_batches_match_the_float_interface(clips_dir: Path) -> None:
    floats = ClipDataset(clips_dir, augment=True, seed=2)
    raw = ClipDataset(clips_dir, augment=True, seed=2, as_uint8=True)
    indices = [0, 3, 5]
    a, b = floats.__getitems__(indices), raw.__getitems__(indices)
    for key in ("camera", "bev_lidar", "bev_map", "bev_object"):
        assert b[key].dtype == torch.uint8 and a[key].dtype == torch.float32
        torch.testing.assert_close(b[key].float() / 255.0, a[key])
        # A batch is the items, stacked: same fill whether fetched alone or together.
        torch.testing.assert_close(raw[indices[1]][key], b[key][1])
    torch.testing.assert_close(a["ego_motion"], b["ego_motion"])
    assert a["caption"] == b["caption"] and a["clip_id"] == [floats.clip_ids[i] for i in indices]


def test_clips_carry_each_frames_rule_tags_as_dense_targets(clips_dir: Path) -> None:
    table = pq.read_table(clips_dir / "clips.parquet").to_pylist()
    lead = next(r for r in table if r["track_id"] == "lead")
    # frame_tags: lead in the left lane for frames 0..11, then in the ego's lane; the clip samples 2..21.
    assert lead["frame_lane"] == ["left" if f < 12 else "host" for f in lead["frame_indices"]]
    assert set(lead["frame_motion"]) == {"approach"}
    assert set(lead["frame_host_motion"]) == {"cruising"}
    ds = ClipDataset(clips_dir)
    assert ds.has_frame_tags
    i = ds.clip_ids.index(lead["clip_id"])
    targets = ds[i]["frame_targets"]  # (T, K)
    assert targets.shape == (8, len(DENSE_TASKS))
    lanes = [DENSE_TASKS["lane"][int(k)] for k in targets[:, 0]]
    assert lanes == lead["frame_lane"]
    assert {DENSE_TASKS["motion"][int(k)] for k in targets[:, 1]} == {"approach"}


def test_frame_tags_are_found_beside_a_captions_file_given_by_name(clips_dir: Path, tmp_path: Path) -> None:
    root = clips_dir.parent
    logs = sorted((root / "logs").iterdir())
    config = replace(FINE_CLIPS, frames_per_clip=8)
    build_clips(logs, root / "captions" / "captions.parquet", tmp_path / "clips", config)
    lead = next(r for r in pq.read_table(tmp_path / "clips" / "clips.parquet").to_pylist() if r["track_id"] == "lead")
    assert lead["frame_lane"] == ["left" if f < 12 else "host" for f in lead["frame_indices"]]


def test_per_log_state_is_bounded_and_items_read_the_same_after_eviction(clips_dir: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A pass over many logs keeps at most the budgets of opened logs and kinematics; a log evicted
    is opened and computed again, to the same items."""
    import encoders.data as data

    whole = ClipDataset(clips_dir, as_uint8=True)
    expected = [whole[i] for i in range(len(whole))]
    logs = {r["log_id"] for r in read_clip_table(clips_dir).to_pylist()}
    assert len(whole._arrays) == len(whole._kinematics) == len(logs) == 3  # within the budgets: all kept
    one_log = next(iter(whole._kinematics._values.values()))[1]
    monkeypatch.setattr(data, "LOGS_KEPT", 1)
    monkeypatch.setattr(data, "KINEMATICS_KEPT_BYTES", one_log)
    bounded = ClipDataset(clips_dir, as_uint8=True)
    for _ in range(2):  # the second pass reopens every log
        for i in reversed(range(len(bounded))):
            item = bounded[i]
            assert len(bounded._arrays) == 1 and bounded._kinematics.total <= one_log
            for key, value in expected[i].items():
                if isinstance(value, torch.Tensor):
                    assert torch.equal(item[key], value), key
                else:
                    assert item[key] == value, key


def test_object_velocity_is_relative_to_the_ego_in_metres_per_second(clips_dir: Path) -> None:
    ds = ClipDataset(clips_dir)
    by_track = {ds[i]["track_id"]: ds[i] for i in range(len(ds)) if ds[i]["log_id"] == "synthetic_0"}
    # The ego drives +x at 5 m/s: the parked car comes back at 5 m/s, the follower keeps its distance.
    np.testing.assert_allclose(by_track["parked"]["object_velocity"].numpy(), [[-5.0, 0.0]] * 8, atol=1e-3)
    np.testing.assert_allclose(by_track["follower"]["object_velocity"].numpy(), 0.0, atol=1e-3)
    lead_vy = by_track["lead"]["object_velocity"].numpy()[:, 1]
    assert lead_vy.min() < -0.5  # the lead moves right, into the ego's lane


def test_object_rates_are_the_objects_own_motion_over_ground(clips_dir: Path) -> None:
    """The ego drives at 5 m/s: the parked car stands (its own speed 0, though it comes back at 5 m/s relative to
    the ego), the follower drives with the ego at 5 m/s."""
    ds = ClipDataset(clips_dir)
    by_track = {ds[i]["track_id"]: ds[i] for i in range(len(ds)) if ds[i]["log_id"] == "synthetic_0"}
    assert by_track["parked"]["object_rates"].shape == (8, 3)
    np.testing.assert_allclose(by_track["parked"]["object_rates"].numpy(), 0.0, atol=1e-3)
    np.testing.assert_allclose(by_track["follower"]["object_rates"].numpy()[:, 0], 5.0, atol=1e-2)


def test_a_category_outside_the_vocabulary_names_the_table_the_field_and_the_clip(
        clips_dir: Path, tmp_path: Path) -> None:
    copy = tmp_path / "clips"
    shutil.copytree(clips_dir, copy, symlinks=True)
    table = read_clip_table(copy)
    cats = table.column("category").to_pylist()
    cats[2] = "lorry"
    pq.write_table(table.set_column(table.schema.get_field_index("category"), "category",
                                    pa.array(cats, pa.string())), copy / "clips.parquet")
    first = table.column("clip_id").to_pylist()[2]
    expected = f"clips.parquet: field 'category' holds ['lorry'] (first at clip '{first}')"
    with pytest.raises(ValueError, match=re.escape(expected)):
        ClipDataset(copy)
