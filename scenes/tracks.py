"""Ego trajectories and object tracks.

Two views of the same annotations:

- :class:`Annotations` is the file's table, one row per (timestamp, track), boxes in the ego
  frame at that timestamp (``ego_SE3_object``), exactly as ``annotations.feather`` stores them.
- :class:`ObjectTrack` is one track over time, in the ego frame and in the city frame.
- :class:`DenseTracks` packs all tracks onto the log's frame grid as ``(K tracks, T frames)``
  arrays with a validity mask, the layout vectorised stages (captioning, clips, tagging) use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scenes.categories import EGO_VEHICLE_LABEL, Category, category_from_label
from scenes.geometry import (
    SE3,
    FloatArray,
    batch_matrices,
    interpolate_poses,
    quat_to_rotmat,
    quat_to_yaw,
    wrap_angle_rad,
    yaw_to_quat,
)

IntArray = NDArray[np.int64]
StrArray = NDArray[np.str_]


def _readonly(array: NDArray[np.generic]) -> NDArray[np.generic]:
    out = np.array(array, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class EgoTrajectory:
    """Poses ``city_SE3_ego`` over time.

    Attributes:
        timestamps_ns: (T,) strictly increasing timestamps.
        quat_wxyz: (T, 4) rotations ego → city, scalar first.
        translation_m: (T, 3) ego origin in the city frame.
    """

    timestamps_ns: IntArray
    quat_wxyz: FloatArray
    translation_m: FloatArray

    def __post_init__(self) -> None:
        ts = np.asarray(self.timestamps_ns, dtype=np.int64).reshape(-1)
        quat = np.asarray(self.quat_wxyz, dtype=np.float64).reshape(-1, 4)
        trans = np.asarray(self.translation_m, dtype=np.float64).reshape(-1, 3)
        if not (ts.shape[0] == quat.shape[0] == trans.shape[0]):
            raise ValueError(
                f"EgoTrajectory lengths differ: {ts.shape[0]} timestamps, {quat.shape[0]} rotations, "
                f"{trans.shape[0]} translations"
            )
        object.__setattr__(self, "timestamps_ns", _readonly(ts))
        object.__setattr__(self, "quat_wxyz", _readonly(quat))
        object.__setattr__(self, "translation_m", _readonly(trans))

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])

    @staticmethod
    def from_xy_yaw(
        timestamps_ns: NDArray[np.integer], xy_m: NDArray[np.floating], yaw_rad: NDArray[np.floating]
    ) -> EgoTrajectory:
        """Planar trajectory on z = 0.

        Args:
            timestamps_ns: (T,) timestamps.
            xy_m: (T, 2) ego origin in the city frame.
            yaw_rad: (T,) ego heading in the city frame.
        """
        xy = np.asarray(xy_m, dtype=np.float64)
        trans = np.concatenate([xy, np.zeros((xy.shape[0], 1))], axis=1)
        return EgoTrajectory(np.asarray(timestamps_ns, dtype=np.int64), yaw_to_quat(yaw_rad), trans)

    @property
    def rotation(self) -> FloatArray:
        """(T, 3, 3) rotations ego → city."""
        return quat_to_rotmat(self.quat_wxyz)

    @property
    def matrices(self) -> FloatArray:
        """(T, 4, 4) homogeneous ``city_SE3_ego``."""
        return batch_matrices(self.rotation, self.translation_m)

    @property
    def yaw_rad(self) -> FloatArray:
        """(T,) ego heading in the city frame."""
        return quat_to_yaw(self.quat_wxyz)

    def city_SE3_ego(self, index: int) -> SE3:
        return SE3.from_quat(self.quat_wxyz[index], self.translation_m[index])

    def interpolate(self, query_timestamps_ns: NDArray[np.integer]) -> EgoTrajectory:
        """Poses at other timestamps (SLERP rotation, linear translation, clamped at the ends).

        Args:
            query_timestamps_ns: (Q,) timestamps.
        """
        quat, trans = interpolate_poses(self.timestamps_ns, self.quat_wxyz, self.translation_m, query_timestamps_ns)
        return EgoTrajectory(np.asarray(query_timestamps_ns, dtype=np.int64), quat, trans)

    def speed_mps(self) -> FloatArray:
        """(T,) planar speed from central differences of positions (0 for a single pose)."""
        if len(self) < 2:
            return np.zeros(len(self))
        t_s = (self.timestamps_ns - self.timestamps_ns[0]).astype(np.float64) * 1e-9
        vel = np.gradient(self.translation_m[:, :2], t_s, axis=0)
        return np.asarray(np.linalg.norm(vel, axis=1), dtype=np.float64)


@dataclass(frozen=True)
class Annotations:
    """Cuboid annotations, one row per (timestamp, track), boxes in the ego frame.

    Attributes:
        timestamp_ns: (N,) sweep timestamp of each row.
        track_id: (N,) track identifier.
        category: (N,) raw dataset label (e.g. ``REGULAR_VEHICLE``); see :attr:`public_category`.
        center_xyz_m: (N, 3) box centre in the ego frame at that timestamp.
        size_lwh_m: (N, 3) box length (along the box x), width, height.
        quat_wxyz: (N, 4) box orientation ``ego_SE3_object``, scalar first.
        num_interior_pts: (N,) LiDAR points inside the box (−1 when unknown).
    """

    timestamp_ns: IntArray
    track_id: StrArray
    category: StrArray
    center_xyz_m: FloatArray
    size_lwh_m: FloatArray
    quat_wxyz: FloatArray
    num_interior_pts: IntArray

    def __post_init__(self) -> None:
        n = int(np.asarray(self.timestamp_ns).shape[0])
        fields = {
            "timestamp_ns": (np.asarray(self.timestamp_ns, dtype=np.int64).reshape(-1), (n,)),
            "track_id": (np.asarray(self.track_id, dtype=np.str_).reshape(-1), (n,)),
            "category": (np.asarray(self.category, dtype=np.str_).reshape(-1), (n,)),
            "center_xyz_m": (np.asarray(self.center_xyz_m, dtype=np.float64).reshape(-1, 3), (n, 3)),
            "size_lwh_m": (np.asarray(self.size_lwh_m, dtype=np.float64).reshape(-1, 3), (n, 3)),
            "quat_wxyz": (np.asarray(self.quat_wxyz, dtype=np.float64).reshape(-1, 4), (n, 4)),
            "num_interior_pts": (np.asarray(self.num_interior_pts, dtype=np.int64).reshape(-1), (n,)),
        }
        for name, (value, shape) in fields.items():
            if value.shape != shape:
                raise ValueError(f"Annotations.{name} has shape {value.shape}, expected {shape}")
            object.__setattr__(self, name, _readonly(value))

    @staticmethod
    def from_yaw(
        timestamp_ns: NDArray[np.integer],
        track_id: NDArray[np.str_] | list[str],
        category: NDArray[np.str_] | list[str],
        center_xyz_m: NDArray[np.floating],
        size_lwh_m: NDArray[np.floating],
        yaw_rad: NDArray[np.floating],
        num_interior_pts: NDArray[np.integer] | None = None,
    ) -> Annotations:
        """Build from upright boxes given by yaw in the ego frame.

        Args:
            timestamp_ns: (N,) timestamps.
            track_id: (N,) track ids.
            category: (N,) raw labels.
            center_xyz_m: (N, 3) centres in the ego frame.
            size_lwh_m: (N, 3) sizes.
            yaw_rad: (N,) headings in the ego frame.
            num_interior_pts: (N,) point counts, or None for unknown.
        """
        n = int(np.asarray(timestamp_ns).shape[0])
        pts = np.full(n, -1, dtype=np.int64) if num_interior_pts is None else num_interior_pts
        return Annotations(
            np.asarray(timestamp_ns, dtype=np.int64),
            np.asarray(track_id, dtype=np.str_),
            np.asarray(category, dtype=np.str_),
            np.asarray(center_xyz_m, dtype=np.float64),
            np.asarray(size_lwh_m, dtype=np.float64),
            yaw_to_quat(np.asarray(yaw_rad, dtype=np.float64)),
            np.asarray(pts, dtype=np.int64),
        )

    @staticmethod
    def empty() -> Annotations:
        return Annotations.from_yaw(
            np.zeros(0, np.int64), [], [], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
        )

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    @property
    def yaw_rad(self) -> FloatArray:
        """(N,) box headings in the ego frame."""
        return quat_to_yaw(self.quat_wxyz)

    @property
    def public_category(self) -> NDArray[np.object_]:
        """(N,) :class:`Category` of each row; unknown labels map to ``other``."""
        labels, inverse = np.unique(self.category, return_inverse=True)
        lookup = np.array([category_from_label(str(label)) or Category.OTHER for label in labels], dtype=object)
        return np.asarray(lookup[inverse.reshape(-1)], dtype=object)

    def unknown_labels(self) -> dict[str, int]:
        """Raw labels that map to no public category, with their row counts."""
        labels, counts = np.unique(self.category, return_counts=True)
        return {
            str(lab): int(c)
            for lab, c in zip(labels, counts)
            if category_from_label(str(lab)) is None and lab != EGO_VEHICLE_LABEL
        }

    def select(self, mask: NDArray[np.bool_] | NDArray[np.integer]) -> Annotations:
        """Rows where ``mask`` is true, or at the given indices. ``mask``: (N,) booleans or (M,) indices."""
        return Annotations(
            self.timestamp_ns[mask],
            self.track_id[mask],
            self.category[mask],
            self.center_xyz_m[mask],
            self.size_lwh_m[mask],
            self.quat_wxyz[mask],
            self.num_interior_pts[mask],
        )

    def without_ego(self) -> Annotations:
        """Drop the ego's own box (``EGO_VEHICLE`` rows), which is never a neighbour."""
        keep = self.category != EGO_VEHICLE_LABEL
        return self if bool(keep.all()) else self.select(keep)

    def sorted(self) -> Annotations:
        """Rows ordered by (timestamp, track id): the canonical file order."""
        order = np.lexsort((self.track_id, self.timestamp_ns))
        return self.select(order) if len(self) else self

    @property
    def timestamps_ns(self) -> IntArray:
        """(T,) distinct timestamps, increasing."""
        return np.unique(self.timestamp_ns)

    @property
    def track_ids(self) -> list[str]:
        """Distinct track ids in order of first appearance."""
        _, first = np.unique(self.track_id, return_index=True)
        return [str(self.track_id[i]) for i in np.sort(first)]


