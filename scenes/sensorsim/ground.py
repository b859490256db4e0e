"""The ground of the static world: a city-frame raster of materials (road, lane paint, crosswalk
stripes, sidewalk, terrain) built from the vector map, and the kerbs along the drivable area.

The materials give LiDAR intensities and the camera's ground texture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.geometry import FloatArray
from scenes.map import VectorMap, resample_polyline
from scenes.sensorsim.config import WorldConfig

#: Cells of the ground raster are capped at this many; a larger world gets coarser cells.
MAX_RASTER_CELLS = 20_000_000


class GroundMaterial(IntEnum):
    """Codes of the ground material raster."""

    TERRAIN = 0
    SIDEWALK = 1
    ROAD = 2
    WHITE_PAINT = 3
    YELLOW_PAINT = 4
    CROSSWALK = 5


#: LiDAR reflectivity (0–255) of each ground material.
GROUND_REFLECTIVITY = np.array([25.0, 45.0, 14.0, 120.0, 110.0, 115.0])


@dataclass(frozen=True)
class GroundRaster:
    """Ground materials on a city-frame grid.

    Cell ``[row, col]`` covers city ``x = origin_x_m + (col + 0.5) · resolution_m`` and
    ``y = origin_y_m + (row + 0.5) · resolution_m`` (rows grow with y; it is a texture, not a picture).

    Attributes:
        origin_x_m: city x of the grid's lower edge.
        origin_y_m: city y of the grid's lower edge.
        resolution_m: cell size.
        material: (H, W) :class:`GroundMaterial` codes, uint8.
        drivable: (H, W) whether the cell lies on the drivable area.
    """

    origin_x_m: float
    origin_y_m: float
    resolution_m: float
    material: NDArray[np.uint8]
    drivable: NDArray[np.bool_]

    def city_to_cell(self, xy_m: FloatArray) -> FloatArray:
        """(N, 2) continuous (col, row) of (N, 2) city points."""
        xy = np.asarray(xy_m, dtype=np.float64)
        return np.stack([(xy[:, 0] - self.origin_x_m) / self.resolution_m - 0.5,
                         (xy[:, 1] - self.origin_y_m) / self.resolution_m - 0.5], axis=1)

    def material_at(self, xy_m: FloatArray) -> NDArray[np.uint8]:
        """(N,) material of the cells holding (N, 2) city points (terrain outside the grid)."""
        h, w = self.material.shape
        cr = np.floor(self.city_to_cell(xy_m) + 0.5).astype(np.int64)
        inside = (cr[:, 0] >= 0) & (cr[:, 0] < w) & (cr[:, 1] >= 0) & (cr[:, 1] < h)
        out = np.full(cr.shape[0], GroundMaterial.TERRAIN, dtype=np.uint8)
        out[inside] = self.material[cr[inside, 1], cr[inside, 0]]
        return out


_SHIFT = 3  # sub-pixel bits for OpenCV drawing


def _to_px(raster_origin: tuple[float, float], resolution_m: float, xy_m: FloatArray) -> NDArray[np.int32]:
    """City points to fixed-point pixel coordinates (col, row) for OpenCV drawing with ``_SHIFT``."""
    px = (np.asarray(xy_m)[:, :2] - np.asarray(raster_origin)) / resolution_m - 0.5
    return np.round(px * (1 << _SHIFT)).astype(np.int32)


def _dash_pieces(points: FloatArray, dash_m: float, gap_m: float) -> list[FloatArray]:
    """Cut a polyline into dashes of ``dash_m`` separated by ``gap_m``."""
    seg = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1)
    total = float(seg.sum())
    if total <= 0:
        return []
    samples = resample_polyline(points, max(2, int(total / 0.5) + 1))
    arc = np.linspace(0.0, total, samples.shape[0])
    phase = np.mod(arc, dash_m + gap_m) < dash_m
    pieces = []
    edges = np.flatnonzero(np.diff(np.r_[0, phase.astype(np.int8), 0]))
    for start, stop in zip(edges[::2], edges[1::2]):
        if stop - start >= 2:
            pieces.append(samples[start:stop])
    return pieces


def build_ground_raster(vector_map: VectorMap | None, extent_xy_m: tuple[float, float, float, float],
                        config: WorldConfig) -> GroundRaster:
    """Rasterise the map's ground materials over ``extent_xy_m`` = (x_min, y_min, x_max, y_max)."""
    x_min, y_min, x_max, y_max = extent_xy_m
    res = config.raster_resolution_m
    area = (x_max - x_min) * (y_max - y_min)
    res = max(res, math.sqrt(area / MAX_RASTER_CELLS))
    w = max(1, math.ceil((x_max - x_min) / res))
    h = max(1, math.ceil((y_max - y_min) / res))
    origin = (x_min, y_min)
    drivable = np.zeros((h, w), np.uint8)
    material = np.full((h, w), GroundMaterial.TERRAIN, np.uint8)
    if vector_map is not None:
        polys = [_to_px(origin, res, a.area_boundary) for a in vector_map.drivable_areas.values()
                 if a.area_boundary.shape[0] >= 3]
        polys += [_to_px(origin, res, s.polygon()) for s in vector_map.lane_segments.values()]
        for poly in polys:  # one call each: fillPoly with several polygons fills by the even-odd rule
            cv2.fillPoly(drivable, [poly], 1, lineType=cv2.LINE_8, shift=_SHIFT)
    if config.sidewalk_width_m > 0:
        dist_px = cv2.distanceTransform((drivable == 0).astype(np.uint8), cv2.DIST_L2, 5)
        material[(dist_px * res <= config.sidewalk_width_m) & (drivable == 0)] = GroundMaterial.SIDEWALK
    material[drivable > 0] = GroundMaterial.ROAD
    if vector_map is not None:
        stripes = []
        for crossing in vector_map.pedestrian_crossings.values():
            # Zebra bars run along the traffic, from edge1 to edge2, spaced along the edges (which
            # follow the walking direction across the road): 0.6 m bars, 0.6 m gaps.
            e1, e2 = crossing.edge1[[0, -1], :2], crossing.edge2[[0, -1], :2]
            length = float(np.linalg.norm(e1[1] - e1[0]))
            n = max(1, int(length / 1.2))
            f0 = (np.arange(n) + 0.25) / n
            f1 = (np.arange(n) + 0.75) / n
            a0 = e1[0] + f0[:, None] * (e1[1] - e1[0])
            a1 = e1[0] + f1[:, None] * (e1[1] - e1[0])
            b0 = e2[0] + f0[:, None] * (e2[1] - e2[0])
            b1 = e2[0] + f1[:, None] * (e2[1] - e2[0])
            quads = np.stack([a0, a1, b1, b0], axis=1)  # (n, 4, 2)
            stripes += [_to_px(origin, res, q) for q in quads]
        for stripe in stripes:
            cv2.fillConvexPoly(material, stripe, int(GroundMaterial.CROSSWALK), lineType=cv2.LINE_8, shift=_SHIFT)
        thickness = max(1, round(config.lane_mark_width_m / res))
        lines: dict[int, list[NDArray[np.int32]]] = {GroundMaterial.WHITE_PAINT: [], GroundMaterial.YELLOW_PAINT: []}
        for seg in vector_map.lane_segments.values():
            if seg.is_intersection:
                continue
            for boundary, mark in ((seg.left_lane_boundary, seg.left_lane_mark_type),
                                   (seg.right_lane_boundary, seg.right_lane_mark_type)):
                if mark in ("NONE", "UNKNOWN", "") or boundary.shape[0] < 2:
                    continue
                code = int(GroundMaterial.YELLOW_PAINT if "YELLOW" in mark else GroundMaterial.WHITE_PAINT)
                pieces = _dash_pieces(boundary, 3.0, 6.0) if "DASHED" in mark and "SOLID" not in mark else [boundary]
                lines[code] += [_to_px(origin, res, p) for p in pieces]
        for code, polylines in lines.items():
            if polylines:
                cv2.polylines(material, polylines, False, int(code), thickness=thickness, lineType=cv2.LINE_8,
                              shift=_SHIFT)
    return GroundRaster(float(x_min), float(y_min), float(res), material, drivable.astype(bool))


