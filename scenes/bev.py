"""Bird's-eye-view (BEV) rasters in the ego frame: boxes, map layers and LiDAR point counts.

Image convention of every raster (H rows × W columns)::

        column 0 = y_max (left)          column W−1 = y_min (right)
    row 0   +------------------------------------+   x = x_max (ahead)
            |                 ^ x                 |
            |                 |                   |
            |           y <---+ ego               |
            |                                     |
    row H−1 +------------------------------------+   x = x_min (behind)

Cell ``[r, c]`` is centred on ego ``x = x_max − (r + 0.5)·res``, ``y = y_max − (c + 0.5)·res``;
forward is up and left is left, as a driver sees a map. A cell belongs to a box (or a polygon) when
its centre does; with ``coverage=True`` boxes give the fraction of each cell they cover.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.geometry import SE3, FloatArray
from scenes.map import VectorMap

MAP_LAYERS: tuple[str, ...] = (
    "drivable_area",
    "lane_boundaries",
    "lane_direction_cos",
    "lane_direction_sin",
    "crosswalks",
    "intersections",
)
_SHIFT = 4  # sub-pixel bits for OpenCV polygon filling


@dataclass(frozen=True)
class BevGrid:
    """A BEV grid in the ego frame (see the module docstring for the image convention).

    Attributes:
        x_min_m: rear edge.
        x_max_m: front edge (row 0).
        y_min_m: right edge (last column).
        y_max_m: left edge (column 0).
        resolution_m: cell size.
    """

    x_min_m: float = -20.0
    x_max_m: float = 60.0
    y_min_m: float = -20.0
    y_max_m: float = 20.0
    resolution_m: float = 0.5

    def __post_init__(self) -> None:
        if not (self.x_max_m > self.x_min_m and self.y_max_m > self.y_min_m and self.resolution_m > 0):
            raise ValueError(f"BevGrid needs x_max > x_min, y_max > y_min and resolution > 0, got {self}")

    @property
    def height(self) -> int:
        """Rows (along x)."""
        return round((self.x_max_m - self.x_min_m) / self.resolution_m)

    @property
    def width(self) -> int:
        """Columns (along y)."""
        return round((self.y_max_m - self.y_min_m) / self.resolution_m)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    def ego_to_pixel(self, xy_m: NDArray[np.floating]) -> FloatArray:
        """(N, 2) continuous (column, row) of (N, 2) ego points; integer values are cell centres."""
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        return np.stack([(self.y_max_m - xy[:, 1]) / self.resolution_m - 0.5,
                         (self.x_max_m - xy[:, 0]) / self.resolution_m - 0.5], axis=1)

    def cell_centers_xy(self) -> FloatArray:
        """(H, W, 2) ego (x, y) of every cell centre."""
        rows = self.x_max_m - (np.arange(self.height) + 0.5) * self.resolution_m
        cols = self.y_max_m - (np.arange(self.width) + 0.5) * self.resolution_m
        x, y = np.meshgrid(rows, cols, indexing="ij")
        return np.stack([x, y], axis=-1)


def box_samples(grid: BevGrid, centers_xy: FloatArray, sizes_lw: FloatArray, yaws: FloatArray,
                supersample: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Sub-cell samples inside each box: (box index, sample row, sample column) on the supersampled grid.

    Vectorised over boxes with a padded window as large as the largest box.
    """
    n = centers_xy.shape[0]
    s = supersample
    step = grid.resolution_m / s
    half_diag = 0.5 * np.hypot(sizes_lw[:, 0], sizes_lw[:, 1])
    radius = math.ceil(float(half_diag.max()) / step) + 1
    # Window of sample offsets around each box centre's nearest sample.
    center_px = np.stack([(grid.y_max_m - centers_xy[:, 1]) / step - 0.5,
                          (grid.x_max_m - centers_xy[:, 0]) / step - 0.5], axis=1)  # (N, 2) col, row
    base = np.round(center_px).astype(np.int64)
    offsets = np.arange(-radius, radius + 1)
    chunk = max(1, int(4_000_000 // offsets.size ** 2))
    out_b, out_r, out_c = [], [], []
    hs, ws = grid.height * s, grid.width * s
    for lo in range(0, n, chunk):
        sl = slice(lo, min(n, lo + chunk))
        cols = base[sl, 0, None, None] + offsets[None, None, :]  # (n, 1, K)
        rows = base[sl, 1, None, None] + offsets[None, :, None]  # (n, K, 1)
        x = grid.x_max_m - (rows + 0.5) * step
        y = grid.y_max_m - (cols + 0.5) * step
        dx, dy = x - centers_xy[sl, 0, None, None], y - centers_xy[sl, 1, None, None]
        c, sn = np.cos(yaws[sl])[:, None, None], np.sin(yaws[sl])[:, None, None]
        lx, ly = c * dx + sn * dy, -sn * dx + c * dy
        inside = (np.abs(lx) <= 0.5 * sizes_lw[sl, 0, None, None]) & (np.abs(ly) <= 0.5 * sizes_lw[sl, 1, None, None])
        rows_b = np.broadcast_to(rows, inside.shape)
        cols_b = np.broadcast_to(cols, inside.shape)
        inside &= (rows_b >= 0) & (rows_b < hs) & (cols_b >= 0) & (cols_b < ws)
        b, i, j = np.nonzero(inside)
        out_b.append(b + lo)
        out_r.append(rows_b[b, i, j])
        out_c.append(cols_b[b, i, j])
    return np.concatenate(out_b), np.concatenate(out_r), np.concatenate(out_c)


def rasterize_boxes(
    grid: BevGrid,
    centers_xy: NDArray[np.floating],
    sizes_lw: NDArray[np.floating],
    yaws: NDArray[np.floating],
    values: NDArray[np.floating] | None = None,
    coverage: bool = False,
    supersample: int = 4,
) -> NDArray[np.float32]:
    """Rasterise upright boxes given in the ego frame.

    Args:
        grid: the BEV grid.
        centers_xy: (N, 2) box centres in the ego frame.
        sizes_lw: (N, 2) box length (along the box heading) and width.
        yaws: (N,) box headings in the ego frame.
        values: (N,) value written into each box's cells (default 1); where boxes overlap, the later
            box in the input order wins. Ignored with ``coverage``.
        coverage: return the fraction of each cell covered by the union of the boxes, from
            ``supersample`` × ``supersample`` samples per cell.
        supersample: samples per cell side for ``coverage``.

    Returns:
        (H, W) float32 raster.
    """
    centers = np.asarray(centers_xy, dtype=np.float64).reshape(-1, 2)
    sizes = np.asarray(sizes_lw, dtype=np.float64).reshape(-1, 2)
    yaw = np.asarray(yaws, dtype=np.float64).reshape(-1)
    n = centers.shape[0]
    if sizes.shape[0] != n or yaw.shape[0] != n:
        raise ValueError(f"rasterize_boxes: {n} centres, {sizes.shape[0]} sizes and {yaw.shape[0]} yaws differ")
    out = np.zeros(grid.shape, np.float32)
    if n == 0:
        return out
    if coverage:
        s = int(supersample)
        b, r, c = box_samples(grid, centers, sizes, yaw, s)
        fine = np.zeros((grid.height * s, grid.width * s), dtype=np.float32)
        fine[r, c] = 1.0
        return np.asarray(fine.reshape(grid.height, s, grid.width, s).mean(axis=(1, 3)), dtype=np.float32)
    vals = np.ones(n, np.float32) if values is None else np.asarray(values, dtype=np.float32).reshape(-1)
    if vals.shape[0] != n:
        raise ValueError(f"rasterize_boxes: {n} boxes but {vals.shape[0]} values")
    b, r, c = box_samples(grid, centers, sizes, yaw, 1)
    winner = np.full(grid.shape, -1, dtype=np.int64)
    np.maximum.at(winner, (r, c), b)
    hit = winner >= 0
    out[hit] = vals[winner[hit]]
    return out


class MapRasterizer:
    """Rasterises a vector map's layers around any ego pose; build once per map, call per frame.

    Layers (all (H, W) float32):

    - ``drivable_area``: 1 on drivable areas and lanes.
    - ``lane_boundaries``: 1 on lane boundary lines (one cell wide).
    - ``lane_direction_cos`` / ``lane_direction_sin``: on lanes, the cosine and sine of the heading
      of the nearest lane centre line, in the ego frame; 0 elsewhere.
    - ``crosswalks``: 1 on pedestrian crossings.
    - ``intersections``: 1 on lanes inside junctions.
    """

    def __init__(self, vector_map: VectorMap, centerline_step_m: float = 1.0) -> None:
        self.vector_map = vector_map
        areas = [a.area_boundary[:, :2] for a in vector_map.drivable_areas.values() if a.area_boundary.shape[0] >= 3]
        lanes = list(vector_map.lane_segments.values())
        self._lanes = [s.polygon()[:, :2] for s in lanes]
        self._drivable = areas + self._lanes
        self._boundaries = [b[:, :2] for s in lanes for b in (s.left_lane_boundary, s.right_lane_boundary)]
        self._crosswalks = [c.polygon()[:, :2] for c in vector_map.pedestrian_crossings.values()]
        self._intersections = [p for p, s in zip(self._lanes, lanes, strict=True) if s.is_intersection]
        self._lane_segments = lanes
        self._centerline_step_m = centerline_step_m
        self._centerlines: dict[int, tuple[FloatArray, FloatArray]] = {}  # computed for the lanes a raster reaches
        self._bounds = {name: self._poly_bounds(polys) for name, polys in (
            ("drivable", self._drivable), ("boundaries", self._boundaries), ("crosswalks", self._crosswalks),
            ("intersections", self._intersections), ("lanes", self._lanes))}

    @staticmethod
    def _poly_bounds(polys: list[FloatArray]) -> FloatArray:
        if not polys:
            return np.zeros((0, 4))
        points = np.concatenate(polys)  # (V, 2), polygon after polygon
        starts = np.cumsum([0] + [p.shape[0] for p in polys[:-1]])
        return np.concatenate([np.minimum.reduceat(points, starts), np.maximum.reduceat(points, starts)], axis=1)

    def _near_indices(self, name: str, center: FloatArray, radius: float) -> NDArray[np.intp]:
        """Indices of the polygons of ``name`` whose bounding boxes reach the square ``center ± radius``."""
        bounds = self._bounds[name]
        if bounds.shape[0] == 0:
            return np.zeros(0, np.intp)
        keep = (bounds[:, 0] <= center[0] + radius) & (bounds[:, 2] >= center[0] - radius) & (
            bounds[:, 1] <= center[1] + radius) & (bounds[:, 3] >= center[1] - radius)
        return np.flatnonzero(keep)

    def _near(self, name: str, polys: list[FloatArray], center: FloatArray, radius: float) -> list[FloatArray]:
        return [polys[i] for i in self._near_indices(name, center, radius)]

    def _centerline_samples(self, center: FloatArray, radius: float) -> tuple[FloatArray, FloatArray]:
        """(M, 2) lane centre-line samples within ``radius`` of ``center`` (city frame) and their (M,)
        headings, in lane order. Each lane is sampled once, when a raster first reaches it: a city's
        map holds far more lanes than one log's rasters touch."""
        points, headings = [], []
        for i in self._near_indices("lanes", center, radius):  # a lane's centre line lies in its box
            if i not in self._centerlines:
                lane = self._lane_segments[i]
                length = float(np.linalg.norm(np.diff(lane.left_lane_boundary[:, :2], axis=0), axis=1).sum())
                line = lane.centerline(max(2, int(length / self._centerline_step_m) + 1))[:, :2]
                tangent = np.gradient(line, axis=0)
                self._centerlines[i] = line, np.arctan2(tangent[:, 1], tangent[:, 0])
            points.append(self._centerlines[i][0])
            headings.append(self._centerlines[i][1])
        if not points:
            return np.zeros((0, 2)), np.zeros(0)
        pts, heads = np.concatenate(points), np.concatenate(headings)
        near = np.linalg.norm(pts - center, axis=1) <= radius
        return pts[near], heads[near]

    def rasterize(self, grid: BevGrid, city_SE3_ego: SE3 | NDArray[np.floating]) -> dict[str, NDArray[np.float32]]:
        """All :data:`MAP_LAYERS` around ``city_SE3_ego`` (an :class:`SE3` or a (4, 4) matrix)."""
        if not isinstance(city_SE3_ego, SE3):
            city_SE3_ego = SE3.from_matrix(city_SE3_ego)
        ego_SE3_city = city_SE3_ego.inverse()
        rot2 = np.ascontiguousarray(ego_SE3_city.rotation[:2, :2].T)
        trans2 = ego_SE3_city.translation[:2]
        corners = np.array([[grid.x_min_m, grid.y_min_m], [grid.x_max_m, grid.y_max_m]])
        mid = corners.mean(axis=0)
        center_city = city_SE3_ego.transform_points(np.array([[mid[0], mid[1], 0.0]]))[0, :2]
        radius = 0.5 * float(np.linalg.norm(corners[1] - corners[0])) + grid.resolution_m

        def to_px(poly_city: FloatArray) -> NDArray[np.int32]:
            ego = poly_city @ rot2 + trans2
            return np.round(grid.ego_to_pixel(ego) * (1 << _SHIFT)).astype(np.int32)

        def fill(name: str, polys: list[FloatArray]) -> NDArray[np.float32]:
            canvas = np.zeros(grid.shape, np.uint8)
            for poly in self._near(name, polys, center_city, radius):  # one call each: no even-odd holes
                cv2.fillPoly(canvas, [to_px(poly)], 1, lineType=cv2.LINE_8, shift=_SHIFT)
            return canvas.astype(np.float32)

        layers = {
            "drivable_area": fill("drivable", self._drivable),
            "crosswalks": fill("crosswalks", self._crosswalks),
            "intersections": fill("intersections", self._intersections),
        }
        lines = np.zeros(grid.shape, np.uint8)
        near_lines = [to_px(b) for b in self._near("boundaries", self._boundaries, center_city, radius)]
        if near_lines:
            cv2.polylines(lines, near_lines, False, 1, thickness=1, lineType=cv2.LINE_8, shift=_SHIFT)
        layers["lane_boundaries"] = lines.astype(np.float32)
        on_lane = fill("lanes", self._lanes) > 0
        cos_l = np.zeros(grid.shape, np.float32)
        sin_l = np.zeros(grid.shape, np.float32)
        if on_lane.any():
            cells_ego = grid.cell_centers_xy()[on_lane]  # (M, 2)
            cells_city = city_SE3_ego.transform_points(np.c_[cells_ego, np.zeros(len(cells_ego))])[:, :2]
            pts, heads = self._centerline_samples(center_city, radius + 10.0)
            if pts.shape[0]:
                from scipy.spatial import cKDTree

                _, nearest = cKDTree(pts).query(cells_city)
                heading_ego = heads[nearest] - city_SE3_ego.yaw_rad
                cos_l[on_lane] = np.cos(heading_ego)
                sin_l[on_lane] = np.sin(heading_ego)
        layers["lane_direction_cos"] = cos_l
        layers["lane_direction_sin"] = sin_l
        return {name: layers[name] for name in MAP_LAYERS}


def rasterize_map(grid: BevGrid, vector_map: VectorMap,
                  city_SE3_ego: SE3 | NDArray[np.floating]) -> dict[str, NDArray[np.float32]]:
    """Map layers around one pose (see :class:`MapRasterizer`; use it directly for many frames)."""
    return MapRasterizer(vector_map).rasterize(grid, city_SE3_ego)


def count_points(
    grid: BevGrid, z_bins_m: NDArray[np.floating], clouds: Sequence[tuple[NDArray[np.float32], FloatArray]]
) -> NDArray[np.int64]:
    """Count the points of several clouds per cell and height bin, each cloud moved into the grid's
    ego frame by its own pose (a frame's current sweep and the previous ones).

    Each cloud is moved and binned by one float32 product: the cell coordinates are folded into the
    pose, and cells are numbered from 1 so that whatever falls outside the grid or the height bins
    lands in a border that is cut off afterwards. No mask or gather runs over the points, which makes
    this several times faster than binning in float64 with masks; points within float32 rounding of a
    cell edge may land on either side of it.

    Args:
        grid: the BEV grid.
        z_bins_m: (Z + 1,) increasing height bin edges (ego frame), at most 255; points outside them
            are ignored.
        clouds: ``(xyz_m, ego_SE3_cloud)`` pairs: (3, N) float32 points in the cloud's frame, with
            coordinates as rows, and the (4, 4) pose of that frame in the ego frame. Points that are
            not finite are ignored.

    Returns:
        (Z, H, W) int64 point counts.
    """
    edges = np.asarray(z_bins_m, dtype=np.float64).reshape(-1)
    edges32 = edges.astype(np.float32)
    if not 2 <= edges.shape[0] <= 255 or np.any(np.diff(edges32) <= 0):  # bins are counted in uint8
        raise ValueError(f"z_bins_m must hold 2 to 255 increasing edges (as float32), got {edges.tolist()}")
    h, w = grid.shape
    padded_h, padded_w, padded_z = h + 2, w + 2, edges.shape[0] + 1
    # ego (x, y, z) → (row + 1, column + 1, z), rows and columns continuous (floored when counted)
    cells_SE3_ego = np.array([[-1.0 / grid.resolution_m, 0.0, 0.0, grid.x_max_m / grid.resolution_m + 1.0],
                              [0.0, -1.0 / grid.resolution_m, 0.0, grid.y_max_m / grid.resolution_m + 1.0],
                              [0.0, 0.0, 1.0, 0.0],
                              [0.0, 0.0, 0.0, 1.0]])
    flats = []
    for xyz_m, ego_SE3_cloud in clouds:
        cells_SE3_cloud = cells_SE3_ego @ ego_SE3_cloud
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite points are dropped just below
            cells = cells_SE3_cloud[:3, :3].astype(np.float32) @ xyz_m  # (3, N)
            cells += cells_SE3_cloud[:3, 3:].astype(np.float32)
        if not np.isfinite(cells).all():  # a NaN would turn into an arbitrary index; ±inf clip to the border
            cells[np.isnan(cells)] = -np.inf  # below every cell and every height bin: the border
        z_bin = np.zeros(cells.shape[1], dtype=np.uint8)  # 0 below the bins, Z + 1 above them
        for edge in edges32:
            np.add(z_bin, cells[2] >= edge, out=z_bin, casting="unsafe")
        flat = z_bin.astype(np.intp)
        flat *= padded_h
        flat += np.clip(cells[0], 0, h + 1).astype(np.intp)  # non-negative, so truncation floors
        flat *= padded_w
        flat += np.clip(cells[1], 0, w + 1).astype(np.intp)
        flats.append(flat)
    size = padded_z * padded_h * padded_w
    counts = np.bincount(np.concatenate(flats) if flats else np.zeros(0, np.intp), minlength=size)
    return counts.reshape(padded_z, padded_h, padded_w)[1:-1, 1:-1, 1:-1]


__all__ = [
    "MAP_LAYERS",
    "BevGrid",
    "MapRasterizer",
    "count_points",
    "rasterize_boxes",
    "rasterize_map",
]
