from dataclasses import replace

import numpy as np
import pytest

from scenes.sim.config import TrackerNoiseConfig
from scenes.sim.noise import apply_tracker_noise, jitter_boxes, occluded_mask
from scenes.tracks import Annotations, EgoTrajectory

NO_NOISE = TrackerNoiseConfig(center_std_m=0.0, yaw_std_rad=0.0, miss_probability=0.0, id_switch_rate_per_s=0.0,
                              max_range_m=1000.0, occlusion_fraction=1.0)


def _ego(num_frames: int) -> EgoTrajectory:
    ts = np.arange(num_frames, dtype=np.int64) * 100_000_000
    return EgoTrajectory.from_xy_yaw(ts, np.zeros((num_frames, 2)), np.zeros(num_frames))


def _cars(num_frames: int, centers_xy: list[tuple[float, float]]) -> Annotations:
    k = len(centers_xy)
    ts = np.repeat(np.arange(num_frames, dtype=np.int64) * 100_000_000, k)
    ids = np.tile([f"t{i}" for i in range(k)], num_frames)
    xy = np.tile(np.asarray(centers_xy, dtype=float), (num_frames, 1))
    center = np.c_[xy, np.full(len(ts), 0.75)]
    size = np.tile([4.6, 1.85, 1.5], (len(ts), 1))
    return Annotations.from_yaw(ts, ids, ["REGULAR_VEHICLE"] * len(ts), center, size, np.zeros(len(ts)))


def test_without_noise_nothing_changes() -> None:
    ann = _cars(5, [(10.0, 0.0), (0.0, 12.0), (-20.0, -5.0)])
    out = apply_tracker_noise(ann, _ego(5), NO_NOISE, np.random.default_rng(0))
    assert len(out) == len(ann)
    np.testing.assert_allclose(out.center_xyz_m, ann.sorted().center_xyz_m)
    assert set(out.track_id) == set(ann.track_id)


@pytest.mark.parametrize(
    ("num_frames", "far_xy", "changes"),
    [
        pytest.param(3, (90.0, 0.0), {"max_range_m": 50.0}, id="range-limit-drops-far-boxes"),
        pytest.param(4, (25.0, 0.0), {"occlusion_fraction": 0.8}, id="occlusion-applies-in-apply-tracker-noise"),
    ],
)
def test_only_the_near_box_is_kept(num_frames: int, far_xy: tuple[float, float], changes: dict[str, float]) -> None:
    ann = _cars(num_frames, [(10.0, 0.0), far_xy])
    out = apply_tracker_noise(ann, _ego(num_frames), replace(NO_NOISE, **changes), np.random.default_rng(0))
    assert set(out.track_id) == {"t0"}


def test_box_behind_a_nearer_box_is_occluded() -> None:
    # t1 is straight behind t0 and no wider: hidden. t2 is off to the side: visible.
    hidden = occluded_mask(np.array([[10.0, 0.0], [25.0, 0.0], [25.0, 15.0]]), np.array([[4.6, 1.85]] * 3),
                           np.zeros(3), fraction=0.8, rays=16)
    assert hidden.tolist() == [False, True, False]


def test_occlusion_works_across_the_rear_wraparound() -> None:
    # Behind the ego the bearings straddle ±π; the test must still see the overlap.
    hidden = occluded_mask(np.array([[-10.0, 0.1], [-30.0, -0.1]]), np.array([[4.6, 1.85]] * 2),
                           np.zeros(2), fraction=0.8, rays=16)
    assert hidden.tolist() == [False, True]


def test_misses_drop_about_the_given_share() -> None:
    ann = _cars(200, [(10.0, 0.0), (0.0, 12.0), (-20.0, -5.0), (5.0, -30.0)])
    config = replace(NO_NOISE, miss_probability=0.25)
    out = apply_tracker_noise(ann, _ego(200), config, np.random.default_rng(1))
    assert abs(len(out) / len(ann) - 0.75) < 0.05


