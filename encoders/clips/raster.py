"""BEV layers of clips, built on :mod:`scenes.bev` (grid, boxes, map layers, LiDAR counts).

Everything here is stored as uint8 (see :mod:`encoders.clips.render`):

- occupancy: log-scaled point density per height bin (:func:`density_uint8`);
- map layers (:data:`MAP_CHANNELS`, the layers of :class:`scenes.bev.MapRasterizer`, see
  :data:`CHANNEL_LAYERS`): 0/255 for the binary layers; the lane direction (unit vector of the lane
  heading in the ego frame) as ``round(128 + 127·v)`` on lanes and 0 elsewhere, so
  ``v = (255·x − 128) / 127`` where ``x > 0``.

The map is rasterised once per log on a city-frame grid (with :class:`scenes.bev.MapRasterizer`
at the identity pose) and warped into each frame's ego grid with one affine warp per frame: the map
is static, only the ego moves.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.bev import MAP_LAYERS, BevGrid, MapRasterizer, box_samples
from scenes.geometry import SE3, FloatArray
from scenes.map import VectorMap

#: Map channels of the BEV view, in order (names used in clips manifests and by the tagging stage).
MAP_CHANNELS: tuple[str, ...] = (
    "drivable_area",
    "lane_boundary",
    "lane_direction_x",
    "lane_direction_y",
    "crossing",
    "intersection",
)
#: The :data:`scenes.bev.MAP_LAYERS` layer behind each channel (direction x, y = heading cos, sin).
CHANNEL_LAYERS: dict[str, str] = dict(zip(MAP_CHANNELS, MAP_LAYERS))
_DIRECTION = (MAP_CHANNELS.index("lane_direction_x"), MAP_CHANNELS.index("lane_direction_y"))


def grid_affine_from(grid: BevGrid, source: BevGrid, source_SE3_grid: FloatArray) -> FloatArray:
    """(2, 3) affine taking pixel (column, row) of ``grid`` to pixel (column, row) of ``source``.

    Args:
        grid: the destination grid, in frame ``g``.
        source: the source grid, in frame ``s``.
        source_SE3_grid: (3, 3) planar pose (rotation and translation) of ``g`` in ``s``.
    """
    res_g, res_s = grid.resolution_m, source.resolution_m
    xy_from_px = np.array([[0.0, -res_g, grid.x_max_m - 0.5 * res_g], [-res_g, 0.0, grid.y_max_m - 0.5 * res_g]])
    rot, trans = source_SE3_grid[:2, :2], source_SE3_grid[:2, 2]
    src_xy = rot @ xy_from_px
    src_xy[:, 2] += trans
    px_from_xy = np.array([[0.0, -1.0 / res_s], [-1.0 / res_s, 0.0]])
    affine = px_from_xy @ src_xy
    affine[:, 2] += np.array([source.y_max_m / res_s - 0.5, source.x_max_m / res_s - 0.5])
    return np.asarray(affine, dtype=np.float64)


def density_uint8(counts: NDArray[np.floating] | NDArray[np.integer], saturation_points: int) -> NDArray[np.uint8]:
    """(...) point counts → (...) uint8 on a log scale, 255 at ``saturation_points`` or more."""
    scale = np.float32(255.0 / np.log1p(float(saturation_points)))
    return np.minimum(np.log1p(counts.astype(np.float32)) * scale + 0.5, 255.0).astype(np.uint8)


def rasterize_track(grid: BevGrid, boxes: NDArray[np.floating]) -> NDArray[np.uint8]:
    """Footprints of one object over frames, each frame on its own (a cell is inside when its
    centre is, as in :func:`scenes.bev.rasterize_boxes`), all frames in one vectorised pass.

    Args:
        grid: the grid.
        boxes: (T, 5) ``x_m, y_m, length_m, width_m, yaw_rad`` in each frame's ego frame; NaN rows
            (object not observed) stay empty.

    Returns:
        (T, H, W) uint8, 1 inside the footprint.
    """
    b = np.asarray(boxes, dtype=np.float64)
    out = np.zeros((b.shape[0], *grid.shape), dtype=np.uint8)
    ok = np.flatnonzero(np.isfinite(b).all(axis=1))
    if ok.size == 0:
        return out
    # scenes.bev's own cell sampler, vectorised over boxes: one box per frame here.
    frame, rows, cols = box_samples(grid, b[ok, :2], b[ok, 2:4], b[ok, 4], 1)
    out[ok[frame], rows, cols] = 1
    return out


def render_map_frames(
    vector_map: VectorMap, grid: BevGrid, city_SE3_ego: NDArray[np.floating]
) -> NDArray[np.uint8]:
    """Map layers in the ego grid of each frame.

    Args:
        vector_map: the log's map.
        grid: the ego grid.
        city_SE3_ego: (F, 4, 4) ego poses.

    Returns:
        (F, C, H, W) uint8 layers (see the module docstring for the encoding).
    """
    poses = np.asarray(city_SE3_ego, dtype=np.float64)
    num_frames = poses.shape[0]
    out = np.zeros((num_frames, len(MAP_CHANNELS), *grid.shape), dtype=np.uint8)
    if num_frames == 0:
        return out
    # A city-frame grid covering every frame's ego grid, rasterised once.
    corners = np.array([[grid.x_min_m, grid.y_min_m], [grid.x_min_m, grid.y_max_m], [grid.x_max_m, grid.y_min_m],
                        [grid.x_max_m, grid.y_max_m]])
    city = np.einsum("fij,cj->fci", poses[:, :2, :2], corners) + poses[:, None, :2, 3]
    lo, hi = city.reshape(-1, 2).min(axis=0) - 2.0, city.reshape(-1, 2).max(axis=0) + 2.0
    city_grid = BevGrid(float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), grid.resolution_m)
    layers = MapRasterizer(vector_map).rasterize(city_grid, SE3.identity())
    stack = np.stack([layers[CHANNEL_LAYERS[name]] for name in MAP_CHANNELS], axis=-1).astype(np.float32)
    h, w = grid.shape
    warped = np.empty((num_frames, len(MAP_CHANNELS), h, w), dtype=np.float32)
    for f in range(num_frames):
        pose = np.eye(3)
        pose[:2, :2], pose[:2, 2] = poses[f, :2, :2], poses[f, :2, 3]
        affine = grid_affine_from(grid, city_grid, pose)
        frame = np.empty((h, w, stack.shape[2]), dtype=np.float32)
        for c0 in range(0, stack.shape[2], 4):  # OpenCV warps at most 4 float channels at once
            part = cv2.warpAffine(stack[:, :, c0 : c0 + 4], affine, (w, h),
                                  flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
            frame[:, :, c0 : c0 + 4] = part.reshape(h, w, -1)
        warped[f] = frame.transpose(2, 0, 1)
    # Lane headings: city → ego frame (subtract the ego yaw).
    ic, is_ = _DIRECTION
    cos_c, sin_c = warped[:, ic], warped[:, is_]
    on_lane = cos_c * cos_c + sin_c * sin_c > 0.5
    yaw_cos, yaw_sin = poses[:, 0, 0][:, None, None], poses[:, 1, 0][:, None, None]
    cos_e = cos_c * yaw_cos + sin_c * yaw_sin
    sin_e = sin_c * yaw_cos - cos_c * yaw_sin
    for c in range(len(MAP_CHANNELS)):
        if c not in _DIRECTION:
            out[:, c] = (warped[:, c] > 0.5) * np.uint8(255)
    out[:, ic] = np.where(on_lane, np.clip(np.round(128 + 127 * cos_e), 1, 255), 0).astype(np.uint8)
    out[:, is_] = np.where(on_lane, np.clip(np.round(128 + 127 * sin_e), 1, 255), 0).astype(np.uint8)
    return out
