"""The BEV arrays of a log, one per frame in that frame's ego grid: box footprints, track boxes,
occupancy (from LiDAR sweeps or from boxes) and map layers (shapes in :mod:`encoders.clips.layout`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from encoders.clips.config import ClipsConfig
from encoders.clips.raster import MAP_CHANNELS, density_uint8, render_map_frames
from encoders.clips.render_stats import LogRenderStats
from scenes.bev import BevGrid, count_points, rasterize_boxes
from scenes.errors import LogFormatError
from scenes.geometry import FloatArray, invert_matrices
from scenes.log import Log
from scenes.tracks import DenseTracks


def render_bev_instances(grid: BevGrid, dense: DenseTracks) -> NDArray[np.uint16]:
    """(F, Hb, Wb) footprints of every valid box; larger boxes are drawn first so small ones stay visible."""
    f = dense.valid.shape[1]
    out = np.zeros((f, *grid.shape), dtype=np.uint16)
    area = np.nan_to_num(dense.size_lwh_m[..., 0] * dense.size_lwh_m[..., 1])  # (K, F)
    for fi in range(f):
        ks = np.flatnonzero(dense.valid[:, fi])
        if ks.size == 0:
            continue
        ks = ks[np.argsort(-area[ks, fi], kind="stable")]  # later boxes win where they overlap
        out[fi] = rasterize_boxes(grid, dense.center_ego_xyz_m[ks, fi, :2], dense.size_lwh_m[ks, fi, :2],
                                  dense.yaw_ego_rad[ks, fi], values=(ks + 1).astype(np.float64))
    return out


def track_boxes(dense: DenseTracks) -> NDArray[np.float32]:
    """(F, K, 5) ``x, y, length, width, yaw`` of every track in each frame's ego frame, NaN when unobserved."""
    boxes = np.concatenate(
        [dense.center_ego_xyz_m[..., :2], dense.size_lwh_m[..., :2], dense.yaw_ego_rad[..., None]], axis=-1
    )  # (K, F, 5)
    boxes[~dense.valid] = np.nan
    return np.ascontiguousarray(np.swapaxes(boxes, 0, 1)).astype(np.float32)


def render_boxes_occupancy(
    grid: BevGrid, dense: DenseTracks, z_bins_m: tuple[float, ...]
) -> NDArray[np.uint8]:
    """(F, Z, Hb, Wb) occupancy rendered from the boxes: a box fills the height bins it spans (255)."""
    k, f = dense.valid.shape
    z_edges = np.asarray(z_bins_m)
    num_z = z_edges.shape[0] - 1
    out = np.zeros((f, num_z, *grid.shape), dtype=np.uint8)
    if k == 0:
        return out
    bottom = dense.center_ego_xyz_m[..., 2] - 0.5 * dense.size_lwh_m[..., 2]  # (K, F)
    top = dense.center_ego_xyz_m[..., 2] + 0.5 * dense.size_lwh_m[..., 2]
    spans = (bottom[..., None] < z_edges[None, None, 1:]) & (top[..., None] > z_edges[None, None, :-1])  # (K,F,Z)
    spans &= dense.valid[..., None]
    for fi in range(f):
        for zi in range(num_z):
            ks = np.flatnonzero(spans[:, fi, zi])
            if ks.size:
                filled = rasterize_boxes(grid, dense.center_ego_xyz_m[ks, fi, :2], dense.size_lwh_m[ks, fi, :2],
                                         dense.yaw_ego_rad[ks, fi])
                out[fi, zi] = (filled > 0) * np.uint8(255)
    return out


def render_lidar_occupancy(
    log: Log, grid: BevGrid, config: ClipsConfig, frame_ts: NDArray[np.int64], city_SE3_ego: FloatArray,
    sweep_index: NDArray[np.int64], stats: LogRenderStats,
) -> NDArray[np.uint8]:
    """(F, Z, Hb, Wb) occupancy from the nearest sweep and the previous ones, motion-compensated.

    Each sweep is read once and kept while frames use it; its points are moved into each frame's ego
    frame by ``ego_SE3_city(frame) · city_SE3_ego(sweep)`` (ego poses interpolated at the sweep
    times) inside :func:`scenes.bev.count_points`.
    """
    b = config.bev
    sweep_ts = log.lidar_timestamps_ns
    num_z = len(b.z_bins_m) - 1
    out = np.zeros((frame_ts.shape[0], num_z, *grid.shape), dtype=np.uint8)
    if sweep_ts.shape[0] == 0:
        return out
    city_SE3_sweep = log.ego.interpolate(sweep_ts).matrices  # (S, 4, 4)
    ego_SE3_city = invert_matrices(city_SE3_ego)  # (F, 4, 4)
    z_bins_m = np.asarray(b.z_bins_m)
    cache: dict[int, NDArray[np.float32] | None] = {}

    def points(j: int) -> NDArray[np.float32] | None:
        """(3, N) the sweep's points as rows of coordinates, or None when it cannot be used."""
        if j not in cache:
            try:
                xyz = log.lidar_points(int(sweep_ts[j]))
            except LogFormatError as exc:
                stats.corrupt_sweeps.append(f"{int(sweep_ts[j])}.feather: {exc.problems[0].message}")
                cache[j] = None
                return None
            if xyz.shape[0] == 0:  # as `validate` says, a sweep with no points: its frames would read as empty
                stats.corrupt_sweeps.append(f"{int(sweep_ts[j])}.feather: sweep has no points")
                cache[j] = None
                return None
            cache[j] = np.ascontiguousarray(xyz.T)
        return cache[j]

    for fi in range(frame_ts.shape[0]):
        j = int(sweep_index[fi])
        if j < 0:
            continue
        if points(j) is None:  # the frame's own sweep is corrupt: skip the frame
            sweep_index[fi] = -1
            continue
        clouds = []
        for jj in range(j, max(j - b.num_sweeps, -1), -1):
            xyz_m = points(jj)
            if xyz_m is not None:
                clouds.append((xyz_m, ego_SE3_city[fi] @ city_SE3_sweep[jj]))
        for stale in [key for key in cache if key < j - b.num_sweeps]:
            del cache[stale]
        out[fi] = density_uint8(count_points(grid, z_bins_m, clouds), b.density_saturation_points)
    return out


def render_map(log: Log, grid: BevGrid, city_SE3_ego: FloatArray) -> NDArray[np.uint8]:
    vector_map = log.map
    if vector_map is None or city_SE3_ego.shape[0] == 0:
        return np.zeros((city_SE3_ego.shape[0], len(MAP_CHANNELS), *grid.shape), dtype=np.uint8)
    return render_map_frames(vector_map, grid, city_SE3_ego)

