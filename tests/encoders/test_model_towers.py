"""Tower shapes, frame-order sensitivity, views and the logit scale of the DualEncoder (tiny config)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import pytest
import torch

from encoders.config import ConfigError, tiny_model_config
from encoders.fusion import UNKNOWN_CATEGORY, category_indices
from encoders.model import DualEncoder
from scenes.categories import CATEGORY_NAMES
from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec, collate_clips

SPEC = SyntheticSpec(frames=8, camera_hw=(32, 48), bev_hw=(32, 16), camera_fraction=1.0)


@pytest.fixture(scope="module")
def batch() -> dict[str, Any]:
    torch.set_num_threads(1)
    ds = SyntheticClipDataset(4, spec=SPEC, seed=3)
    return collate_clips([ds[i] for i in range(4)])


@pytest.fixture(scope="module")
def model() -> DualEncoder:
    torch.manual_seed(0)
    return DualEncoder(tiny_model_config()).eval()


def reverse_time(batch: dict[str, Any]) -> dict[str, Any]:
    return {k: v.flip(1) if isinstance(v, torch.Tensor) and v.ndim >= 3 else v for k, v in batch.items()}


def test_shapes(model: DualEncoder, batch: dict[str, Any]) -> None:
    with torch.no_grad():
        for view in ("fused", "camera", "bev"):
            v = model.encode_video(batch, view=view)
            assert v.shape == (4, 32)
            assert torch.allclose(v.norm(dim=-1), torch.ones(4), atol=1e-5)
        raw = model.encode_video(batch, normalize=False)
        assert not torch.allclose(raw.norm(dim=-1), torch.ones(4), atol=1e-3)
        t = model.encode_text(batch["caption"])
        assert t.shape == (4, 32)
        e = model.bev_embedding(batch)
    cfg = model.config.bev
    assert e.shape == (4, SPEC.frames, cfg.embed_channels, 32 // cfg.downsample, 16 // cfg.downsample)


def test_bev_embedding_is_fully_convolutional_in_time(model: DualEncoder, batch: dict[str, Any]) -> None:
    with torch.no_grad():
        e_full = model.bev_embedding(batch)
        short = {k: v[:, :5] if isinstance(v, torch.Tensor) and v.ndim >= 3 else v for k, v in batch.items()}
        e_short = model.bev_embedding(short)
    assert e_short.shape[1] == 5
    # Away from the cut (temporal kernel 3), frames see the same inputs and get the same E.
    assert torch.allclose(e_full[:, :4], e_short[:, :4], atol=1e-5)


@pytest.mark.parametrize("view", ["camera", "bev"])
def test_towers_depend_on_frame_order(model: DualEncoder, batch: dict[str, Any], view: str) -> None:
    with torch.no_grad():
        forward = model.encode_video(batch, view=view)
        backward = model.encode_video(reverse_time(batch), view=view)
    assert (forward - backward).abs().max() > 1e-3


def test_unknown_view_is_rejected(model: DualEncoder, batch: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="view"):
        model.encode_video(batch, view="lidar")


def test_clip_without_camera_uses_bev_only(model: DualEncoder, batch: dict[str, Any]) -> None:
    no_cam = dict(batch, has_camera=torch.zeros(4, dtype=torch.bool), camera=torch.rand_like(batch["camera"]))
    with torch.no_grad():
        a = model.encode_video(no_cam)
        b = model.encode_video(dict(no_cam, camera=torch.zeros_like(batch["camera"])))
        fused = model.encode_video(batch)
    assert torch.allclose(a, b, atol=1e-6)  # camera pixels are ignored
    assert not torch.allclose(a, fused, atol=1e-4)  # but used when present


def test_modality_dropout_only_in_training(batch: dict[str, Any]) -> None:
    torch.manual_seed(0)
    model = DualEncoder(tiny_model_config())
    model.fusion.train()
    cam, bev = torch.randn(64, 32), torch.randn(64, 32)
    has = torch.ones(64, dtype=torch.bool)
    torch.manual_seed(1)
    trained = model.fusion(cam, bev, has)
    model.fusion.eval()
    evaluated = model.fusion(cam, bev, has)
    changed = (trained - evaluated).abs().amax(dim=1) > 1e-6
    # drop_camera_p + drop_bev_p = 0.45 of the clips lose one view
    assert 10 <= int(changed.sum()) <= 48


def category_model(drop_p: float = 0.0) -> DualEncoder:
    tiny = tiny_model_config()
    torch.manual_seed(0)
    return DualEncoder(replace(tiny, fusion=replace(tiny.fusion, object_category=True, category_drop_p=drop_p)))


def test_category_indices_follow_the_vocabulary_and_name_what_they_cannot_read() -> None:
    cpu = torch.device("cpu")
    idx = category_indices(["car", "pedestrian", "other"], 3, cpu)
    assert idx.tolist() == [CATEGORY_NAMES.index(c) for c in ("car", "pedestrian", "other")]
    assert len(CATEGORY_NAMES) == UNKNOWN_CATEGORY and UNKNOWN_CATEGORY not in idx.tolist()
    with pytest.raises(ValueError, match=r"'category'.*\['lorry'\] not among the object categories"):
        category_indices(["car", "lorry"], 2, cpu)
    with pytest.raises(ValueError, match="1 categories for 2 clips"):
        category_indices(["car"], 2, cpu)


def test_object_category_reaches_the_fused_view_only(batch: dict[str, Any]) -> None:
    model = category_model().eval()
    cars, trucks = dict(batch, category=["car"] * 4), dict(batch, category=["truck"] * 4)
    untold = {k: v for k, v in batch.items() if k != "category"}
    assert model.category(untold) is None
    with torch.no_grad():
        # Zero at first: the fusion starts as it was without categories.
        torch.testing.assert_close(model.encode_video(cars), model.encode_video(untold))
        model.fusion.category.weight.normal_()  # type: ignore[union-attr]
        # A batch without categories reads the "not told" row, as the fusion does when given none.
        cam, bev, has = torch.randn(4, 32), torch.randn(4, 32), torch.ones(4, dtype=torch.bool)
        unknown = torch.full((4,), UNKNOWN_CATEGORY, dtype=torch.long)
        torch.testing.assert_close(model.fusion(cam, bev, has, unknown), model.fusion(cam, bev, has, None))
        assert not torch.allclose(model.encode_video(cars), model.encode_video(trucks), atol=1e-4)
        views_car, views_truck = model.encode_views(cars), model.encode_views(trucks)
    for view in ("camera", "bev"):
        torch.testing.assert_close(views_car[view], views_truck[view])
    torch.testing.assert_close(views_car["fused"], model.encode_video(cars), atol=1e-6, rtol=1e-5)
    # A model without the option reads no category: its fusion has no vectors for them.
    plain = DualEncoder(tiny_model_config()).eval()
    assert plain.fusion.category is None and plain.category(cars) is None


def test_category_dropout_withholds_categories_in_training_only(batch: dict[str, Any]) -> None:
    model = category_model(drop_p=1.0)
    with torch.no_grad():
        model.fusion.category.weight.normal_()  # type: ignore[union-attr]
    cam, bev, has = torch.randn(4, 32), torch.randn(4, 32), torch.zeros(4, dtype=torch.bool)
    cars = category_indices(["car"] * 4, 4, torch.device("cpu"))
    model.fusion.train()
    torch.manual_seed(1)
    withheld = model.fusion(cam, bev, has, cars)
    torch.manual_seed(1)
    torch.testing.assert_close(withheld, model.fusion(cam, bev, has, None))
    model.fusion.eval()
    assert not torch.allclose(model.fusion(cam, bev, has, cars), model.fusion(cam, bev, has, None), atol=1e-4)


def test_logit_scale_init_and_clamp() -> None:
    model = DualEncoder(tiny_model_config())
    assert math.isclose(float(model.scale().detach()), 1 / 0.07, rel_tol=1e-5)
    with torch.no_grad():
        model.logit_scale.fill_(10.0)
    assert math.isclose(float(model.scale().detach()), 100.0, rel_tol=1e-5)


def test_saved_state_dict_round_trip(model: DualEncoder, batch: dict[str, Any]) -> None:
    torch.manual_seed(5)
    other = DualEncoder(tiny_model_config()).eval()
    other.load_saved_state_dict(model.saved_state_dict())
    with torch.no_grad():
        assert torch.allclose(other.encode_video(batch), model.encode_video(batch))
    with pytest.raises(ValueError, match="missing"):
        other.load_saved_state_dict({k: v for k, v in model.saved_state_dict().items() if "camera" not in k})


def test_embedding_prefixes_name_exactly_the_parameters_behind_e(batch: dict[str, Any]) -> None:
    from encoders.bev import BevTower

    torch.manual_seed(0)
    model = DualEncoder(tiny_model_config()).eval()
    model.bev_embedding(batch).square().mean().backward()
    for name, p in model.bev.named_parameters():
        behind_e = name.startswith(BevTower.EMBEDDING_PREFIXES)
        assert behind_e == (p.grad is not None), name


def views_model_and_batch(has_camera: list[bool]) -> tuple[DualEncoder, dict[str, Any]]:
    """A seeded tiny model in eval mode and 4 synthetic clips whose camera flags are ``has_camera``."""
    torch.manual_seed(0)
    model = DualEncoder(tiny_model_config()).eval()
    ds = SyntheticClipDataset(4, spec=SPEC, seed=3)
    batch = collate_clips([ds[i] for i in range(4)])
    batch["has_camera"] = torch.tensor(has_camera)
    return model, batch


def test_encode_views_equals_encode_video_per_view() -> None:
    model, batch = views_model_and_batch([True, False, True, True])  # fusion must mask per clip
    with torch.no_grad():
        views = model.encode_views(batch)
        for view in ("camera", "bev", "fused"):
            torch.testing.assert_close(views[view], model.encode_video(batch, view=view), rtol=1e-5, atol=1e-5)


def test_encode_views_detach_camera_keeps_the_values_and_cuts_the_fused_gradient() -> None:
    model, batch = views_model_and_batch([True] * 4)
    attached, detached = model.encode_views(batch), model.encode_views(batch, detach_camera=True)
    for view in ("camera", "bev", "fused"):
        torch.testing.assert_close(attached[view], detached[view], rtol=0, atol=0)
    detached["fused"].sum().backward()
    assert all(p.grad is None for p in model.camera.parameters())  # the fused view does not train the camera
    assert any(p.grad is not None for p in model.bev.parameters())
    detached["camera"].sum().backward()
    assert any(p.grad is not None for p in model.camera.parameters())  # its own view does


def test_encode_views_can_skip_the_camera_tower_when_no_clip_has_camera() -> None:
    model, batch = views_model_and_batch([False] * 4)
    calls: list[int] = []
    model.camera.register_forward_hook(lambda *_: calls.append(1))
    with torch.no_grad():
        views = model.encode_views(batch, camera_always=False)
        assert not calls and float(views["camera"].abs().sum()) == 0.0
        torch.testing.assert_close(views["fused"], model.encode_video(batch), rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(views["bev"], model.encode_video(batch, view="bev"), rtol=1e-5, atol=1e-5)
        batch["has_camera"] = torch.tensor([False, True, False, False])  # one clip with camera: the tower runs
        model.encode_views(batch, camera_always=False)
        assert calls


@pytest.mark.parametrize("object_crop", [False, True])
@pytest.mark.parametrize("as_bytes", [False, True])
def test_clips_with_blank_camera_frames_share_one_frame_of_the_cnn_in_eval_mode(
        batch: dict[str, Any], object_crop: bool, as_bytes: bool) -> None:
    from encoders.camera import _frames, _pool, unit_pixels

    config = tiny_model_config()
    torch.manual_seed(0)
    model = DualEncoder(replace(config, camera=replace(config.camera, object_crop=object_crop))).eval()
    blanked = _with_crops(batch) if object_crop else dict(batch)
    for key in ("camera", "camera_crop", "camera_box"):
        if key in blanked:  # clips 1 and 3 as a clip the camera never saw: every frame zero; clip 0 is seen
            blanked[key] = blanked[key].clone()
            blanked[key][[1, 3]] = 0.0
            if as_bytes and key != "camera_box":  # as ClipDataset(as_uint8=True) gives them
                blanked[key] = (blanked[key] * 255).round().to(torch.uint8)
    b, t = blanked["camera"].shape[:2]
    frames_run: list[int] = []
    model.camera.cnn.register_forward_hook(lambda _m, args, _out: frames_run.append(int(args[0].shape[0])))
    with torch.no_grad():
        shared = model.camera._pooled(model.camera.cnn, blanked["camera"])
        alone = _pool(model.camera.cnn, unit_pixels(_frames(blanked["camera"]))).reshape(b, t, -1)  # every frame
        torch.testing.assert_close(shared, alone, rtol=1e-5, atol=1e-5)
        assert frames_run == [2 * t + 1, b * t]  # the seen clips' frames and one zero frame
        views = model.encode_views(blanked)
        for i in range(b):  # each clip's vectors as when embedded alone
            one = {k: v[i:i + 1] if isinstance(v, torch.Tensor) else v for k, v in blanked.items()}
            for view, x in model.encode_views(one).items():
                torch.testing.assert_close(views[view][i:i + 1], x, rtol=1e-5, atol=1e-5)
    model.train()  # in training batch norm reads the batch: every frame runs
    frames_run.clear()
    model.camera._pooled(model.camera.cnn, blanked["camera"])
    assert frames_run == [b * t]


def test_uint8_batches_are_converted_on_the_device(model: DualEncoder, batch: dict[str, Any]) -> None:
    # Quantise the float views to bytes, as `ClipDataset(as_uint8=True)` delivers them.
    as_bytes = dict(batch)
    quantised = dict(batch)
    for key in ("camera", "bev_lidar", "bev_map", "bev_object"):
        as_bytes[key] = (batch[key] * 255).round().to(torch.uint8)
        quantised[key] = as_bytes[key].float() / 255.0
    with torch.no_grad():
        torch.testing.assert_close(model.encode_video(as_bytes), model.encode_video(quantised))
        torch.testing.assert_close(model.bev_embedding(as_bytes), model.bev_embedding(quantised))


def _receptive_rows(config: Any) -> int:
    """Input rows of the map raster that reach E's centre cell (by the gradient)."""
    from encoders.bev import BevTower

    torch.manual_seed(0)
    tower = BevTower(config, 16).eval()
    h, w = 256, 32
    gen = torch.Generator().manual_seed(0)
    bev_map = torch.rand(1, 1, config.map_channels, h, w, generator=gen).requires_grad_(True)
    e = tower.embed_map(torch.rand(1, 1, config.lidar_channels, h, w, generator=gen), bev_map)
    e[0, 0, :, e.shape[-2] // 2, e.shape[-1] // 2].sum().backward()
    assert bev_map.grad is not None
    return int((bev_map.grad.abs().sum(dim=(0, 1, 2, 4)) > 0).sum())


def test_context_and_extra_blocks_widen_the_receptive_field() -> None:
    import dataclasses

    from encoders.config import BevConfig

    base = BevConfig(widths=(4, 4, 4, 4), embed_channels=8)
    plain = _receptive_rows(base)
    deeper = _receptive_rows(dataclasses.replace(base, blocks_per_stage=2))
    context = _receptive_rows(dataclasses.replace(base, context_blocks=2))
    # Strided 3×3 convolutions at strides 2..16 see 31 rows (plus the header's 3×3 and upsampling).
    assert 31 <= plain < 64
    assert deeper > plain + 40  # +2 cells per stage: 2·(2+4+8+16) = 60 rows
    assert context > plain + 100  # two dilated blocks at stride 16: 2·2·2·16 = 128 rows


def test_one_block_per_stage_keeps_the_state_dict_layout() -> None:
    from encoders.bev import Backbone

    keys = set(Backbone(3, (4, 8)).state_dict())
    assert keys == {f"stages.{i}.{j}.{p}" for i in (0, 1) for j, params in ((0, ("weight",)), (1, (
        "weight", "bias", "running_mean", "running_var", "num_batches_tracked"))) for p in params}


def test_bev_tower_reads_the_object_track(model: DualEncoder, batch: dict[str, Any]) -> None:
    """The track stream moves the clip vector; without the track the tower says what is missing, and a
    tower configured without it needs none."""
    with torch.no_grad():
        base = model.encode_video(batch, view="bev")
        moved = dict(batch, object_track=batch["object_track"].flip(0))  # other clips' tracks
        assert not torch.allclose(base, model.encode_video(moved, view="bev"), atol=1e-4)
        with pytest.raises(KeyError, match="object_track"):
            model.encode_video({k: v for k, v in batch.items() if k != "object_track"}, view="bev")
    config = tiny_model_config()
    off = DualEncoder(replace(config, bev=replace(config.bev, track_features=0))).eval()
    assert not any(name.startswith("bev.track") for name, _ in off.named_parameters())
    with torch.no_grad():
        assert off.encode_video({k: v for k, v in batch.items() if k != "object_track"}, view="bev").shape == base.shape


def test_track_velocity_gives_the_track_stream_velocity_and_range_rates(batch: dict[str, Any]) -> None:
    from encoders.bev import VELOCITY_FEATURES, VELOCITY_SCALE_MPS

    config = tiny_model_config()
    model = DualEncoder(replace(config, bev=replace(config.bev, track_velocity=True, track_rates=False))).eval()
    track, ego, velocity = batch["object_track"], batch["ego_motion"], batch["object_velocity"]
    features = model.bev.track_features(track, ego, velocity)  # (B, T, 2 (F + 4) + E)
    f = track.shape[-1] + len(VELOCITY_FEATURES)
    assert features.shape[-1] == 2 * f + model.bev.config.ego_features
    v = velocity / VELOCITY_SCALE_MPS
    torch.testing.assert_close(features[..., f - 4 : f - 2], v)
    # Range rate along x: negative while the object closes in, whichever side it is on.
    torch.testing.assert_close(features[..., f - 2], torch.sign(track[..., 0]) * v[..., 0])
    with torch.no_grad():
        assert model.encode_video(batch, view="bev").shape == (track.shape[0], config.embed_dim)
        with pytest.raises(KeyError, match="object_velocity"):
            model.encode_video({k: x for k, x in batch.items() if k != "object_velocity"}, view="bev")


def test_track_rates_give_the_track_stream_the_objects_own_motion(batch: dict[str, Any]) -> None:
    from encoders.bev import RATES_SCALE

    config = tiny_model_config()
    assert config.bev.track_rates  # the default
    model = DualEncoder(config).eval()
    plain = DualEncoder(replace(config, bev=replace(config.bev, track_rates=False))).eval()
    track, ego = batch["object_track"], batch["ego_motion"]
    rates = torch.zeros(*track.shape[:2], 3)
    rates[..., 1] = -3.0  # braking at 3 m/s²
    features = model.bev.track_features(track, ego, object_rates=rates)  # (B, T, 2 (F + 3) + E)
    f = track.shape[-1] + len(RATES_SCALE)
    assert features.shape[-1] == 2 * f + config.bev.ego_features
    assert plain.bev.track_features(track, ego).shape[-1] == features.shape[-1] - 6
    torch.testing.assert_close(features[..., f - 2], torch.full(track.shape[:2], -3.0 / RATES_SCALE[1]))
    with torch.no_grad():
        moving = model.encode_video({**batch, "object_rates": rates}, view="bev")
        still = model.encode_video({**batch, "object_rates": torch.zeros_like(rates)}, view="bev")
        assert not torch.allclose(moving, still)
        with pytest.raises(KeyError, match="object_rates"):
            model.encode_video({k: x for k, x in batch.items() if k != "object_rates"}, view="bev")


def test_dense_heads_read_the_frame_tokens_of_each_stream(batch: dict[str, Any]) -> None:
    from encoders.dense import DENSE_TASKS

    config = replace(tiny_model_config(), dense_streams=("track", "camera", "bev"))
    assert config.dense_streams == ("camera", "bev", "track")  # one order, whatever was written
    model = DualEncoder(config).eval()
    frames: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        views = model.encode_views(batch, frames=frames)
        plain = model.encode_views(batch)
    for name in views:
        torch.testing.assert_close(views[name], plain[name])  # the tokens change nothing
    b, t = batch["bev_lidar"].shape[:2]
    logits = model.dense_logits(frames)
    assert sorted(logits) == ["bev", "camera", "track"]
    for x in logits.values():
        assert x.shape == (b, t, sum(len(c) for c in DENSE_TASKS.values()))
    with pytest.raises(ConfigError, match="dense_streams: unknown \\['lidar'\\]"):
        replace(tiny_model_config(), dense_streams=("lidar",))


def test_ego_rates_reach_the_bev_tower_and_older_models_read_the_pose_and_speed_only(batch: dict[str, Any]) -> None:
    """With ``ego_features`` 6 the temporal models read the ego's smoothed acceleration and yaw rate (scaled to
    about unit range); a model configured before them (4) reads the first four columns of the same batch."""
    from encoders.camera import EGO_MOTION_SCALE

    config = replace(tiny_model_config(), bev=replace(tiny_model_config().bev, track_rates=False))
    assert config.bev.ego_features == 6 == batch["ego_motion"].shape[-1] == len(EGO_MOTION_SCALE)
    new = DualEncoder(config).eval()
    old = DualEncoder(replace(config, bev=replace(config.bev, ego_features=4))).eval()
    track, ego = batch["object_track"], batch["ego_motion"].clone()
    ego[..., 4], ego[..., 5] = -2.0, 0.25  # braking at 2 m/s² through a left bend
    features = new.bev.track_features(track, ego)  # (B, T, 2 F + 6)
    torch.testing.assert_close(features[..., -2:], torch.tensor([-1.0, 0.5]).expand_as(features[..., -2:]))
    assert old.bev.track_features(track, ego).shape[-1] == features.shape[-1] - 2
    steady = {**batch, "ego_motion": ego * torch.tensor([1.0, 1, 1, 1, 0, 0])}
    with torch.no_grad():
        assert not torch.allclose(new.encode_video({**batch, "ego_motion": ego}, view="bev"),
                                  new.encode_video(steady, view="bev"))
        torch.testing.assert_close(old.encode_video({**batch, "ego_motion": ego}, view="bev"),
                                   old.encode_video(steady, view="bev"))


@pytest.mark.parametrize("kernel", [1, 3, 5])
@pytest.mark.parametrize("training", [True, False])
def test_bev_frame_features_pool_the_time_convolved_embedding(kernel: int, training: bool) -> None:
    """The tower pools S and convolves over time after; that equals pooling E = header_time(S) itself."""
    import torch.nn.functional as F

    from encoders.bev import BevTower
    from encoders.camera import masked_mean
    from encoders.config import BevConfig

    torch.manual_seed(0)
    config = BevConfig(widths=(4, 8), embed_channels=8, temporal_kernel=kernel, track_features=0)
    tower = BevTower(config, 16).train(training)
    with torch.no_grad():
        tower.header_time.weight.normal_()  # it starts as the identity
    b, t, h, w = 3, 6, 32, 16
    lidar, bev_map = torch.rand(b, t, config.lidar_channels, h, w), torch.rand(b, t, config.map_channels, h, w)
    obj = (torch.rand(b, t, 1, h, w) > 0.7).float()
    obj[0, 2] = 0.0  # a frame where the object is not seen: its masked mean is 0
    space = tower.embed_space(lidar, bev_map)
    e = tower.header_time(space).flatten(0, 1)  # (B*T, D_e, h', w')
    small = F.adaptive_avg_pool2d(obj.flatten(0, 1), e.shape[-2:])
    expected = torch.cat([masked_mean(e, small), e.mean(dim=(2, 3))], dim=-1).reshape(b, t, -1)
    got = tower.frame_features(space, obj, torch.rand(b, t, 6))[..., : expected.shape[-1]]
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    assert torch.equal(tower.embed_map(lidar, bev_map), tower.header_time(space))


def test_bev_tower_embeds_equal_frames_once_in_eval_mode(monkeypatch: pytest.MonkeyPatch) -> None:
    from encoders.bev import BevTower, distinct_frames
    from encoders.config import BevConfig

    torch.manual_seed(0)
    config = BevConfig(widths=(4, 8), embed_channels=8, track_features=0)
    tower = BevTower(config, 16).eval()
    lidar, bev_map = torch.rand(3, 4, config.lidar_channels, 16, 8), torch.rand(3, 4, config.map_channels, 16, 8)
    lidar[1, :3], bev_map[1, :3] = lidar[0, 1:], bev_map[0, 1:]  # two clips of a log, one frame apart
    lidar[2, 0] = lidar[0, 0]  # the same LiDAR over another map: another frame
    first, inverse = distinct_frames(lidar.flatten(0, 1), bev_map.flatten(0, 1))
    assert len(first) == 12 - 3 and inverse[4:7].tolist() == inverse[1:4].tolist()
    assert inverse[8] != inverse[0]
    off_by_one = lidar.flatten(0, 1).clone()
    off_by_one[1].view(-1)[5] += 1e-6  # one value of one frame: not the same frame
    assert len(distinct_frames(off_by_one, bev_map.flatten(0, 1))[0]) == 12 - 2
    ran: list[int] = []
    backbone = tower.lidar.forward
    monkeypatch.setattr(tower.lidar, "forward", lambda x: ran.append(len(x)) or backbone(x))
    with torch.no_grad():
        shared = tower.embed_space(lidar, bev_map)
        alone = torch.cat([tower.embed_space(lidar[i : i + 1], bev_map[i : i + 1]) for i in range(3)])
    assert ran == [9, 4, 4, 4]
    torch.testing.assert_close(shared, alone, atol=1e-6, rtol=1e-6)
    tower.train()  # batch norm reads the batch: every frame runs
    tower.embed_space(lidar, bev_map)
    assert ran[-1] == 12


def test_distinct_frames_on_bytes_match_floats_and_never_merge_different_frames() -> None:
    from encoders.bev import distinct_frames

    gen = torch.Generator().manual_seed(0)
    lidar = torch.randint(0, 256, (4, 5, 3, 8, 6), generator=gen, dtype=torch.uint8)
    bev_map = torch.randint(0, 256, (4, 5, 2, 8, 6), generator=gen, dtype=torch.uint8)
    lidar[1, :4], bev_map[1, :4] = lidar[0, 1:], bev_map[0, 1:]
    lidar[3], bev_map[3] = lidar[2], bev_map[2]
    as_bytes = distinct_frames(lidar.flatten(0, 1), bev_map.flatten(0, 1))
    as_floats = distinct_frames(lidar.flatten(0, 1).float() / 255, bev_map.flatten(0, 1).float() / 255)
    assert len(as_bytes[0]) == 20 - 4 - 5
    for a, b in zip(as_bytes, as_floats):
        assert torch.equal(a, b)
    # Rows whose byte count is not a whole number of 64-bit words are padded, not misread.
    odd = torch.randint(0, 256, (6, 3, 5), generator=gen, dtype=torch.uint8)
    odd[4] = odd[1]
    first, inverse = distinct_frames(odd)
    assert first.tolist() == [0, 1, 2, 3, 5] and inverse[4] == inverse[1]


def test_distinct_frames_keep_frames_whose_hash_collides_apart(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every frame hashing alike (a forced collision): only the frames equal in full are merged."""
    from encoders import bev

    frames = torch.tensor([[1, 2], [3, 4], [1, 2], [3, 4], [5, 6]], dtype=torch.uint8)
    monkeypatch.setattr(bev.torch, "randint", lambda *a, **k: torch.zeros(a[-1], dtype=torch.long))
    _, inverse = bev.distinct_frames(frames)
    # Frame 1 differs from its group's first (frame 0): it and its equal, frame 3, each stand alone.
    assert inverse[2] == inverse[0] and len(set(inverse.tolist())) == 4


def test_pool_frames_from_distinct_frames_equals_pooling_every_frame() -> None:
    from encoders.bev import pool_frames

    gen = torch.Generator().manual_seed(0)
    s = torch.randn(4, 6, 10, generator=gen)  # (U, C, P)
    inverse = torch.tensor([2, 0, 2, 3, 0, 0, 2])  # frame 1 of the 4 distinct ones is never used
    weights = torch.rand(7, 10, 3, generator=gen)  # (M, P, K)
    expected = torch.bmm(s[inverse], weights)
    torch.testing.assert_close(pool_frames(s, weights, inverse), expected)
    torch.testing.assert_close(pool_frames(s[inverse], weights), expected)


def test_bev_tower_reads_rasters_as_bytes_as_it_reads_them_as_floats() -> None:
    """Eval mode finds equal frames on the bytes and converts only those: the embedding is the same
    bit for bit as from float rasters, and so are the frame features from the distinct frames."""
    from encoders.bev import BevTower
    from encoders.camera import unit_pixels
    from encoders.config import BevConfig

    torch.manual_seed(0)
    config = BevConfig(widths=(4, 8), embed_channels=8, track_features=0)
    tower = BevTower(config, 16).eval()
    lidar = torch.randint(0, 256, (3, 4, config.lidar_channels, 16, 8), dtype=torch.uint8)
    bev_map = torch.randint(0, 256, (3, 4, config.map_channels, 16, 8), dtype=torch.uint8)
    lidar[1, :3], bev_map[1, :3] = lidar[0, 1:], bev_map[0, 1:]
    obj = (torch.rand(3, 4, 1, 16, 8) > 0.7).float()
    ego = torch.rand(3, 4, 6)
    with torch.no_grad():
        as_bytes = tower(lidar, bev_map, obj, ego)
        as_floats = tower(unit_pixels(lidar), unit_pixels(bev_map), obj, ego)
        space, inverse = tower.embed_distinct(lidar, bev_map)
        every_frame = tower.frame_features(tower.embed_space(lidar, bev_map), obj, ego)
    assert inverse is not None and len(space) == 12 - 3
    assert torch.equal(as_bytes, as_floats)
    torch.testing.assert_close(tower.frame_features(space, obj, ego, inverse), every_frame)


def test_camera_tower_reads_the_ego_motion_only_when_configured(batch: dict[str, Any]) -> None:
    """With ``camera.ego_features`` 6 the camera's frame vectors end in the ego's motion scaled to about unit
    range, and the camera view changes with it; the default camera (0) reads its pixels alone."""
    from encoders.camera import EGO_MOTION_SCALE

    torch.manual_seed(0)
    config = tiny_model_config()
    assert config.camera.ego_features == 0
    with_ego = DualEncoder(replace(config, camera=replace(config.camera, ego_features=6))).eval()
    pixels_only = DualEncoder(config).eval()
    ego = batch["ego_motion"].clone()
    ego[..., 3], ego[..., 4] = 10.0, -2.0  # 10 m/s, braking at 2 m/s²
    features = with_ego.camera.frame_features(batch["camera"], ego)  # (B, T, 2F + 8 + 6)
    assert features.shape[-1] == pixels_only.camera.frame_features(batch["camera"]).shape[-1] + 6
    torch.testing.assert_close(features[..., -6:], ego / torch.tensor(EGO_MOTION_SCALE))
    still = {**batch, "ego_motion": torch.zeros_like(ego)}
    with torch.no_grad():
        assert not torch.allclose(with_ego.encode_video({**batch, "ego_motion": ego}, view="camera"),
                                  with_ego.encode_video(still, view="camera"))
        torch.testing.assert_close(pixels_only.encode_video({**batch, "ego_motion": ego}, view="camera"),
                                   pixels_only.encode_video(still, view="camera"))
    with pytest.raises(ValueError, match="needs the clips' ego_motion"):
        with_ego.camera.frame_features(batch["camera"])
    with pytest.raises(ConfigError, match="CameraConfig.ego_features must be 0 to 6"):
        replace(config.camera, ego_features=7)


def test_mask_scale_reads_the_objects_size_on_a_log_scale(batch: dict[str, Any]) -> None:
    """One pixel and the whole image are 1/log(1 + H·W) and 1 apart from an empty mask's 0, and with
    ``camera.mask_scale`` the camera's frame vectors carry that scale and its change since the previous frame."""
    from encoders.camera import mask_scale

    mask = torch.zeros(3, 1, 4, 8)
    mask[1, 0, 0, 0] = 1.0
    mask[2] = 1.0
    torch.testing.assert_close(mask_scale(mask), torch.tensor([[0.0], [math.log(2) / math.log(33)], [1.0]]))
    config = tiny_model_config()
    scaled = DualEncoder(replace(config, camera=replace(config.camera, mask_scale=True))).eval()
    features = scaled.camera.frame_features(batch["camera"])  # (B, T, 2F + 8 + 2)
    b, t = batch["camera"].shape[:2]
    expected = mask_scale(batch["camera"][:, :, -1:].flatten(0, 1)).reshape(b, t)
    torch.testing.assert_close(features[..., -2], expected)
    torch.testing.assert_close(features[:, 1:, -1], (expected[:, 1:] - expected[:, :-1]) * t)


def _with_crops(batch: dict[str, Any], seed: int = 0) -> dict[str, Any]:
    """The batch with object crops (B, T, 4, Hc, Wc) and their box features (B, T, 4)."""
    g = torch.Generator().manual_seed(seed)
    b, t, _, h, w = batch["camera"].shape
    crop = torch.rand(b, t, 4, h, w, generator=g)
    crop[:, :, 3] = (crop[:, :, 3] > 0.7).float()
    return {**batch, "camera_crop": crop, "camera_box": torch.rand(b, t, 4, generator=g)}


def test_object_crops_reach_the_camera_view_and_a_model_without_them_ignores_them(
        model: DualEncoder, batch: dict[str, Any]) -> None:
    config = tiny_model_config()
    torch.manual_seed(0)
    crop_model = DualEncoder(replace(config, camera=replace(config.camera, object_crop=True))).eval()
    with torch.no_grad():
        one = crop_model.encode_video(_with_crops(batch, 0), view="camera")
        other = crop_model.encode_video(_with_crops(batch, 1), view="camera")
        assert one.shape == (4, 32) and not torch.allclose(one, other, atol=1e-4)
        views = crop_model.encode_views(_with_crops(batch, 0))
        torch.testing.assert_close(views["camera"], one)
        # The crop's own CNN and the box features widen the camera's frame vectors.
        cropped = _with_crops(batch)
        frames = crop_model.camera.frame_features(batch["camera"], batch["ego_motion"], cropped["camera_crop"],
                                                  cropped["camera_box"])
        plain = model.camera.frame_features(batch["camera"], batch["ego_motion"])
        assert frames.shape[-1] == plain.shape[-1] + 2 * config.camera.widths[-1] + 8
        torch.testing.assert_close(model.encode_video(_with_crops(batch), view="camera"),
                                   model.encode_video(batch, view="camera"))
    with pytest.raises(ValueError, match="object crops.*scenesearch clips"):
        crop_model.encode_video(batch, view="camera")


def test_pooling_shared_frames_keeps_the_products_dtype_under_autocast() -> None:
    from encoders.bev import pool_frames

    torch.manual_seed(0)
    s, weights = torch.randn(3, 4, 6), torch.rand(5, 6, 2)  # 3 distinct frames, 5 frames reading them
    inverse = torch.tensor([0, 2, 2, 1, 0])
    exact = pool_frames(s, weights, inverse)
    torch.testing.assert_close(exact, torch.bmm(s[inverse], weights))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        mixed = pool_frames(s, weights, inverse)
    assert mixed.dtype == torch.bfloat16
    torch.testing.assert_close(mixed.float(), exact, atol=0.05, rtol=0.02)
