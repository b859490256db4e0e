"""Rigid-body geometry: SE(3) poses, quaternions, yaw, and pose interpolation.

Frames follow av2-api. Every pose is named ``target_SE3_source``: it maps points expressed in
``source`` into ``target`` (``city_SE3_ego`` takes ego-frame points into the city frame). Poses
compose right to left::

    city_SE3_object = city_SE3_ego.compose(ego_SE3_object)

The ego frame (and every object frame) is right-handed, metres::

            x (forward)
            ^
            |   yaw grows counter-clockwise, toward +y
            |  /
    y <-----+        z points up, out of the page
    (left)

Yaw is the rotation about +z, 0 along +x, growing toward +y, in radians wrapped to (−π, π].
Quaternions are scalar-first ``(qw, qx, qy, qz)`` as in the AV2 files.

Transforms return new objects; they never change their input.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def wrap_angle_rad(angle_rad: NDArray[np.floating] | float) -> NDArray[np.float64]:
    """Wrap angles to (−π, π].

    Args:
        angle_rad: (...) angles in radians.

    Returns:
        (...) the same angles in (−π, π].
    """
    a = np.asarray(angle_rad, dtype=np.float64)
    wrapped = np.mod(a + np.pi, 2.0 * np.pi) - np.pi  # in [−π, π)
    # Map −π to +π so that the interval is (−π, π].
    return np.where(wrapped <= -np.pi, wrapped + 2.0 * np.pi, wrapped)


def quat_to_rotmat(quat_wxyz: NDArray[np.floating]) -> FloatArray:
    """Convert unit quaternions to rotation matrices.

    Args:
        quat_wxyz: (..., 4) scalar-first quaternions; they are normalised first.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    q = np.asarray(quat_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rot = np.empty((*q.shape[:-1], 3, 3), dtype=np.float64)
    rot[..., 0, 0] = 1 - 2 * (y * y + z * z)
    rot[..., 0, 1] = 2 * (x * y - z * w)
    rot[..., 0, 2] = 2 * (x * z + y * w)
    rot[..., 1, 0] = 2 * (x * y + z * w)
    rot[..., 1, 1] = 1 - 2 * (x * x + z * z)
    rot[..., 1, 2] = 2 * (y * z - x * w)
    rot[..., 2, 0] = 2 * (x * z - y * w)
    rot[..., 2, 1] = 2 * (y * z + x * w)
    rot[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return rot


def rotmat_to_quat(rotation: NDArray[np.floating]) -> FloatArray:
    """Convert rotation matrices to unit quaternions with a non-negative scalar part.

    Args:
        rotation: (..., 3, 3) rotation matrices.

    Returns:
        (..., 4) scalar-first quaternions ``(qw, qx, qy, qz)``, ``qw >= 0``.
    """
    r = np.asarray(rotation, dtype=np.float64)
    batch = r.shape[:-2]
    r = r.reshape(-1, 3, 3)
    n = r.shape[0]
    q = np.empty((n, 4), dtype=np.float64)
    trace = r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]
    # Shepperd's method: pick the numerically largest of w, x, y, z to divide by.
    cand = np.stack([trace, r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]], axis=1)
    best = np.argmax(cand, axis=1)
    for case in range(4):
        m = best == case
        if not np.any(m):
            continue
        rr = r[m]
        if case == 0:
            s = np.sqrt(1.0 + trace[m]) * 2.0
            q[m, 0] = 0.25 * s
            q[m, 1] = (rr[:, 2, 1] - rr[:, 1, 2]) / s
            q[m, 2] = (rr[:, 0, 2] - rr[:, 2, 0]) / s
            q[m, 3] = (rr[:, 1, 0] - rr[:, 0, 1]) / s
        elif case == 1:
            s = np.sqrt(1.0 + rr[:, 0, 0] - rr[:, 1, 1] - rr[:, 2, 2]) * 2.0
            q[m, 0] = (rr[:, 2, 1] - rr[:, 1, 2]) / s
            q[m, 1] = 0.25 * s
            q[m, 2] = (rr[:, 0, 1] + rr[:, 1, 0]) / s
            q[m, 3] = (rr[:, 0, 2] + rr[:, 2, 0]) / s
        elif case == 2:
            s = np.sqrt(1.0 + rr[:, 1, 1] - rr[:, 0, 0] - rr[:, 2, 2]) * 2.0
            q[m, 0] = (rr[:, 0, 2] - rr[:, 2, 0]) / s
            q[m, 1] = (rr[:, 0, 1] + rr[:, 1, 0]) / s
            q[m, 2] = 0.25 * s
            q[m, 3] = (rr[:, 1, 2] + rr[:, 2, 1]) / s
        else:
            s = np.sqrt(1.0 + rr[:, 2, 2] - rr[:, 0, 0] - rr[:, 1, 1]) * 2.0
            q[m, 0] = (rr[:, 1, 0] - rr[:, 0, 1]) / s
            q[m, 1] = (rr[:, 0, 2] + rr[:, 2, 0]) / s
            q[m, 2] = (rr[:, 1, 2] + rr[:, 2, 1]) / s
            q[m, 3] = 0.25 * s
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(*batch, 4)


