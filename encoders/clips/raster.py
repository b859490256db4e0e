"""Bird's-eye-view rasters for clips: the ego-frame grid, boxes, LiDAR occupancy and map layers.

The grid lies in an ego frame (x forward, y left)::

    row 0     = x_max_m   (forward at the top)
    column 0  = y_max_m   (left on the left)

so a cell (row, col) covers ``x ∈ [x_max − (row+1)·res, x_max − row·res)`` and
``y ∈ [y_max − (col+1)·res, y_max − col·res)``.

Map layers are rasterised once per log in a city-frame raster and warped into each frame's ego
grid with one affine warp per frame (the map is static, only the ego moves).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.geometry import FloatArray
from scenes.map import VectorMap, resample_polyline

#: Map channels of the BEV view, in order.
MAP_CHANNELS: tuple[str, ...] = (
    "drivable_area",
    "lane_boundary",
    "lane_direction_x",
    "lane_direction_y",
    "crossing",
    "intersection",
)

#: Sub-pixel bits for OpenCV polygon drawing.
_SHIFT = 4


@dataclass(frozen=True)
class BevGrid:
    """A regular grid in an ego frame; see the module docstring for the layout."""

    x_min_m: float = -20.0
    x_max_m: float = 60.0
    y_min_m: float = -20.0
    y_max_m: float = 20.0
    resolution_m: float = 0.5

    @property
    def height_px(self) -> int:
        return round((self.x_max_m - self.x_min_m) / self.resolution_m)

    @property
    def width_px(self) -> int:
        return round((self.y_max_m - self.y_min_m) / self.resolution_m)

    def to_pixel(self, xy_m: NDArray[np.floating]) -> FloatArray:
        """(..., 2) ego-frame points → (..., 2) continuous pixel coordinates ``(col, row)``.

        Pixel centres are at integer + 0.5.
        """
        xy = np.asarray(xy_m, dtype=np.float64)
        col = (self.y_max_m - xy[..., 1]) / self.resolution_m
        row = (self.x_max_m - xy[..., 0]) / self.resolution_m
        return np.stack([col, row], axis=-1)

    def cell_of(self, xy_m: NDArray[np.floating]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
        """(N, 2) ego-frame points → (N,) rows, (N,) columns and (N,) inside-the-grid flags."""
        pix = np.floor(self.to_pixel(xy_m)).astype(np.int64)
        col, row = pix[..., 0], pix[..., 1]
        inside = (row >= 0) & (row < self.height_px) & (col >= 0) & (col < self.width_px)
        return row, col, inside


def box_corners_xy(
    centers_xy: NDArray[np.floating], sizes_lw: NDArray[np.floating], yaws_rad: NDArray[np.floating]
) -> FloatArray:
    """Footprint corners of upright boxes.

    Args:
        centers_xy: (..., 2) box centres.
        sizes_lw: (..., 2) box length (along its heading) and width.
        yaws_rad: (...) headings.

    Returns:
        (..., 4, 2) corners, counter-clockwise from front-left.
    """
    c = np.asarray(centers_xy, dtype=np.float64)
    half = 0.5 * np.asarray(sizes_lw, dtype=np.float64)
    yaw = np.asarray(yaws_rad, dtype=np.float64)
    signs = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    local = signs * half[..., None, :]  # (..., 4, 2)
    cos, sin = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    x = cos * local[..., 0] - sin * local[..., 1]
    y = sin * local[..., 0] + cos * local[..., 1]
    return np.stack([x, y], axis=-1) + c[..., None, :]


def _poly_px(grid: BevGrid, corners_xy: FloatArray) -> NDArray[np.int32]:
    """(..., N, 2) ego points → fixed-point pixel polygons for OpenCV (centre-of-pixel convention)."""
    pix = grid.to_pixel(corners_xy) - 0.5
    return np.round(pix * (1 << _SHIFT)).astype(np.int32)


def rasterize_boxes(
    grid: BevGrid,
    centers_xy: NDArray[np.floating],
    sizes_lw: NDArray[np.floating],
    yaws: NDArray[np.floating],
    values: NDArray[np.integer] | None = None,
    dtype: type = np.uint8,
) -> NDArray[Any]:
    """Fill box footprints into one grid; later boxes overwrite earlier ones.

    Args:
        grid: the grid.
        centers_xy: (N, 2) centres in the grid's ego frame.
        sizes_lw: (N, 2) lengths and widths.
        yaws: (N,) headings in the grid's ego frame.
        values: (N,) fill values (default 1 = 255 for uint8 masks … 1).
        dtype: output dtype.

    Returns:
        (H, W) raster.
    """
    out: NDArray[Any] = np.zeros((grid.height_px, grid.width_px), dtype=dtype)
    n = int(np.asarray(centers_xy).shape[0])
    if n == 0:
        return out
    polys = _poly_px(grid, box_corners_xy(centers_xy, sizes_lw, yaws))
    vals = np.ones(n, dtype=np.int64) if values is None else np.asarray(values, dtype=np.int64)
    for poly, value in zip(polys, vals):
        cv2.fillConvexPoly(out, poly, int(value), lineType=cv2.LINE_8, shift=_SHIFT)
    return out


def rasterize_track(grid: BevGrid, boxes: NDArray[np.floating]) -> NDArray[np.uint8]:
    """Footprints of one object over frames, each frame on its own.

    Args:
        grid: the grid.
        boxes: (T, 5) ``x_m, y_m, length_m, width_m, yaw_rad`` in each frame's ego frame; NaN rows
            (object not observed) stay empty.

    Returns:
        (T, H, W) uint8, 1 inside the footprint.
    """
    b = np.asarray(boxes, dtype=np.float64)
    out = np.zeros((b.shape[0], grid.height_px, grid.width_px), dtype=np.uint8)
    ok = np.isfinite(b).all(axis=1)
    if not ok.any():
        return out
    polys = _poly_px(grid, box_corners_xy(b[ok, :2], b[ok, 2:4], b[ok, 4]))
    for t, poly in zip(np.flatnonzero(ok), polys):
        cv2.fillConvexPoly(out[t], poly, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return out


def lidar_counts(grid: BevGrid, points_xyz: NDArray[np.floating], z_bins_m: tuple[float, ...]) -> NDArray[np.int32]:
    """Points per cell and height bin.

    Args:
        grid: the grid.
        points_xyz: (N, 3) points in the grid's ego frame.
        z_bins_m: (Z + 1,) increasing height-bin edges.

    Returns:
        (Z, H, W) point counts; points outside the grid or the bins are dropped.
    """
    pts = np.asarray(points_xyz, dtype=np.float32)
    z_edges = np.asarray(z_bins_m, dtype=np.float32)
    num_z = z_edges.shape[0] - 1
    h, w = grid.height_px, grid.width_px
    inv = np.float32(1.0 / grid.resolution_m)
    # Float32 throughout and no stacked temporaries: this runs on ~10⁵ points per frame.
    row = np.floor((np.float32(grid.x_max_m) - pts[:, 0]) * inv).astype(np.int32)
    col = np.floor((np.float32(grid.y_max_m) - pts[:, 1]) * inv).astype(np.int32)
    zbin = np.searchsorted(z_edges, pts[:, 2], side="right").astype(np.int32) - 1
    keep = (row >= 0) & (row < h) & (col >= 0) & (col < w) & (zbin >= 0) & (zbin < num_z)
    flat = (zbin[keep] * h + row[keep]) * w + col[keep]
    return np.bincount(flat, minlength=num_z * h * w).astype(np.int32).reshape(num_z, h, w)


def density_uint8(counts: NDArray[np.integer], saturation_points: int) -> NDArray[np.uint8]:
    """(...) point counts → (...) uint8 on a log scale, 255 at ``saturation_points`` or more."""
    scale = 255.0 / np.log1p(float(saturation_points))
    return np.minimum(np.log1p(counts.astype(np.float32)) * scale + 0.5, 255.0).astype(np.uint8)


# ---------------------------------------------------------------------------------------------
# Map


@dataclass(frozen=True)
class CityRaster:
    """Map layers rasterised once in the city frame.

    Attributes:
        layers: (H, W, C) uint8, channels as :data:`MAP_CHANNELS`; the lane direction channels
            hold the city-frame unit direction encoded as ``round(128 + 127·d)`` inside lanes, 0 outside.
        origin_xy_m: (2,) city coordinates of the raster's corner (column 0, row 0).
        resolution_m: cell size.
    """

    layers: NDArray[np.uint8]
    origin_xy_m: FloatArray
    resolution_m: float


def rasterize_city_map(vector_map: VectorMap, extent_xy_m: FloatArray, resolution_m: float) -> CityRaster:
    """Rasterise a vector map over a city-frame rectangle (column = x, row = y, both increasing).

    Args:
        vector_map: the log's map.
        extent_xy_m: (2, 2) ``[[x_min, y_min], [x_max, y_max]]`` in the city frame.
        resolution_m: cell size.
    """
    origin = np.asarray(extent_xy_m[0], dtype=np.float64)
    size = np.ceil((np.asarray(extent_xy_m[1]) - origin) / resolution_m).astype(int) + 1
    w, h = int(size[0]), int(size[1])

    def px(points_xyz: FloatArray) -> NDArray[np.int32]:
        p = (np.asarray(points_xyz)[..., :2] - origin) / resolution_m - 0.5
        return np.round(p * (1 << _SHIFT)).astype(np.int32)

    drivable = np.zeros((h, w), np.uint8)
    boundary = np.zeros((h, w), np.uint8)
    dir_x = np.zeros((h, w), np.uint8)
    dir_y = np.zeros((h, w), np.uint8)
    crossing = np.zeros((h, w), np.uint8)
    intersection = np.zeros((h, w), np.uint8)
    areas = [px(a.area_boundary) for a in vector_map.drivable_areas.values() if a.area_boundary.shape[0] >= 3]
    if areas:
        for poly in areas:  # one call each: fillPoly over several polygons drops their overlaps
            cv2.fillPoly(drivable, [poly], 255, lineType=cv2.LINE_8, shift=_SHIFT)
    crossings = [px(c.polygon()) for c in vector_map.pedestrian_crossings.values()]
    if crossings:
        for poly in crossings:  # one call each: fillPoly over several polygons drops their overlaps
            cv2.fillPoly(crossing, [poly], 255, lineType=cv2.LINE_8, shift=_SHIFT)
    lines: list[NDArray[np.int32]] = []
    junction: list[NDArray[np.int32]] = []
    n_pts = 8
    for lane in vector_map.lane_segments.values():
        lines.append(px(lane.left_lane_boundary))
        lines.append(px(lane.right_lane_boundary))
        if lane.is_intersection:
            junction.append(px(lane.polygon()))
        left = resample_polyline(lane.left_lane_boundary, n_pts)
        right = resample_polyline(lane.right_lane_boundary, n_pts)
        centre = 0.5 * (left + right)
        step = np.diff(centre[:, :2], axis=0)
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        unit = np.where(norm > 1e-6, step / np.maximum(norm, 1e-6), 0.0)
        enc = np.round(128 + 127 * unit).astype(int)
        quads = np.stack([left[:-1], left[1:], right[1:], right[:-1]], axis=1)  # (n-1, 4, 3)
        for quad, (ex, ey) in zip(px(quads), enc):
            cv2.fillConvexPoly(dir_x, quad, int(ex), lineType=cv2.LINE_8, shift=_SHIFT)
            cv2.fillConvexPoly(dir_y, quad, int(ey), lineType=cv2.LINE_8, shift=_SHIFT)
    if lines:
        cv2.polylines(boundary, lines, False, 255, thickness=1, lineType=cv2.LINE_8, shift=_SHIFT)
    if junction:
        for poly in junction:  # one call each: fillPoly over several polygons drops their overlaps
            cv2.fillPoly(intersection, [poly], 255, lineType=cv2.LINE_8, shift=_SHIFT)
    layers = np.stack([drivable, boundary, dir_x, dir_y, crossing, intersection], axis=-1)
    return CityRaster(layers, origin, resolution_m)


def warp_city_map(raster: CityRaster, grid: BevGrid, city_SE3_ego: NDArray[np.floating]) -> NDArray[np.uint8]:
    """Map layers in the ego grid of each frame.

    Args:
        raster: the log's city-frame raster.
        grid: the ego grid.
        city_SE3_ego: (F, 4, 4) ego poses.

    Returns:
        (F, C, H, W) uint8 layers; lane directions are rotated into each frame's ego frame.
    """
    poses = np.asarray(city_SE3_ego, dtype=np.float64)
    num_frames = poses.shape[0]
    h, w = grid.height_px, grid.width_px
    c = raster.layers.shape[2]
    out = np.zeros((num_frames, c, h, w), dtype=np.uint8)
    res_g, res_c = grid.resolution_m, raster.resolution_m
    for f in range(num_frames):
        rot, trans = poses[f, :2, :2], poses[f, :2, 3]
        # Grid pixel (col, row) → ego xy: x = x_max − (row + .5)·res, y = y_max − (col + .5)·res.
        ego_from_px = np.array(
            [[0.0, -res_g, grid.x_max_m - 0.5 * res_g], [-res_g, 0.0, grid.y_max_m - 0.5 * res_g]]
        )
        city_from_px = rot @ ego_from_px
        city_from_px[:, 2] += trans
        # City xy → raster pixel (col, row): (p − origin)/res − 0.5.
        src_from_px = city_from_px / res_c
        src_from_px[:, 2] -= raster.origin_xy_m / res_c + 0.5
        out[f] = np.moveaxis(
            cv2.warpAffine(
                raster.layers, src_from_px, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0
            ),
            -1,
            0,
        )
    # Rotate the lane directions from the city frame into each ego frame.
    ix, iy = MAP_CHANNELS.index("lane_direction_x"), MAP_CHANNELS.index("lane_direction_y")
    inside = out[:, ix] > 0
    dx = (out[:, ix].astype(np.float32) - 128.0) / 127.0
    dy = (out[:, iy].astype(np.float32) - 128.0) / 127.0
    cos, sin = poses[:, 0, 0][:, None, None], poses[:, 1, 0][:, None, None]
    ex = cos * dx + sin * dy  # R^T d
    ey = -sin * dx + cos * dy
    out[:, ix] = np.where(inside, np.clip(np.round(128 + 127 * ex), 1, 255), 0).astype(np.uint8)
    out[:, iy] = np.where(inside, np.clip(np.round(128 + 127 * ey), 1, 255), 0).astype(np.uint8)
    return out
