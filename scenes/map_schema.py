"""Checks of a log's vector map against the log contract: plausible coordinates, and a map that is the
log's own (near its ego poses). Like :mod:`scenes.schema`'s, each returns the problems it finds, each
naming the file, the map element's key and the point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scenes.errors import Problem
from scenes.map import VectorMap
from scenes.schema import MAX_CITY_COORDINATE_M

#: Farthest a map point may lie from the box of the log's ego positions (AV2 crops a log's map to
#: its route; a whole simulated city spans a few km), in metres.
MAX_MAP_REACH_M = 20_000.0
#: A map covers an ego position with a vertex within about this distance (AV2 lane segments and
#: drivable-area outlines place vertices every few to a few tens of metres), in metres.
MAP_COVER_RADIUS_M = 100.0
#: Share of ego positions a log's own map covers at least; another log's map covers few or none.
MIN_MAP_COVERED_SHARE = 0.5


def _map_polylines(vector_map: VectorMap) -> list[tuple[str, NDArray[np.float64]]]:
    """Every polyline of the map, (N, 3) in the city frame, with the key that names it in the JSON."""
    polylines: list[tuple[str, NDArray[np.float64]]] = []
    for lane in vector_map.lane_segments.values():
        polylines.append((f"lane_segments[{lane.id}].left_lane_boundary", lane.left_lane_boundary))
        polylines.append((f"lane_segments[{lane.id}].right_lane_boundary", lane.right_lane_boundary))
    for crossing in vector_map.pedestrian_crossings.values():
        polylines.append((f"pedestrian_crossings[{crossing.id}].edge1", crossing.edge1))
        polylines.append((f"pedestrian_crossings[{crossing.id}].edge2", crossing.edge2))
    for area in vector_map.drivable_areas.values():
        polylines.append((f"drivable_areas[{area.id}].area_boundary", area.area_boundary))
    return polylines


def check_map_covers_poses(path: Path, vector_map: VectorMap, city_xy_m: NDArray[np.floating]) -> list[Problem]:
    """A map that is not the log's: a vertex farther than :data:`MAX_MAP_REACH_M` from every ego
    position (a point typed in the wrong unit or city), or a map near too few of the ego's positions
    (another log's map): fewer than :data:`MIN_MAP_COVERED_SHARE` of them within
    :data:`MAP_COVER_RADIUS_M` of a map vertex. ``city_xy_m``: (T, 2) ego positions."""
    polylines = _map_polylines(vector_map)
    ego = np.asarray(city_xy_m, dtype=np.float64).reshape(-1, 2)
    if not polylines or ego.shape[0] == 0:
        return []
    vertices = np.concatenate([p[:, :2] for _, p in polylines])  # (V, 2), every polyline's in turn
    lo, hi = ego.min(axis=0), ego.max(axis=0)
    # Distance to the box of the ego positions: a lower bound of the distance to the nearest one.
    gap_m = np.linalg.norm(np.maximum(np.maximum(lo - vertices, vertices - hi), 0.0), axis=1)
    if (far := gap_m > MAX_MAP_REACH_M).any():
        first = int(np.argmax(far))
        starts = np.cumsum([0] + [p.shape[0] for _, p in polylines])
        line = int(np.searchsorted(starts, first, side="right")) - 1
        name, row = polylines[line][0], first - int(starts[line])
        point = f"({vertices[first, 0]:.6g}, {vertices[first, 1]:.6g}) m"
        return [Problem(path, f"point {point} lies {gap_m[first] / 1000:.0f} km from every ego pose (maps reach "
                              f"at most {MAX_MAP_REACH_M / 1000:g} km from the log's route)", field=name, row=row)]
    # A grid of cells MAP_COVER_RADIUS_M wide: a position within the radius of a vertex has one in its
    # own cell or a neighbouring one, so checking the 3 × 3 cells around each position is exact enough.
    cells = np.unique(_cell_codes(np.floor(vertices / MAP_COVER_RADIUS_M).astype(np.int64)))
    ego_cells = np.floor(ego / MAP_COVER_RADIUS_M).astype(np.int64)
    covered = np.zeros(ego.shape[0], dtype=bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            covered |= np.isin(_cell_codes(ego_cells + np.array([di, dj])), cells)
    if covered.mean() >= MIN_MAP_COVERED_SHARE:
        return []
    return [Problem(path, f"the map is not this log's: only {int(covered.sum())} of {covered.shape[0]} ego poses lie "
                          f"within about {MAP_COVER_RADIUS_M:g} m of its lanes, crossings or drivable areas "
                          f"(the first pose is at ({ego[0, 0]:.1f}, {ego[0, 1]:.1f}) m; the map spans "
                          f"x {vertices[:, 0].min():.0f}..{vertices[:, 0].max():.0f} m, "
                          f"y {vertices[:, 1].min():.0f}..{vertices[:, 1].max():.0f} m)")]


def _cell_codes(cells: NDArray[np.int64]) -> NDArray[np.int64]:
    """(N, 2) integer cells → (N,) one integer each (cells within ±2³¹ of the origin: 200,000 km here)."""
    return (cells[:, 0] << 32) + cells[:, 1]


def check_map_coordinates(path: Path, vector_map: VectorMap) -> list[Problem]:
    """NaN, inf or implausible (beyond :data:`MAX_CITY_COORDINATE_M`) coordinates in the map's
    polylines; names the element's key and the point."""
    problems = []
    for name, points in _map_polylines(vector_map):
        finite = np.isfinite(points)
        if not finite.all():
            problems.append(Problem(path, "NaN or inf coordinate", field=name, row=int(np.argmax(~finite.all(axis=1)))))
            continue
        far = np.abs(points) > MAX_CITY_COORDINATE_M
        if far.any():
            row, axis = (int(i) for i in np.argwhere(far)[0])
            problems.append(Problem(path, f"{'xyz'[axis]} = {points[row, axis]:.6g} m is beyond the bound of "
                                    f"±{MAX_CITY_COORDINATE_M:g} m for city-frame coordinates", field=name, row=row))
    return problems


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose keys are unique: a lane id given twice would silently replace the first lane."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"key {key!r} appears twice in one object (two map elements with one id?)")
        out[key] = value
    return out
