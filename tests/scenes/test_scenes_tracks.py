"""Ego trajectories, annotations, per-track and dense views of a synthetic scene with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.categories import EGO_VEHICLE_LABEL, Category
from scenes.tracks import Annotations, EgoTrajectory, dense_tracks, tracks_from_annotations

T0 = 1_600_000_000_000_000_000
STEP_NS = 100_000_000


def _scene() -> tuple[Annotations, EgoTrajectory]:
    """The ego drives along city +x at 10 m/s, poses at 20 Hz. A car is parked at city (50, 3)
    facing −x; a pedestrian walks along city +y from (30, −5) at 1 m/s but is seen only in the
    frames 5..14; an EGO_VEHICLE row sits at the origin of every frame."""
    pose_ts = T0 + np.arange(0, 41) * (STEP_NS // 2)
    pose_t_s = (pose_ts - T0) * 1e-9
    ego = EgoTrajectory.from_xy_yaw(pose_ts, np.c_[10.0 * pose_t_s, np.zeros_like(pose_t_s)], np.zeros(41))
    rows: dict[str, list] = {k: [] for k in ("ts", "id", "cat", "c", "lwh", "yaw")}
    for i in range(20):
        ts = T0 + i * STEP_NS
        ego_x = 10.0 * i * 0.1
        rows["ts"].append(ts)
        rows["id"].append("car")
        rows["cat"].append("REGULAR_VEHICLE")
        rows["c"].append([50.0 - ego_x, 3.0, 0.8])
        rows["lwh"].append([4.5, 1.9, 1.6])
        rows["yaw"].append(np.pi)
        rows["ts"].append(ts)
        rows["id"].append("ego")
        rows["cat"].append(EGO_VEHICLE_LABEL)
        rows["c"].append([0.0, 0.0, 0.8])
        rows["lwh"].append([4.8, 2.0, 1.6])
        rows["yaw"].append(0.0)
        if 5 <= i < 15:
            rows["ts"].append(ts)
            rows["id"].append("ped")
            rows["cat"].append("PEDESTRIAN")
            rows["c"].append([30.0 - ego_x, -5.0 + 1.0 * i * 0.1, 0.9])
            rows["lwh"].append([0.5, 0.5, 1.8])
            rows["yaw"].append(np.pi / 2)
    ann = Annotations.from_yaw(
        np.array(rows["ts"]), rows["id"], rows["cat"], np.array(rows["c"]), np.array(rows["lwh"]), np.array(rows["yaw"])
    )
    return ann, ego


def test_tracks_are_in_the_city_frame_and_exclude_the_ego() -> None:
    ann, ego = _scene()
    tracks = tracks_from_annotations(ann, ego)
    assert list(tracks) == ["car", "ped"]  # order of first appearance; the ego's own box is dropped
    car = tracks["car"]
    assert car.category is Category.CAR and car.raw_category == "REGULAR_VEHICLE"
    np.testing.assert_allclose(car.center_city_xyz_m[:, :2], np.tile([50.0, 3.0], (20, 1)), atol=1e-9)
    np.testing.assert_allclose(np.abs(car.yaw_city_rad), np.pi, atol=1e-9)
    ped = tracks["ped"]
    assert len(ped) == 10
    np.testing.assert_allclose(ped.center_city_xyz_m[:, 0], 30.0, atol=1e-9)
    np.testing.assert_allclose(np.diff(ped.center_city_xyz_m[:, 1]), 0.1, atol=1e-9)


def test_dense_tracks_agree_with_per_track_view() -> None:
    ann, ego = _scene()
    tracks = tracks_from_annotations(ann, ego)
    dense = dense_tracks(ann, ego)
    assert dense.valid.shape == (2, 20)
    assert dense.city_SE3_ego.shape == (20, 4, 4)
    for k, tid in enumerate(dense.track_ids):
        track = tracks[str(tid)]
        assert dense.categories[k] == track.category.value
        frames = np.searchsorted(dense.timestamps_ns, track.timestamps_ns)
        assert dense.valid[k].sum() == len(track)
        assert dense.valid[k, frames].all()
        np.testing.assert_allclose(dense.center_city_xyz_m[k, frames], track.center_city_xyz_m, atol=1e-9)
        np.testing.assert_allclose(dense.center_ego_xyz_m[k, frames], track.center_ego_xyz_m, atol=1e-12)
        np.testing.assert_allclose(dense.yaw_city_rad[k, frames], track.yaw_city_rad, atol=1e-12)
        assert np.isnan(dense.center_ego_xyz_m[k, ~dense.valid[k]]).all()


def test_city_frame_follows_ego_rotation() -> None:
    # Ego at city (10, 20) facing +y: an object 1 m ahead is at city (10, 21), heading adds up.
    ego = EgoTrajectory.from_xy_yaw(np.array([T0]), np.array([[10.0, 20.0]]), np.array([np.pi / 2]))
    ann = Annotations.from_yaw(np.array([T0]), ["a"], ["BUS"], np.array([[1.0, 0.0, 0.0]]),
                               np.array([[12.0, 2.5, 3.0]]), np.array([0.25]))
    track = tracks_from_annotations(ann, ego)["a"]
    np.testing.assert_allclose(track.center_city_xyz_m[0], [10.0, 21.0, 0.0], atol=1e-12)
    assert track.yaw_city_rad[0] == pytest.approx(np.pi / 2 + 0.25)
    assert track.category is Category.BUS


def test_ego_speed_and_interpolation() -> None:
    _, ego = _scene()
    np.testing.assert_allclose(ego.speed_mps(), 10.0, atol=1e-9)
    mid = ego.interpolate(np.array([T0 + STEP_NS // 4]))
    assert mid.translation_m[0, 0] == pytest.approx(0.25)


def test_unknown_labels_map_to_other_and_are_counted() -> None:
    ann = Annotations.from_yaw(
        np.array([T0, T0, T0 + STEP_NS]), ["a", "b", "a"], ["SPACESHIP", EGO_VEHICLE_LABEL, "SPACESHIP"],
        np.zeros((3, 3)), np.ones((3, 3)), np.zeros(3),
    )
    assert ann.unknown_labels() == {"SPACESHIP": 2}
    assert list(ann.public_category) == [Category.OTHER, Category.OTHER, Category.OTHER]
    assert len(ann.without_ego()) == 2


def test_annotations_reject_mismatched_shapes() -> None:
    with pytest.raises(ValueError, match="center_xyz_m"):
        Annotations.from_yaw(np.array([T0, T0]), ["a", "b"], ["BUS", "BUS"], np.zeros((3, 3)), np.ones((2, 3)),
                             np.zeros(2))