@dataclass(frozen=True)
class ObjectTrack:
    """One object over time, in the ego frame and in the city frame.

    Attributes:
        track_id: track identifier.
        category: public category.
        raw_category: the dataset's own label.
        timestamps_ns: (T,) increasing timestamps where the track is observed.
        center_ego_xyz_m: (T, 3) box centre in the ego frame at each timestamp.
        yaw_ego_rad: (T,) box heading in the ego frame.
        center_city_xyz_m: (T, 3) box centre in the city frame.
        yaw_city_rad: (T,) box heading in the city frame.
        size_lwh_m: (T, 3) box size.
    """

    track_id: str
    category: Category
    raw_category: str
    timestamps_ns: IntArray
    center_ego_xyz_m: FloatArray
    yaw_ego_rad: FloatArray
    center_city_xyz_m: FloatArray
    yaw_city_rad: FloatArray
    size_lwh_m: FloatArray

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])


def tracks_from_annotations(annotations: Annotations, ego: EgoTrajectory) -> dict[str, ObjectTrack]:
    """Split annotations into per-track objects with city-frame poses.

    Args:
        annotations: the log's annotations (the ego's own box is dropped).
        ego: ``city_SE3_ego`` at any rate; interpolated to the annotation timestamps.

    Returns:
        Tracks keyed by id, in order of first appearance.
    """
    ann = annotations.without_ego().sorted()
    if len(ann) == 0:
        return {}
    ego_at = ego.interpolate(ann.timestamp_ns)
    rot = ego_at.rotation  # (N, 3, 3)
    center_city = np.einsum("nij,nj->ni", rot, ann.center_xyz_m) + ego_at.translation_m
    yaw_ego = ann.yaw_rad
    yaw_city = wrap_angle_rad(yaw_ego + ego_at.yaw_rad)
    public = ann.public_category
    order = np.argsort(ann.track_id, kind="stable")  # rows stay time-ordered within a track
    ids_sorted = ann.track_id[order]
    bounds = np.flatnonzero(np.r_[True, ids_sorted[1:] != ids_sorted[:-1], True])
    tracks: dict[str, ObjectTrack] = {}
    for start, stop in zip(bounds[:-1], bounds[1:]):
        rows = order[start:stop]
        tid = str(ann.track_id[rows[0]])
        tracks[tid] = ObjectTrack(
            track_id=tid,
            category=public[rows[0]],
            raw_category=str(ann.category[rows[0]]),
            timestamps_ns=ann.timestamp_ns[rows],
            center_ego_xyz_m=ann.center_xyz_m[rows],
            yaw_ego_rad=yaw_ego[rows],
            center_city_xyz_m=center_city[rows],
            yaw_city_rad=yaw_city[rows],
            size_lwh_m=ann.size_lwh_m[rows],
        )
    first_seen = {tid: int(t.timestamps_ns[0]) for tid, t in tracks.items()}
    return dict(sorted(tracks.items(), key=lambda kv: (first_seen[kv[0]], kv[0])))