def kerb_segments(raster: GroundRaster) -> FloatArray:
    """(S, 2, 2) city-frame segments along the edges of the drivable area (not along the grid border)."""
    contours, _ = cv2.findContours(raster.drivable.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    h, w = raster.drivable.shape
    eps_px = max(0.5, 0.3 / raster.resolution_m)
    segments = []
    for contour in contours:
        poly = cv2.approxPolyDP(contour, eps_px, True).reshape(-1, 2).astype(np.float64)
        if poly.shape[0] < 2:
            continue
        a, b = poly, np.roll(poly, -1, axis=0)
        on_border = ((a[:, 0] <= 1) & (b[:, 0] <= 1)) | ((a[:, 0] >= w - 2) & (b[:, 0] >= w - 2)) | (
            (a[:, 1] <= 1) & (b[:, 1] <= 1)) | ((a[:, 1] >= h - 2) & (b[:, 1] >= h - 2))
        segments.append(np.stack([a[~on_border], b[~on_border]], axis=1))
    if not segments:
        return np.zeros((0, 2, 2))
    px = np.concatenate(segments)
    return np.stack([raster.origin_x_m + (px[..., 0] + 0.5) * raster.resolution_m,
                     raster.origin_y_m + (px[..., 1] + 0.5) * raster.resolution_m], axis=-1)
