"""The road surface between lanes and kerbs, as polygons: lane polygons grown outward on a grid until
a road edge (or a reach limit) stops them.

Each connected piece becomes one outline; a hole in it (a traffic island enclosed by road edges)
is joined to the outline by a zero-width cut, so that filling the outline, as the BEV rasteriser
and the ground raster do (one polygon per call), leaves the hole out.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from scenes.geometry import FloatArray

#: The road surface reaches this far beyond the lanes unless a road edge comes first.
DRIVABLE_REACH_M = 5.0
DRIVABLE_RESOLUTION_M = 0.5
#: A huge map is coarsened rather than refused: at most this many grid cells.
_MAX_CELLS = 16e6


def _splice_holes(outline: NDArray[np.float64], holes: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """One polygon from an outline and its holes, each hole joined by a zero-width cut between the
    closest pair of vertices. Filled (even-odd or non-zero) it leaves the holes out.

    ``outline``: (N, 2); each hole: (M, 2). Returns (N + Σ(M + 2), 2).
    """
    polygon = outline
    for hole in holes:
        dist, nearest = cKDTree(hole).query(polygon)  # (N,) each: the closest hole vertex
        i = int(np.argmin(dist))
        j = int(nearest[i])
        polygon = np.concatenate([polygon[: i + 1], hole[j:], hole[: j + 1], polygon[i:]])
    return polygon


def drivable_polygons(
    lane_polygons: list[FloatArray],
    road_edges: list[FloatArray],
    reach_m: float = DRIVABLE_REACH_M,
    resolution_m: float = DRIVABLE_RESOLUTION_M,
) -> list[FloatArray]:
    """Road surface outlines: lane polygons grown by up to ``reach_m``, the growth stopped by road edges.

    Args:
        lane_polygons: (N, 2) outlines of the lanes, city frame.
        road_edges: (M, 2) road-edge polylines, city frame.
        reach_m: how far beyond the lanes the surface may reach.
        resolution_m: grid cell size.

    Returns:
        (K, 2) outlines, city frame, holes joined in by zero-width cuts.
    """
    lanes = [p for p in lane_polygons if p.shape[0] >= 3]
    if not lanes:
        return []
    allpts = np.concatenate(lanes)
    margin = reach_m + 2 * resolution_m
    x0, y0 = allpts.min(axis=0) - margin
    x1, y1 = allpts.max(axis=0) + margin
    res = max(resolution_m, float(np.sqrt((x1 - x0) * (y1 - y0) / _MAX_CELLS)))
    width, height = int(np.ceil((x1 - x0) / res)) + 1, int(np.ceil((y1 - y0) / res)) + 1
    shift = 4

    def to_px(xy: FloatArray) -> NDArray[np.int32]:
        return np.round((xy - [x0, y0]) / res * (1 << shift)).astype(np.int32)

    surface = np.zeros((height, width), np.uint8)
    for poly in lanes:  # one call each: fillPoly with several polygons fills by the even-odd rule
        cv2.fillPoly(surface, [to_px(poly)], 1, lineType=cv2.LINE_8, shift=shift)
    walls = np.zeros_like(surface)
    edges = [to_px(e) for e in road_edges if e.shape[0] >= 2]
    if edges:
        # An 8-connected line cannot be crossed by 4-connected growth (the cross kernel below).
        cv2.polylines(walls, edges, False, 1, thickness=1, lineType=cv2.LINE_8, shift=shift)
    open_cells = (walls == 0).astype(np.uint8)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    for _ in range(round(reach_m / res)):
        surface = np.maximum(surface, cv2.dilate(surface, cross) & open_cells)
    contours, hierarchy = cv2.findContours(surface, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return []
    links = hierarchy[0]  # (C, 4): next, previous, first child, parent

    def to_city(contour: NDArray[Any]) -> NDArray[np.float64]:
        simple = cv2.approxPolyDP(contour, 0.5, True).reshape(-1, 2).astype(np.float64)
        return np.asarray(simple * res + [x0, y0], dtype=np.float64)

    result = []
    for c, contour in enumerate(contours):
        if links[c][3] != -1 or contour.shape[0] < 3:
            continue
        holes, child = [], int(links[c][2])
        while child != -1:
            if contours[child].shape[0] >= 3:
                holes.append(to_city(contours[child]))
            child = int(links[child][0])
        outline = to_city(contour)
        if outline.shape[0] >= 3:
            result.append(_splice_holes(outline, holes))
    return result
