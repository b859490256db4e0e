"""Metamorphic properties: mirroring swaps left/right, reversing time swaps approach/away."""

from __future__ import annotations

import numpy as np
import pytest

from captioning.config import CaptioningConfig, SmoothingConfig
from captioning.pipeline import caption_arrays
from captioning.tags import HOST_DIRECTIONS, HOST_MOTIONS, LANES, MOTIONS, NO_TAG
from scenes.geometry import batch_matrices, quat_to_rotmat, yaw_to_quat


def smooth_scene(seed: int, turning: bool, k: int = 16, t: int = 100) -> dict:
    rng = np.random.default_rng(seed)
    ts = (np.arange(t) * 100_000_000).astype(np.int64)
    yaw_rate = np.convolve(rng.normal(0, 1.2, t), np.ones(15) / 15, "same") if turning else np.zeros(t)
    yaw = np.cumsum(yaw_rate) * 0.1
    speed = np.clip(6 + np.cumsum(rng.normal(0, 0.4, t)), 0, None)
    xy = np.cumsum(np.stack([speed * np.cos(yaw), speed * np.sin(yaw)], 1) * 0.1, 0)
    poses = batch_matrices(quat_to_rotmat(yaw_to_quat(yaw)), np.c_[xy, np.zeros(t)])
    vel = np.cumsum(rng.normal(0, 0.5, (k, t, 2)), 1) * 0.1 + rng.normal(0, 6, (k, 1, 2))
    center = np.cumsum(vel * 0.1, 1) + rng.normal(0, 15, (k, 1, 2))
    heading = rng.uniform(-np.pi, np.pi, (k, 1)) + np.cumsum(rng.normal(0, 0.05, (k, t)), 1)
    valid = np.ones((k, t), bool)
    valid[:, 40:43] = rng.random((k, 3)) < 0.5  # some gaps
    return dict(
        log_id="m", timestamps_ns=ts, track_ids=np.array([f"t{i}" for i in range(k)]),
        categories=np.array(["car"] * k), valid=valid, center_ego_xy_m=center, yaw_ego_rad=heading,
        city_SE3_ego=poses,
    )


def names(codes: np.ndarray, vocab: list) -> np.ndarray:
    lookup = np.array([v.value for v in vocab] + [""], dtype=object)
    return lookup[np.where(codes == NO_TAG, len(vocab), codes)]


SWAP = {"left": "right", "right": "left", "left_lateral": "right_lateral", "right_lateral": "left_lateral",
        "steering_left": "steering_right", "steering_right": "steering_left",
        "approach": "away", "away": "approach", "accelerating": "decelerating", "decelerating": "accelerating"}


def swapped(values: np.ndarray, keys: set[str]) -> np.ndarray:
    return np.vectorize(lambda v: SWAP[v] if v in keys else v, otypes=[object])(values)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mirroring_swaps_left_and_right(seed: int) -> None:
    config = CaptioningConfig()
    data = smooth_scene(seed, turning=True)
    mirror = np.diag([1.0, -1.0, 1.0, 1.0])
    mirrored = dict(data)
    mirrored["city_SE3_ego"] = mirror @ data["city_SE3_ego"] @ mirror
    mirrored["center_ego_xy_m"] = data["center_ego_xy_m"] * np.array([1.0, -1.0])
    mirrored["yaw_ego_rad"] = -data["yaw_ego_rad"]
    a = caption_arrays(config=config, **data)  # type: ignore[arg-type]
    b = caption_arrays(config=config, **mirrored)  # type: ignore[arg-type]
    lr = {"left", "right", "left_lateral", "right_lateral", "steering_left", "steering_right"}
    assert (names(b.neighbors.lane, LANES) == swapped(names(a.neighbors.lane, LANES), lr)).all()
    assert (names(b.neighbors.motion, MOTIONS) == names(a.neighbors.motion, MOTIONS)).all()
    assert (names(b.host_direction, HOST_DIRECTIONS) == swapped(names(a.host_direction, HOST_DIRECTIONS), lr)).all()
    assert (b.host_motion == a.host_motion).all()
    # Not vacuous: both sides and both steering directions occur.
    lanes = set(names(a.neighbors.lane, LANES).ravel())
    assert {"left", "right"} <= lanes
    assert {"steering_left", "steering_right"} <= set(names(a.host_direction, HOST_DIRECTIONS))


def reverse(data: dict) -> dict:
    out = dict(data)
    ts = data["timestamps_ns"]
    out["timestamps_ns"] = (ts[0] + ts[-1] - ts)[::-1].copy()
    out["city_SE3_ego"] = data["city_SE3_ego"][::-1].copy()
    for key in ("valid", "center_ego_xy_m", "yaw_ego_rad"):
        out[key] = data[key][:, ::-1].copy()
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reversing_time_swaps_approach_away_and_accelerating_decelerating(seed: int) -> None:
    # Flicker suppression fills a short run from the run before it, which is not time-symmetric: off here.
    config = CaptioningConfig(smoothing=SmoothingConfig(min_run_s=0.0))
    data = smooth_scene(seed, turning=False)  # a straight ego keeps the first-frame axes of eq. 3 aligned
    a = caption_arrays(config=config, **data)  # type: ignore[arg-type]
    b = caption_arrays(config=config, **reverse(data))  # type: ignore[arg-type]
    keys = {"approach", "away", "accelerating", "decelerating"}
    assert (names(b.neighbors.motion, MOTIONS)[:, ::-1] == swapped(names(a.neighbors.motion, MOTIONS), keys)).all()
    assert (names(b.neighbors.lane, LANES)[:, ::-1] == names(a.neighbors.lane, LANES)).all()
    assert (names(b.host_motion, HOST_MOTIONS)[::-1] == swapped(names(a.host_motion, HOST_MOTIONS), keys)).all()
    motions = set(names(a.neighbors.motion, MOTIONS).ravel())
    assert {"approach", "away"} <= motions
    assert {"accelerating", "decelerating"} <= set(names(a.host_motion, HOST_MOTIONS))


def test_reversing_time_swaps_steering(make_scene) -> None:  # type: ignore[no-untyped-def]
    config = CaptioningConfig(smoothing=SmoothingConfig(min_run_s=0.0))
    rate = np.r_[np.full(30, 0.35), np.full(30, -0.35)]
    data = make_scene(8.0, rate).arrays()
    a = caption_arrays(config=config, **data)
    b = caption_arrays(config=config, **reverse(data))
    keys = {"steering_left", "steering_right"}
    forward = names(a.host_direction, HOST_DIRECTIONS)
    assert (names(b.host_direction, HOST_DIRECTIONS)[::-1] == swapped(forward, keys)).all()
    assert names(a.host_direction, HOST_DIRECTIONS)[10] == "steering_left"