def yaw_to_quat(yaw_rad: NDArray[np.floating] | float) -> FloatArray:
    """Quaternions of rotations about +z.

    Args:
        yaw_rad: (...) yaw angles in radians.

    Returns:
        (..., 4) scalar-first quaternions ``(cos(yaw/2), 0, 0, sin(yaw/2))``.
    """
    half = 0.5 * np.asarray(yaw_rad, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def quat_to_yaw(quat_wxyz: NDArray[np.floating]) -> FloatArray:
    """Yaw (rotation about +z) of quaternions, in (−π, π].

    Uses the heading of the rotated x axis, which is exact for upright boxes and the best
    planar heading for slightly tilted ones.

    Args:
        quat_wxyz: (..., 4) scalar-first quaternions.

    Returns:
        (...) yaw angles in radians.
    """
    rot = quat_to_rotmat(quat_wxyz)
    return wrap_angle_rad(np.arctan2(rot[..., 1, 0], rot[..., 0, 0]))


def yaw_to_rotmat(yaw_rad: NDArray[np.floating] | float) -> FloatArray:
    """Rotation matrices about +z.

    Args:
        yaw_rad: (...) yaw angles in radians.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros((*yaw.shape, 3, 3), dtype=np.float64)
    rot[..., 0, 0] = c
    rot[..., 0, 1] = -s
    rot[..., 1, 0] = s
    rot[..., 1, 1] = c
    rot[..., 2, 2] = 1.0
    return rot


@dataclass(frozen=True)
class SE3:
    """A rigid transform ``target_SE3_source``: ``p_target = rotation @ p_source + translation``.

    Attributes:
        rotation: (3, 3) rotation matrix.
        translation: (3,) translation in metres.
    """

    rotation: FloatArray
    translation: FloatArray

    def __post_init__(self) -> None:
        rotation = np.asarray(self.rotation, dtype=np.float64)
        translation = np.asarray(self.translation, dtype=np.float64).reshape(-1)
        if rotation.shape != (3, 3):
            raise ValueError(f"SE3 rotation must have shape (3, 3), got {rotation.shape}")
        if translation.shape != (3,):
            raise ValueError(f"SE3 translation must have shape (3,), got {translation.shape}")
        # Frozen dataclass: store read-only copies so that no caller can mutate a pose in place.
        rotation = rotation.copy()
        translation = translation.copy()
        rotation.setflags(write=False)
        translation.setflags(write=False)
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "translation", translation)

    @staticmethod
    def identity() -> SE3:
        return SE3(np.eye(3), np.zeros(3))

    @staticmethod
    def from_matrix(matrix: NDArray[np.floating]) -> SE3:
        """Build from a (4, 4) homogeneous matrix."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"expected a (4, 4) matrix, got {m.shape}")
        return SE3(m[:3, :3], m[:3, 3])

    @staticmethod
    def from_quat(quat_wxyz: NDArray[np.floating], translation: NDArray[np.floating]) -> SE3:
        """Build from a (4,) scalar-first quaternion and a (3,) translation."""
        return SE3(quat_to_rotmat(quat_wxyz), np.asarray(translation, dtype=np.float64))

    @staticmethod
    def from_yaw(yaw_rad: float, translation: NDArray[np.floating]) -> SE3:
        """Build a rotation about +z by ``yaw_rad`` followed by a (3,) translation."""
        return SE3(yaw_to_rotmat(yaw_rad), np.asarray(translation, dtype=np.float64))

    @property
    def matrix(self) -> FloatArray:
        """(4, 4) homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.translation
        return m

    @property
    def quat_wxyz(self) -> FloatArray:
        """(4,) scalar-first unit quaternion with ``qw >= 0``."""
        return rotmat_to_quat(self.rotation)

    @property
    def yaw_rad(self) -> float:
        """Heading of the rotated x axis about +z, in (−π, π]."""
        return float(wrap_angle_rad(np.arctan2(self.rotation[1, 0], self.rotation[0, 0])))

    def compose(self, right: SE3) -> SE3:
        """``self ∘ right``: with self = a_SE3_b and right = b_SE3_c, returns a_SE3_c."""
        return SE3(self.rotation @ right.rotation, self.rotation @ right.translation + self.translation)

    def inverse(self) -> SE3:
        """With self = a_SE3_b, returns b_SE3_a."""
        rot_t = self.rotation.T
        return SE3(rot_t, -rot_t @ self.translation)

    def transform_points(self, points_xyz: NDArray[np.floating]) -> FloatArray:
        """Map points from the source frame to the target frame.

        Args:
            points_xyz: (N, 3) points in the source frame.

        Returns:
            (N, 3) points in the target frame.
        """
        pts = np.asarray(points_xyz, dtype=np.float64)
        # A contiguous copy of Rᵀ: multiplying by the transposed view is much slower for large N
        # (docs/research/ingest-profile.md).
        return pts @ np.ascontiguousarray(self.rotation.T) + self.translation


def batch_matrices(rotation: NDArray[np.floating], translation: NDArray[np.floating]) -> FloatArray:
    """Stack rotations and translations into homogeneous matrices.

    Args:
        rotation: (T, 3, 3) rotations.
        translation: (T, 3) translations.

    Returns:
        (T, 4, 4) homogeneous matrices.
    """
    rot = np.asarray(rotation, dtype=np.float64)
    out = np.zeros((rot.shape[0], 4, 4), dtype=np.float64)
    out[:, :3, :3] = rot
    out[:, :3, 3] = translation
    out[:, 3, 3] = 1.0
    return out


def invert_matrices(matrices: NDArray[np.floating]) -> FloatArray:
    """Invert rigid homogeneous matrices.

    Args:
        matrices: (T, 4, 4) rigid transforms a_SE3_b.

    Returns:
        (T, 4, 4) the transforms b_SE3_a.
    """
    m = np.asarray(matrices, dtype=np.float64)
    rot_t = np.swapaxes(m[:, :3, :3], 1, 2)
    out = np.zeros_like(m)
    out[:, :3, :3] = rot_t
    out[:, :3, 3] = -np.einsum("tij,tj->ti", rot_t, m[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def slerp_quat(q0_wxyz: NDArray[np.floating], q1_wxyz: NDArray[np.floating], t: NDArray[np.floating]) -> FloatArray:
    """Spherical linear interpolation between unit quaternions, element-wise.

    Args:
        q0_wxyz: (N, 4) start quaternions.
        q1_wxyz: (N, 4) end quaternions.
        t: (N,) interpolation fractions in [0, 1].

    Returns:
        (N, 4) interpolated unit quaternions.
    """
    q0 = np.asarray(q0_wxyz, dtype=np.float64)
    q1 = np.asarray(q1_wxyz, dtype=np.float64)
    frac = np.asarray(t, dtype=np.float64)[:, None]
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    dot = np.sum(q0 * q1, axis=1, keepdims=True)
    # q and −q are the same rotation: take the short way round.
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-9
    safe_sin = np.where(near, 1.0, sin_theta)
    w0 = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * theta) / safe_sin)
    w1 = np.where(near, frac, np.sin(frac * theta) / safe_sin)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def interpolate_poses(
    source_timestamps_ns: NDArray[np.integer],
    quat_wxyz: NDArray[np.floating],
    translation_m: NDArray[np.floating],
    query_timestamps_ns: NDArray[np.integer],
) -> tuple[FloatArray, FloatArray]:
    """Interpolate a pose sequence at query times: SLERP for rotation, linear for translation.

    Queries outside the source range are clamped to the first/last pose (no extrapolation),
    which is what a log's sensor timestamps need at the ends of a pose stream.

    Args:
        source_timestamps_ns: (S,) strictly increasing timestamps of the known poses.
        quat_wxyz: (S, 4) rotations of the known poses.
        translation_m: (S, 3) translations of the known poses.
        query_timestamps_ns: (Q,) timestamps to interpolate at.

    Returns:
        (Q, 4) quaternions and (Q, 3) translations.
    """
    src = np.asarray(source_timestamps_ns, dtype=np.int64)
    qry = np.asarray(query_timestamps_ns, dtype=np.int64)
    quat = np.asarray(quat_wxyz, dtype=np.float64)
    trans = np.asarray(translation_m, dtype=np.float64)
    if src.shape[0] == 1:
        return np.repeat(quat, qry.shape[0], axis=0), np.repeat(trans, qry.shape[0], axis=0)
    idx = np.clip(np.searchsorted(src, qry, side="right") - 1, 0, src.shape[0] - 2)
    t0, t1 = src[idx], src[idx + 1]
    # Differences of int64 nanoseconds first, then float: keeps sub-microsecond precision.
    frac = np.clip((qry - t0).astype(np.float64) / (t1 - t0).astype(np.float64), 0.0, 1.0)
    out_q = slerp_quat(quat[idx], quat[idx + 1], frac)
    out_t = trans[idx] + frac[:, None] * (trans[idx + 1] - trans[idx])
    return out_q, out_t


def points_in_polygon(points_xy_m: NDArray[np.floating], polygon_xy_m: NDArray[np.floating]) -> NDArray[np.bool_]:
    """(...,) whether each of ``points_xy_m`` (..., 2) lies inside ``polygon_xy_m`` (M, ≥2; vertices in
    order, not closed): the even-odd rule, one pass over the M edges; NaN points are outside."""
    px, py = points_xy_m[..., 0], points_xy_m[..., 1]
    inside = np.zeros(px.shape, dtype=bool)
    ax, ay = polygon_xy_m[:, 0], polygon_xy_m[:, 1]
    bx, by = np.roll(ax, 1), np.roll(ay, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        for x0, y0, x1, y1 in zip(ax.tolist(), ay.tolist(), bx.tolist(), by.tolist()):
            if y0 == y1:
                continue
            straddles = (py < y0) != (py < y1)
            inside ^= straddles & (px < x0 + (py - y0) * (x1 - x0) / (y1 - y0))
    return inside


def point_polyline_distance(points_xy: FloatArray, polyline_xy: FloatArray) -> FloatArray:
    """(N,) distance from each point to a polyline.

    Args:
        points_xy: (N, 2) points.
        polyline_xy: (M, 2) polyline vertices, M ≥ 1.
    """
    if polyline_xy.shape[0] == 1:
        return np.asarray(np.linalg.norm(points_xy - polyline_xy[0], axis=1), dtype=np.float64)
    a, b = polyline_xy[:-1], polyline_xy[1:]  # (S, 2) each
    ab = b - a
    length2 = np.maximum((ab * ab).sum(axis=1), 1e-12)  # (S,)
    rel = points_xy[:, None, :] - a[None]  # (N, S, 2)
    t = np.clip((rel * ab[None]).sum(axis=2) / length2, 0.0, 1.0)  # (N, S)
    closest = a[None] + t[..., None] * ab[None]  # (N, S, 2)
    dist = np.linalg.norm(points_xy[:, None, :] - closest, axis=2)
    return np.asarray(dist.min(axis=1), dtype=np.float64)