def test_jitter_has_the_configured_spread() -> None:
    ann = _cars(500, [(10.0, 0.0), (0.0, 12.0)])
    config = replace(NO_NOISE, center_std_m=0.2, yaw_std_rad=0.05)
    out = apply_tracker_noise(ann, _ego(500), config, np.random.default_rng(2))
    err = out.center_xyz_m[:, :2] - ann.sorted().center_xyz_m[:, :2]
    assert abs(err.std() - 0.2) < 0.02
    assert abs(out.yaw_rad.std() - 0.05) < 0.01
    np.testing.assert_allclose(out.center_xyz_m[:, 2], 0.75)


def test_jitter_alone_keeps_every_box_and_id() -> None:
    # Far, hidden and pose-less boxes all stay: real labels scatter but are not dropped.
    ann = _cars(400, [(10.0, 0.0), (20.0, 0.0), (150.0, 3.0)])
    out = jitter_boxes(ann, TrackerNoiseConfig(center_std_m=0.15, yaw_std_rad=0.03), np.random.default_rng(4))
    assert len(out) == len(ann)
    np.testing.assert_array_equal(out.track_id, ann.sorted().track_id)
    np.testing.assert_array_equal(out.size_lwh_m, ann.sorted().size_lwh_m)
    err = out.center_xyz_m[:, :2] - ann.sorted().center_xyz_m[:, :2]
    assert abs(err.std() - 0.15) < 0.01 and abs(err.mean()) < 0.01
    assert abs(out.yaw_rad.std() - 0.03) < 0.005


def test_jitter_alone_is_seeded_and_leaves_its_input() -> None:
    ann = _cars(30, [(10.0, 0.0), (0.0, 12.0)])
    before = ann.center_xyz_m.copy()
    a = jitter_boxes(ann, TrackerNoiseConfig(), np.random.default_rng(5))
    b = jitter_boxes(ann, TrackerNoiseConfig(), np.random.default_rng(5))
    np.testing.assert_array_equal(a.center_xyz_m, b.center_xyz_m)
    np.testing.assert_array_equal(a.quat_wxyz, b.quat_wxyz)
    np.testing.assert_array_equal(ann.center_xyz_m, before)
    assert not np.array_equal(a.center_xyz_m, ann.sorted().center_xyz_m)


def test_id_switches_start_new_ids_and_keep_rows() -> None:
    ann = _cars(300, [(10.0, 0.0)])  # one 30 s track
    config = replace(NO_NOISE, id_switch_rate_per_s=0.5)
    out = apply_tracker_noise(ann, _ego(300), config, np.random.default_rng(3))
    assert len(out) == len(ann)
    ids = out.track_id
    assert len(set(ids)) > 3
    assert ids[0] == "t0"
    # Each id is one contiguous stretch of time: a switch never goes back to an old id.
    changes = np.count_nonzero(ids[1:] != ids[:-1])
    assert changes == len(set(ids)) - 1


def test_same_generator_state_same_output_and_input_untouched() -> None:
    ann = _cars(50, [(10.0, 0.0), (0.0, 12.0), (-20.0, -5.0)])
    before = ann.center_xyz_m.copy()
    config = TrackerNoiseConfig()
    a = apply_tracker_noise(ann, _ego(50), config, np.random.default_rng(9))
    b = apply_tracker_noise(ann, _ego(50), config, np.random.default_rng(9))
    np.testing.assert_array_equal(a.center_xyz_m, b.center_xyz_m)
    np.testing.assert_array_equal(a.track_id, b.track_id)
    np.testing.assert_array_equal(ann.center_xyz_m, before)


def test_frames_without_ego_pose_are_dropped() -> None:
    ann = _cars(10, [(10.0, 0.0)])
    out = apply_tracker_noise(ann, _ego(5), NO_NOISE, np.random.default_rng(0))
    assert len(out) == 5
