"""Camera rendering: occlusion in the instance mask, projection consistency, near-plane clipping."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.geometry import SE3
from scenes.metadata import TimeOfDay, Weather
from scenes.sensorsim.appearance import Appearance
from scenes.sensorsim.camera import NEAR_PLANE_M, CameraRenderer, clip_near_plane
from scenes.sensorsim.config import CameraConfig
from scenes.sensorsim.objects import FrameObjects
from scenes.sensorsim.world import StaticWorld

CAMERA = CameraConfig(width_px=160, height_px=90, pitch_deg=0.0)


def _renderer(world: StaticWorld, n_tracks: int, appearance: Appearance | None = None,
              camera: CameraConfig = CAMERA) -> CameraRenderer:
    ids = [f"t{i}" for i in range(n_tracks)]
    return CameraRenderer(world, camera, appearance or Appearance(), ids, ["car"] * n_tracks)


def _project(camera: CameraConfig, point_ego: tuple[float, float, float]) -> tuple[int, int]:
    cam = camera.ego_SE3_sensor.inverse().transform_points(np.array([point_ego]))
    uv, ok = camera.intrinsics.project(cam)
    assert ok[0]
    return round(float(uv[0, 0])), round(float(uv[0, 1]))


def test_nearer_object_occludes_farther_one_in_the_mask(bare_world: StaticWorld) -> None:
    far = ("truck", (25.0, 0.0, 1.6), (8.0, 2.5, 3.2), 0.0)
    near = ("car", (12.0, 0.0, 0.75), (4.5, 1.9, 1.5), 0.0)
    renderer = _renderer(bare_world, 2)
    rng = np.random.default_rng(0)
    _, alone = renderer.render(FrameObjects.from_boxes([far]), SE3.identity(), rng)
    _, both = renderer.render(FrameObjects.from_boxes([far, near]), SE3.identity(), rng)
    u, v = _project(CAMERA, (25.0 - 4.0, 0.0, 0.75))  # the truck's rear face, at the car's height
    assert alone[v, u] == 1
    assert both[v, u] == 2, "the nearer car hides the truck"
    u_top, v_top = _project(CAMERA, (21.0, 0.0, 2.9))  # the truck's top shows above the car
    assert both[v_top, u_top] == 1
    assert (both == 1).sum() < (alone == 1).sum()


def test_box_centre_projects_inside_its_mask(bare_world: StaticWorld) -> None:
    boxes = [("car", (15.0, 4.0, 0.75), (4.5, 1.9, 1.5), 0.3), ("pedestrian", (9.0, -3.0, 0.9), (0.6, 0.6, 1.8), 0.0),
             ("cyclist", (20.0, -4.0, 0.85), (1.8, 0.7, 1.7), 1.2), ("bus", (40.0, 1.0, 1.6), (12.0, 2.6, 3.2), -0.2)]
    renderer = _renderer(bare_world, len(boxes))
    _, mask = renderer.render(FrameObjects.from_boxes(boxes), SE3.identity(), np.random.default_rng(0))
    for k, (_, center, _, _) in enumerate(boxes):
        u, v = _project(CAMERA, center)
        assert mask[v, u] == k + 1, f"box {k} centre lands on mask value {mask[v, u]}"


def test_mask_matches_box_silhouette(bare_world: StaticWorld) -> None:
    # A box seen straight from behind: its mask is the projected rear face, a rectangle.
    box = ("truck", (20.0, 0.0, 1.5), (4.0, 2.0, 3.0), 0.0)
    camera = CameraConfig(width_px=320, height_px=180, pitch_deg=0.0, mount_height_m=1.5)
    renderer = _renderer(bare_world, 1, camera=camera)
    _, mask = renderer.render(FrameObjects.from_boxes([box]), SE3.identity(), np.random.default_rng(0))
    u0, v0 = _project(camera, (18.0, 1.0, 3.0))
    u1, v1 = _project(camera, (18.0, -1.0, 0.0))
    expected = np.zeros_like(mask, dtype=bool)
    expected[v0:v1 + 1, u0:u1 + 1] = True
    got = mask == 1
    assert (got ^ expected).sum() <= 2 * ((u1 - u0) + (v1 - v0)) + 4  # at most a one-pixel border


def test_object_crossing_the_near_plane_is_clipped_not_mirrored(bare_world: StaticWorld) -> None:
    # A bus beside the ego reaching from behind the camera to ahead of it, on the left.
    bus = ("bus", (1.0, 3.0, 1.6), (14.0, 2.6, 3.2), 0.0)
    renderer = _renderer(bare_world, 1)
    _, mask = renderer.render(FrameObjects.from_boxes([bus]), SE3.identity(), np.random.default_rng(0))
    cols = np.flatnonzero((mask == 1).any(axis=0))
    assert cols.size > 0
    assert cols.min() == 0, "the bus runs out of the left edge of the image"
    assert cols.max() < CAMERA.width_px // 2, "nothing of the bus appears right of the centre"


def test_object_behind_the_camera_is_not_drawn(bare_world: StaticWorld) -> None:
    renderer = _renderer(bare_world, 1)
    _, mask = renderer.render(FrameObjects.from_boxes([("car", (-10.0, 0.0, 0.75), (4.5, 1.9, 1.5), 0.0)]),
                              SE3.identity(), np.random.default_rng(0))
    assert not mask.any()


def test_empty_frame_has_sky_above_and_ground_below(bare_world: StaticWorld) -> None:
    renderer = _renderer(bare_world, 0)
    image, mask = renderer.render(FrameObjects.from_boxes([]), SE3.identity(), np.random.default_rng(0))
    assert image.shape == (90, 160, 3) and image.dtype == np.uint8
    assert not mask.any()
    horizon = int(CAMERA.intrinsics.cy_px)  # level camera: the horizon is the middle row
    sky = image[: horizon - 10].reshape(-1, 3).mean(axis=0)
    ground = image[horizon + 10:].reshape(-1, 3).mean(axis=0)
    assert sky[0] > sky[2] + 20, "a clear day sky is blue"
    assert ground.mean() < sky.mean()


@pytest.mark.parametrize(("tod", "weather"), [("night", "clear"), ("dusk", "rain"), ("day", "fog")])
def test_appearance_changes_the_picture(bare_world: StaticWorld, tod: str, weather: str) -> None:
    boxes = FrameObjects.from_boxes([("car", (15.0, 0.0, 0.75), (4.5, 1.9, 1.5), 0.0)])
    day, day_mask = _renderer(bare_world, 1).render(boxes, SE3.identity(), np.random.default_rng(0))
    look = Appearance(TimeOfDay(tod), Weather(weather))
    other, other_mask = _renderer(bare_world, 1, look).render(boxes, SE3.identity(), np.random.default_rng(0))
    assert np.array_equal(day_mask, other_mask), "appearance never changes the geometry"
    if tod == "night":
        assert other.mean() < 0.5 * day.mean()
    if weather == "fog":
        assert other.std() < day.std()
    assert np.abs(other.astype(float) - day.astype(float)).mean() > 10


def test_vehicle_colours_come_from_the_metadata(bare_world: StaticWorld) -> None:
    look = Appearance.from_metadata({"vehicle_colors": {"t0": [255, 0, 0]}})
    renderer = _renderer(bare_world, 1, look)
    image, mask = renderer.render(FrameObjects.from_boxes([("car", (12.0, 0.0, 0.75), (4.5, 1.9, 1.5), 0.0)]),
                                  SE3.identity(), np.random.default_rng(0))
    body = image[mask == 1].astype(float).mean(axis=0)
    assert body[2] > body[0] + 40 and body[2] > body[1] + 40  # red in BGR


def test_bad_appearance_names_the_field() -> None:
    with pytest.raises(ValueError, match="appearance.weather"):
        Appearance.from_metadata({"weather": "snow"})
    with pytest.raises(ValueError, match="vehicle_colors.t1"):
        Appearance.from_metadata({"vehicle_colors": {"t1": [1, 2]}})


def test_clip_near_plane() -> None:
    square = np.array([[-1.0, -1.0, -1.0], [1.0, -1.0, -1.0], [1.0, 1.0, 3.0], [-1.0, 1.0, 3.0]])
    clipped = clip_near_plane(square)
    assert np.all(clipped[:, 2] >= NEAR_PLANE_M - 1e-12)
    # The plane z = near cuts the square where y = −1 + 2 (near + 1) / 4.
    y_cut = -1.0 + 2.0 * (NEAR_PLANE_M + 1.0) / 4.0
    assert np.isclose(clipped[:, 1].min(), y_cut)
    assert clipped.shape[0] == 4
    shift = np.array([0.0, 0.0, 10.0])
    assert clip_near_plane(square - shift).shape[0] == 0
    assert np.array_equal(clip_near_plane(square + shift), square + shift)


def test_mask_agrees_with_ray_casting(bare_world: StaticWorld) -> None:
    """The painter's-order mask equals a per-pixel ray cast of the same shapes (a z-buffer)."""
    import open3d as o3d

    from scenes.sensorsim.objects import build_object_mesh

    boxes = [("bus", (1.0, 3.2, 1.6), (14.0, 2.6, 3.2), 0.0), ("car", (12.0, 0.0, 0.75), (4.5, 1.9, 1.5), 0.1),
             ("truck", (24.0, 1.5, 1.6), (8.0, 2.5, 3.2), -0.2), ("pedestrian", (7.0, -2.5, 0.9), (0.6, 0.6, 1.8), 0.0),
             ("cyclist", (10.0, -3.2, 0.85), (1.8, 0.7, 1.7), 0.7)]
    objects = FrameObjects.from_boxes(boxes)
    camera = CameraConfig(width_px=320, height_px=180, pitch_deg=3.0)
    _, mask = _renderer(bare_world, len(boxes), camera=camera).render(objects, SE3.identity(), np.random.default_rng(0))
    mesh = build_object_mesh(objects)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles))
    h, w = mask.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pix = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3)
    ego_SE3_cam = camera.ego_SE3_sensor
    dirs = pix @ np.linalg.inv(camera.intrinsics.K).T @ ego_SE3_cam.rotation.T
    rays = np.concatenate([np.broadcast_to(ego_SE3_cam.translation, dirs.shape), dirs], axis=1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    prim = hit["primitive_ids"].numpy()
    truth = np.zeros(h * w, np.int64)
    ok = np.isfinite(hit["t_hit"].numpy())
    truth[ok] = mesh.owner[prim[ok].astype(np.int64)] + 1
    truth = truth.reshape(h, w)
    assert (truth == mask).mean() > 0.985
    for k in range(1, len(boxes) + 1):
        inter = ((truth == k) & (mask == k)).sum()
        union = ((truth == k) | (mask == k)).sum()
        assert union > 0 and inter / union > 0.9, f"object {k}: IoU {inter / union:.2f}"
