"""Properties of SE(3) poses, quaternions, yaw wrapping and pose interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scenes.geometry import (
    SE3,
    batch_matrices,
    interpolate_poses,
    invert_matrices,
    point_polyline_distance,
    points_in_polygon,
    quat_to_rotmat,
    quat_to_yaw,
    rotmat_to_quat,
    slerp_quat,
    wrap_angle_rad,
    yaw_to_quat,
    yaw_to_rotmat,
)

PROPS = settings(max_examples=60, deadline=None, derandomize=True)

coord = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
unit = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
quats = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1).map(
    lambda q: np.asarray(q) / np.linalg.norm(q)
)
translations = st.tuples(coord, coord, coord).map(np.asarray)
poses = st.builds(SE3.from_quat, quats, translations)
points = st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=8).map(np.asarray)
angles = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False)


def _same_pose(a: SE3, b: SE3, atol: float = 1e-8) -> bool:
    return bool(np.allclose(a.matrix, b.matrix, atol=atol))


@PROPS
@given(poses, poses, poses)
def test_compose_is_associative(a: SE3, b: SE3, c: SE3) -> None:
    assert _same_pose(a.compose(b).compose(c), a.compose(b.compose(c)), atol=1e-7)


@PROPS
@given(poses)
def test_inverse_composed_with_self_is_identity(a: SE3) -> None:
    assert _same_pose(a.inverse().compose(a), SE3.identity())
    assert _same_pose(a.compose(a.inverse()), SE3.identity())
    assert _same_pose(a.inverse().inverse(), a)


@PROPS
@given(poses, poses, points)
def test_transform_points_matches_composition_and_matrix(a: SE3, b: SE3, pts: np.ndarray) -> None:
    composed = a.compose(b).transform_points(pts)
    chained = a.transform_points(b.transform_points(pts))
    np.testing.assert_allclose(composed, chained, atol=1e-7)
    homogeneous = (a.matrix @ np.c_[pts, np.ones(len(pts))].T).T[:, :3]
    np.testing.assert_allclose(a.transform_points(pts), homogeneous, atol=1e-9)
    np.testing.assert_allclose(a.inverse().transform_points(a.transform_points(pts)), pts, atol=1e-7)


@PROPS
@given(quats)
def test_quat_rotmat_round_trip(q: np.ndarray) -> None:
    rot = quat_to_rotmat(q)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    back = rotmat_to_quat(rot)
    assert back[0] >= 0.0
    # q and −q are the same rotation.
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


@PROPS
@given(angles)
def test_wrap_angle_range_and_equivalence(angle: float) -> None:
    wrapped = float(wrap_angle_rad(angle))
    assert -np.pi < wrapped <= np.pi
    turns = (angle - wrapped) / (2.0 * np.pi)
    assert turns == pytest.approx(round(turns), abs=1e-9)


def test_wrap_angle_maps_minus_pi_to_pi() -> None:
    np.testing.assert_allclose(wrap_angle_rad(np.array([-np.pi, np.pi, 3 * np.pi, 0.0])), [np.pi, np.pi, np.pi, 0.0])


@PROPS
@given(st.floats(-np.pi + 1e-6, np.pi, allow_nan=False))
def test_yaw_quat_and_rotmat_agree(yaw: float) -> None:
    q = yaw_to_quat(yaw)
    assert float(quat_to_yaw(q)) == pytest.approx(yaw, abs=1e-9)
    np.testing.assert_allclose(quat_to_rotmat(q), yaw_to_rotmat(yaw), atol=1e-12)
    pose = SE3.from_yaw(yaw, np.zeros(3))
    assert pose.yaw_rad == pytest.approx(yaw, abs=1e-9)
    # Yaw grows from +x toward +y.
    if 0.1 < yaw < np.pi - 0.1:
        assert pose.transform_points(np.array([[1.0, 0.0, 0.0]]))[0, 1] > 0


@PROPS
@given(quats, quats)
def test_slerp_endpoints_and_midpoint(q0: np.ndarray, q1: np.ndarray) -> None:
    out = slerp_quat(np.stack([q0, q0, q0]), np.stack([q1, q1, q1]), np.array([0.0, 1.0, 0.5]))
    assert min(np.abs(out[0] - q0).max(), np.abs(out[0] + q0).max()) < 1e-9
    assert min(np.abs(out[1] - q1).max(), np.abs(out[1] + q1).max()) < 1e-9

    def angle(a: np.ndarray, b: np.ndarray) -> float:
        return float(2.0 * np.arccos(np.clip(abs(np.dot(a, b)), 0.0, 1.0)))

    total = angle(q0, q1)
    assert angle(q0, out[2]) == pytest.approx(total / 2.0, abs=1e-6)
    assert angle(out[2], q1) == pytest.approx(total / 2.0, abs=1e-6)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)


def test_interpolate_poses_midpoint_and_clamping() -> None:
    ts = np.array([0, 1_000_000_000], dtype=np.int64)
    quat = yaw_to_quat(np.array([0.0, np.pi / 2]))
    trans = np.array([[0.0, 0.0, 0.0], [10.0, 2.0, 0.0]])
    q, t = interpolate_poses(ts, quat, trans, np.array([-5, 500_000_000, 2_000_000_000]))
    np.testing.assert_allclose(t, [[0.0, 0.0, 0.0], [5.0, 1.0, 0.0], [10.0, 2.0, 0.0]])
    np.testing.assert_allclose(quat_to_yaw(q), [0.0, np.pi / 4, np.pi / 2], atol=1e-12)


def test_batch_and_inverse_matrices_agree_with_se3() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 4))
    rot = quat_to_rotmat(q)
    trans = rng.normal(size=(5, 3)) * 10
    mats = batch_matrices(rot, trans)
    inv = invert_matrices(mats)
    for i in range(5):
        np.testing.assert_allclose(inv[i], SE3(rot[i], trans[i]).inverse().matrix, atol=1e-12)
        np.testing.assert_allclose(mats[i] @ inv[i], np.eye(4), atol=1e-12)


def test_se3_is_immutable_and_copies_its_input() -> None:
    rot = np.eye(3)
    pose = SE3(rot, np.zeros(3))
    rot[0, 0] = 5.0
    assert pose.rotation[0, 0] == 1.0
    with pytest.raises(ValueError):
        pose.rotation[0, 0] = 2.0
    with pytest.raises(ValueError, match="shape"):
        SE3(np.eye(2), np.zeros(3))


def test_points_in_polygon_follows_the_even_odd_rule() -> None:
    concave = np.asarray([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [2.0, 1.0], [0.0, 4.0]])  # a notch from the top
    points = np.asarray([[1.0, 0.5], [2.0, 3.0], [3.5, 3.0], [5.0, 1.0], [np.nan, 1.0], [-0.1, 2.0]])
    assert points_in_polygon(points, concave).tolist() == [True, False, True, False, False, False]
    grid = np.stack(np.meshgrid(np.linspace(-1, 5, 7), np.linspace(-1, 5, 7)), axis=-1)  # (7, 7, 2)
    assert points_in_polygon(grid, concave).shape == (7, 7)


def test_point_polyline_distance() -> None:
    polyline = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    points = np.array([[5.0, 2.0], [12.0, 5.0], [-3.0, -4.0], [11.0, 11.0]])
    np.testing.assert_allclose(point_polyline_distance(points, polyline), [2.0, 2.0, 5.0, np.sqrt(2.0)])