@dataclass(frozen=True)
class DenseTracks:
    """All tracks of a log on its frame grid: K tracks × T frames.

    Entries where a track is not observed hold NaN and ``valid`` is false.

    Attributes:
        timestamps_ns: (T,) the log's frame timestamps.
        track_ids: (K,) track ids.
        categories: (K,) public category values (str).
        valid: (K, T) whether the track is observed at the frame.
        center_ego_xyz_m: (K, T, 3) box centres in the ego frame.
        yaw_ego_rad: (K, T) headings in the ego frame.
        center_city_xyz_m: (K, T, 3) box centres in the city frame.
        yaw_city_rad: (K, T) headings in the city frame.
        size_lwh_m: (K, T, 3) box sizes.
        city_SE3_ego: (T, 4, 4) ego poses at the frames.
    """

    timestamps_ns: IntArray
    track_ids: StrArray
    categories: StrArray
    valid: NDArray[np.bool_]
    center_ego_xyz_m: FloatArray
    yaw_ego_rad: FloatArray
    center_city_xyz_m: FloatArray
    yaw_city_rad: FloatArray
    size_lwh_m: FloatArray
    city_SE3_ego: FloatArray


def dense_tracks(
    annotations: Annotations, ego: EgoTrajectory, frame_timestamps_ns: NDArray[np.integer] | None = None
) -> DenseTracks:
    """Pack annotations onto a frame grid (vectorised, no per-frame loop).

    Args:
        annotations: the log's annotations (the ego's own box is dropped).
        ego: ``city_SE3_ego`` at any rate; interpolated to the frame timestamps.
        frame_timestamps_ns: (T,) the frame grid; it must hold every annotation timestamp. Frames
            without any annotation (nothing around the ego) are kept. Defaults to the annotations'
            own distinct timestamps.
    """
    ann = annotations.without_ego()
    frame_ts = ann.timestamps_ns
    if frame_timestamps_ns is not None:
        frame_ts = np.unique(np.asarray(frame_timestamps_ns, dtype=np.int64))
        missing = np.setdiff1d(ann.timestamps_ns, frame_ts)
        if missing.size:
            raise ValueError(f"annotation timestamp {int(missing[0])} is not on the frame grid")
    ego_at = ego.interpolate(frame_ts) if len(frame_ts) else ego
    track_ids, track_index = np.unique(ann.track_id, return_inverse=True)
    frame_index = np.searchsorted(frame_ts, ann.timestamp_ns)
    k, t = track_ids.shape[0], frame_ts.shape[0]
    valid = np.zeros((k, t), dtype=bool)
    valid[track_index, frame_index] = True
    center_ego = np.full((k, t, 3), np.nan)
    center_ego[track_index, frame_index] = ann.center_xyz_m
    yaw_ego = np.full((k, t), np.nan)
    yaw_ego[track_index, frame_index] = ann.yaw_rad
    size = np.full((k, t, 3), np.nan)
    size[track_index, frame_index] = ann.size_lwh_m
    rot = ego_at.rotation  # (T, 3, 3)
    center_city = np.einsum("tij,ktj->kti", rot, center_ego) + ego_at.translation_m[None]
    yaw_city = wrap_angle_rad(yaw_ego + ego_at.yaw_rad[None])
    categories = np.empty(k, dtype=object)
    public = ann.public_category
    categories[track_index] = public
    return DenseTracks(
        timestamps_ns=frame_ts,
        track_ids=track_ids,
        categories=np.array([str(c) for c in categories], dtype=np.str_),
        valid=valid,
        center_ego_xyz_m=center_ego,
        yaw_ego_rad=yaw_ego,
        center_city_xyz_m=center_city,
        yaw_city_rad=yaw_city,
        size_lwh_m=size,
        city_SE3_ego=ego_at.matrices,
    )
