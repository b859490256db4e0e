"""Scene geometry for the sensor simulation.

The **static world** is built once per log from its vector map, in the city frame:

- a ground plane at the ego's ground height, with a material raster (road, lane paint, crosswalk
  stripes, sidewalk, terrain) that gives LiDAR intensities and the camera's ground texture;
- kerbs: low walls along the edges of the union of the drivable areas;
- building blocks on a lattice, kept ``building_setback_m`` away from the drivable area.

**Objects** are rebuilt every frame, in the ego frame, from their boxes: each category has its own
shape inside its box (cars: body and cabin; pedestrians: an octagonal prism; cyclists: a narrow
bicycle and a rider; trucks, buses and others: the box itself), so every surface point of a shape
lies inside (or on) the object's annotated box.

The world assumes flat ground (simulated logs are planar): the ground lies at the median height of
the ego origin over the log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from scenes.categories import Category
from scenes.geometry import FloatArray
from scenes.map import VectorMap, resample_polyline
from scenes.sensorsim.config import WorldConfig
from scenes.tracks import DenseTracks


def o3d_tensor(array: NDArray[np.generic]) -> o3d.core.Tensor:
    """An open3d tensor sharing a contiguous copy of ``array``."""
    return o3d.core.Tensor(np.ascontiguousarray(array))  # type: ignore[call-overload]


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


class StaticKind(IntEnum):
    """Geometry ids of the static ray-casting scene, in the order they are added."""

    GROUND = 0
    KERB = 1
    BUILDING = 2


#: LiDAR reflectivity (0–255) of each ground material.
GROUND_REFLECTIVITY = np.array([25.0, 45.0, 14.0, 120.0, 110.0, 115.0])
KERB_REFLECTIVITY = 55.0
BUILDING_REFLECTIVITY = 60.0


# ---------------------------------------------------------------------------------------------
# Object shapes


@dataclass(frozen=True)
class ShapeTemplate:
    """A shape inside the unit box [−0.5, 0.5]³, scaled by an object's (l, w, h).

    Attributes:
        vertices: (V, 3) vertices in unit-box coordinates.
        triangles: (F, 3) vertex indices, for ray casting.
        faces: convex polygons (vertex index tuples) in drawing order, for the camera.
        face_normals: (P, 3) outward unit normals of ``faces`` in unit-box coordinates (valid for
            any positive scaling since every face is axis-aligned or vertical).
        face_part: (P,) :class:`ShapePart` of each face (how the camera colours it).
    """

    vertices: FloatArray
    triangles: NDArray[np.int32]
    faces: tuple[tuple[int, ...], ...]
    face_normals: FloatArray
    face_part: NDArray[np.int64]


class ShapePart(IntEnum):
    """What a face of a shape is, for colouring. Lights are decals: drawn, never ray cast."""

    BODY = 0
    CABIN = 1
    RIDER = 2
    FRAME = 3
    HEADLIGHT = 4
    TAILLIGHT = 5


_BOX_CORNERS = np.array(
    [[sx, sy, sz] for sz in (-0.5, 0.5) for sy in (-0.5, 0.5) for sx in (-0.5, 0.5)], dtype=np.float64
)
# Corner index = ix + 2 iy + 4 iz. Faces wound counter-clockwise seen from outside.
_BOX_FACES = ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5))
_BOX_NORMALS = np.array([[0, 0, -1], [0, 0, 1], [0, -1, 0], [0, 1, 0], [-1, 0, 0], [1, 0, 0]], dtype=np.float64)


def _triangulate(faces: tuple[tuple[int, ...], ...]) -> NDArray[np.int32]:
    tris = [(f[0], f[i], f[i + 1]) for f in faces for i in range(1, len(f) - 1)]
    return np.array(tris, dtype=np.int32)


def _boxes_template(parts: list[tuple[tuple[float, float, float], tuple[float, float, float], ShapePart]],
                    lights_z: tuple[float, float] | None = None) -> ShapeTemplate:
    """Union of boxes given as ((min x, y, z), (max x, y, z), part) in unit-box coordinates, with
    optional head- and taillight decals between heights ``lights_z`` on the front and rear faces."""
    verts: list[FloatArray] = []
    faces: list[tuple[int, ...]] = []
    normals: list[FloatArray] = []
    face_part: list[int] = []
    for i, (lo, hi, part) in enumerate(parts):
        lo_a, hi_a = np.array(lo), np.array(hi)
        verts.append(lo_a + (_BOX_CORNERS + 0.5) * (hi_a - lo_a))
        faces.extend(tuple(8 * i + j for j in f) for f in _BOX_FACES)
        normals.append(_BOX_NORMALS)
        face_part += [part] * 6
    solid = tuple(faces)
    offset = 8 * len(parts)
    if lights_z is not None:
        z0, z1 = lights_z
        for sign, part in ((1.0, ShapePart.HEADLIGHT), (-1.0, ShapePart.TAILLIGHT)):
            for y0, y1 in ((0.28, 0.44), (-0.44, -0.28)):
                x = sign * 0.505
                quad = np.array([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]])
                verts.append(quad)
                faces.append(tuple(range(offset, offset + 4)))
                normals.append(np.array([[sign, 0.0, 0.0]]))
                face_part.append(part)
                offset += 4
    return ShapeTemplate(np.concatenate(verts), _triangulate(solid), tuple(faces), np.concatenate(normals),
                         np.array(face_part, dtype=np.int64))


def _prism_template(sides: int = 8) -> ShapeTemplate:
    """A vertical prism whose flat sides touch the unit box (an upright cylinder, roughly)."""
    angles = np.pi / sides + 2 * np.pi * np.arange(sides) / sides
    radius = 0.5 / math.cos(math.pi / sides)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    verts = np.concatenate([np.c_[ring, np.full(sides, -0.5)], np.c_[ring, np.full(sides, 0.5)]])
    sides_f = tuple((i, (i + 1) % sides, sides + (i + 1) % sides, sides + i) for i in range(sides))
    bottom = tuple(range(sides - 1, -1, -1))
    top = tuple(range(sides, 2 * sides))
    mid = angles + np.pi / sides
    side_n = np.stack([np.cos(mid), np.sin(mid), np.zeros(sides)], axis=1)
    faces = (bottom, *sides_f, top)
    normals = np.concatenate([[[0.0, 0.0, -1.0]], side_n, [[0.0, 0.0, 1.0]]])
    return ShapeTemplate(verts, _triangulate(faces), faces, normals, np.full(len(faces), ShapePart.RIDER))


_UNIT = ((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
BOX_SHAPE = _boxes_template([(*_UNIT, ShapePart.BODY)])
VEHICLE_BOX_SHAPE = _boxes_template([(*_UNIT, ShapePart.BODY)], lights_z=(-0.38, -0.28))
CAR_SHAPE = _boxes_template(
    [((-0.5, -0.5, -0.5), (0.5, 0.5, 0.08), ShapePart.BODY), ((-0.33, -0.44, 0.08), (0.2, 0.44, 0.5), ShapePart.CABIN)],
    lights_z=(-0.15, 0.0),
)
PEDESTRIAN_SHAPE = _prism_template(8)
CYCLIST_SHAPE = _boxes_template(
    [((-0.5, -0.2, -0.5), (0.5, 0.2, 0.05), ShapePart.FRAME), ((-0.25, -0.5, 0.05), (0.15, 0.5, 0.5), ShapePart.RIDER)]
)

SHAPES: dict[str, ShapeTemplate] = {
    Category.CAR.value: CAR_SHAPE,
    Category.TRUCK.value: VEHICLE_BOX_SHAPE,
    Category.BUS.value: VEHICLE_BOX_SHAPE,
    Category.PEDESTRIAN.value: PEDESTRIAN_SHAPE,
    Category.CYCLIST.value: CYCLIST_SHAPE,
    Category.MOTORCYCLE.value: CYCLIST_SHAPE,
    Category.OTHER.value: BOX_SHAPE,
}

#: LiDAR reflectivity (0–255) of each category's surface.
OBJECT_REFLECTIVITY: dict[str, float] = {
    Category.CAR.value: 45.0,
    Category.TRUCK.value: 55.0,
    Category.BUS.value: 60.0,
    Category.PEDESTRIAN.value: 30.0,
    Category.CYCLIST.value: 40.0,
    Category.MOTORCYCLE.value: 45.0,
    Category.OTHER.value: 50.0,
}


def shape_of(category: str) -> ShapeTemplate:
    """The shape template of a public category (unknown ones are boxes)."""
    return SHAPES.get(category, BOX_SHAPE)


@dataclass(frozen=True)
class FrameObjects:
    """The objects present in one frame, in the ego frame.

    Attributes:
        track_index: (N,) index of each object in the log's track list (``DenseTracks.track_ids``).
        categories: (N,) public category values.
        center_xyz_m: (N, 3) box centres in the ego frame.
        yaw_rad: (N,) box headings in the ego frame.
        size_lwh_m: (N, 3) box sizes.
    """

    track_index: NDArray[np.int64]
    categories: NDArray[np.str_]
    center_xyz_m: FloatArray
    yaw_rad: FloatArray
    size_lwh_m: FloatArray

    def __len__(self) -> int:
        return int(self.track_index.shape[0])

    @staticmethod
    def empty() -> FrameObjects:
        return FrameObjects(np.zeros(0, np.int64), np.zeros(0, np.str_), np.zeros((0, 3)), np.zeros(0),
                            np.zeros((0, 3)))

    @staticmethod
    def from_boxes(boxes: list[tuple[str, tuple[float, float, float], tuple[float, float, float], float]],
                   ) -> FrameObjects:
        """Objects from ``(category, centre xyz, size lwh, yaw)`` rows, track index = row index."""
        return FrameObjects(
            np.arange(len(boxes), dtype=np.int64),
            np.array([b[0] for b in boxes], dtype=np.str_),
            np.array([b[1] for b in boxes], dtype=np.float64).reshape(-1, 3),
            np.array([b[3] for b in boxes], dtype=np.float64),
            np.array([b[2] for b in boxes], dtype=np.float64).reshape(-1, 3),
        )

    @staticmethod
    def at_frame(dense: DenseTracks, frame: int) -> FrameObjects:
        """The tracks observed at ``frame`` of ``dense``."""
        idx = np.flatnonzero(dense.valid[:, frame])
        return FrameObjects(
            idx.astype(np.int64),
            np.asarray(dense.categories[idx], dtype=np.str_),
            dense.center_ego_xyz_m[idx, frame],
            dense.yaw_ego_rad[idx, frame],
            dense.size_lwh_m[idx, frame],
        )

    def contains_points(self, points_xyz: FloatArray, margin_m: float = 0.0) -> NDArray[np.bool_]:
        """(N, P) whether each box holds each point.

        Args:
            points_xyz: (P, 3) points in the ego frame.
            margin_m: grow every box by this much on each side.
        """
        pts = np.asarray(points_xyz, dtype=np.float64)
        rel = pts[None, :, :] - self.center_xyz_m[:, None, :]  # (N, P, 3)
        c, s = np.cos(self.yaw_rad)[:, None], np.sin(self.yaw_rad)[:, None]
        local_x = c * rel[..., 0] + s * rel[..., 1]
        local_y = -s * rel[..., 0] + c * rel[..., 1]
        half = 0.5 * self.size_lwh_m[:, None, :] + margin_m
        inside_xy = (np.abs(local_x) <= half[..., 0]) & (np.abs(local_y) <= half[..., 1])
        return inside_xy & (np.abs(rel[..., 2]) <= half[..., 2])


def object_vertices(template: ShapeTemplate, objects: FrameObjects) -> FloatArray:
    """(N, V, 3) the template's vertices placed at every object's box, in the ego frame."""
    local = template.vertices[None, :, :] * objects.size_lwh_m[:, None, :]  # (N, V, 3)
    c, s = np.cos(objects.yaw_rad)[:, None], np.sin(objects.yaw_rad)[:, None]
    out = np.empty_like(local)
    out[..., 0] = c * local[..., 0] - s * local[..., 1]
    out[..., 1] = s * local[..., 0] + c * local[..., 1]
    out[..., 2] = local[..., 2]
    return out + objects.center_xyz_m[:, None, :]


@dataclass(frozen=True)
class ObjectMesh:
    """All objects of a frame as one triangle mesh.

    Attributes:
        vertices: (V, 3) vertices in the ego frame.
        triangles: (F, 3) vertex indices.
        owner: (F,) index into the frame's objects of each triangle's object; −1 for the ego's own body.
    """

    vertices: NDArray[np.float32]
    triangles: NDArray[np.uint32]
    owner: NDArray[np.int64]


def build_object_mesh(objects: FrameObjects, ego_box_lwh_m: tuple[float, float, float] | None = None,
                      ego_box_center_x_m: float = 0.0) -> ObjectMesh:
    """One mesh of every object's shape (vectorised per category), plus the ego's body if given."""
    verts: list[FloatArray] = []
    tris: list[NDArray[np.int64]] = []
    owners: list[NDArray[np.int64]] = []
    offset = 0
    for category in np.unique(objects.categories):
        template = shape_of(str(category))
        idx = np.flatnonzero(objects.categories == category)
        sub = FrameObjects(objects.track_index[idx], objects.categories[idx], objects.center_xyz_m[idx],
                           objects.yaw_rad[idx], objects.size_lwh_m[idx])
        v = object_vertices(template, sub)  # (n, V, 3)
        n, nv = v.shape[0], v.shape[1]
        verts.append(v.reshape(-1, 3))
        first = offset + nv * np.arange(n)
        tris.append((template.triangles[None, :, :].astype(np.int64) + first[:, None, None]).reshape(-1, 3))
        owners.append(np.repeat(idx, template.triangles.shape[0]))
        offset += n * nv
    if ego_box_lwh_m is not None and min(ego_box_lwh_m) > 0:
        length, width, height = ego_box_lwh_m
        verts.append(_BOX_CORNERS * [length, width, height] + [ego_box_center_x_m, 0.0, 0.5 * height])
        tris.append(BOX_SHAPE.triangles.astype(np.int64) + offset)
        owners.append(np.full(BOX_SHAPE.triangles.shape[0], -1, dtype=np.int64))
    if not verts:
        return ObjectMesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros(0, np.int64))
    return ObjectMesh(
        np.concatenate(verts).astype(np.float32),
        np.concatenate(tris).astype(np.uint32),
        np.concatenate(owners),
    )


# ---------------------------------------------------------------------------------------------
# Static world


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


@dataclass(frozen=True)
class Buildings:
    """Upright building blocks in the city frame.

    Attributes:
        center_xyz_m: (B, 3) block centres.
        size_lwh_m: (B, 3) block sizes along city x, city y and up.
        shade: (B,) per-building brightness factor for the camera and LiDAR.
    """

    center_xyz_m: FloatArray
    size_lwh_m: FloatArray
    shade: FloatArray

    def __len__(self) -> int:
        return int(self.center_xyz_m.shape[0])

    def corners(self) -> FloatArray:
        """(B, 8, 3) corners, indexed like :data:`BOX_SHAPE` vertices."""
        return self.center_xyz_m[:, None, :] + _BOX_CORNERS[None] * self.size_lwh_m[:, None, :]


def place_buildings(raster: GroundRaster, ground_z_m: float, config: WorldConfig, rng: np.random.Generator,
                    keep_clear_xy: FloatArray | None = None) -> Buildings:
    """Building blocks on a jittered lattice wherever the footprint keeps clear of the drivable area.

    Args:
        raster: the ground raster (its drivable cells are kept clear).
        ground_z_m: ground height.
        config: building sizes, spacing and setback.
        rng: draws sizes, heights and jitter.
        keep_clear_xy: (P, 2) further city points to keep ``building_setback_m`` clear of (the ego's
            path, so that a log without a map is not built over).
    """
    h, w = raster.drivable.shape
    res = raster.resolution_m
    x0, y0 = raster.origin_x_m, raster.origin_y_m
    spacing = config.building_spacing_m
    xs = np.arange(x0 + 0.5 * spacing, x0 + w * res, spacing)
    ys = np.arange(y0 + 0.5 * spacing, y0 + h * res, spacing)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    n = gx.size
    lo, hi = config.building_size_m
    size_xy = rng.uniform(lo, hi, size=(n, 2))
    size_xy = np.minimum(size_xy, spacing - 1.0) if spacing > 1.0 + lo else size_xy
    jitter = rng.uniform(-1.0, 1.0, size=(n, 2)) * np.maximum(0.0, 0.5 * (spacing - size_xy) - 0.5)
    centers = np.stack([gx.ravel(), gy.ravel()], axis=1) + jitter
    heights = rng.uniform(*config.building_height_m, size=n)
    shade = rng.uniform(0.75, 1.15, size=n)
    if raster.drivable.any():
        dist_m = cv2.distanceTransform((~raster.drivable).astype(np.uint8), cv2.DIST_L2, 5) * res
    else:
        dist_m = np.full((h, w), np.inf, dtype=np.float32)
    cr = np.floor(raster.city_to_cell(centers) + 0.5).astype(np.int64)
    inside = (cr[:, 0] >= 0) & (cr[:, 0] < w) & (cr[:, 1] >= 0) & (cr[:, 1] < h)
    clearance = np.zeros(n)
    clearance[inside] = dist_m[cr[inside, 1], cr[inside, 0]]
    half_diag = 0.5 * np.linalg.norm(size_xy, axis=1)
    keep = inside & (clearance >= config.building_setback_m + half_diag)
    if keep_clear_xy is not None and len(keep_clear_xy) and keep.any():
        from scipy.spatial import cKDTree

        path_dist, _ = cKDTree(np.asarray(keep_clear_xy)[:, :2]).query(centers[keep])
        keep[np.flatnonzero(keep)] = path_dist >= config.building_setback_m + 2.0 + half_diag[keep]
    center_xyz = np.c_[centers[keep], ground_z_m + 0.5 * heights[keep]]
    return Buildings(center_xyz, np.c_[size_xy[keep], heights[keep]], shade[keep])


def _kerb_mesh(segments: FloatArray, ground_z_m: float, height_m: float) -> tuple[FloatArray, NDArray[np.int64]]:
    s = segments.shape[0]
    a, b = segments[:, 0], segments[:, 1]
    z0 = np.full((s, 1), ground_z_m - 0.05)
    z1 = np.full((s, 1), ground_z_m + height_m)
    verts = np.stack([np.c_[a, z0], np.c_[b, z0], np.c_[b, z1], np.c_[a, z1]], axis=1).reshape(-1, 3)
    base = 4 * np.arange(s)[:, None]
    tris = np.concatenate([base + np.array([0, 1, 2]), base + np.array([0, 2, 3])], axis=1).reshape(-1, 3)
    return verts, tris


@dataclass
class StaticWorld:
    """The static part of a log's world, built once: ray-casting scene, ground raster, buildings.

    Attributes:
        ground_z_m: height of the flat ground in the city frame.
        raster: ground materials (road, paint, sidewalk, …).
        buildings: building blocks.
        kerbs: (S, 2, 2) kerb segments in the city frame.
        kerb_height_m: kerb height.
        scene: the open3d ray-casting scene; geometry ids are :class:`StaticKind` values.
    """

    ground_z_m: float
    raster: GroundRaster
    buildings: Buildings
    kerbs: FloatArray
    kerb_height_m: float
    scene: o3d.t.geometry.RaycastingScene

    @staticmethod
    def build(vector_map: VectorMap | None, city_SE3_ego: FloatArray, config: WorldConfig,
              rng: np.random.Generator) -> StaticWorld:
        """Build the world around an ego path.

        Args:
            vector_map: the log's map (None: bare ground).
            city_SE3_ego: (T, 4, 4) ego poses; the world covers their extent plus ``config.margin_m``.
            config: world parameters.
            rng: seeds the building placement.
        """
        poses = np.asarray(city_SE3_ego, dtype=np.float64)
        xy = poses[:, :2, 3]
        ground_z = float(np.median(poses[:, 2, 3]))
        m = config.margin_m
        extent = (float(xy[:, 0].min() - m), float(xy[:, 1].min() - m), float(xy[:, 0].max() + m),
                  float(xy[:, 1].max() + m))
        raster = build_ground_raster(vector_map, extent, config)
        buildings = place_buildings(raster, ground_z, config, rng, keep_clear_xy=xy)
        kerbs = kerb_segments(raster) if config.kerb_height_m > 0 else np.zeros((0, 2, 2))
        scene = o3d.t.geometry.RaycastingScene()
        big = 10.0 * max(extent[2] - extent[0], extent[3] - extent[1])
        cx, cy = 0.5 * (extent[0] + extent[2]), 0.5 * (extent[1] + extent[3])
        ground_v = np.array([[cx - big, cy - big, ground_z], [cx + big, cy - big, ground_z],
                             [cx + big, cy + big, ground_z], [cx - big, cy + big, ground_z]], np.float32)
        ground_ids = scene.add_triangles(o3d_tensor(ground_v), o3d_tensor(np.array([[0, 1, 2], [0, 2, 3]],
                                                                                             np.uint32)))
        # Keep the geometry ids equal to StaticKind even when kerbs or buildings are empty: add a
        # degenerate far-away triangle as a placeholder.
        far = np.array([[1e7, 1e7, -1e7], [1e7 + 1, 1e7, -1e7], [1e7, 1e7 + 1, -1e7]], np.float32)
        kv, kt = _kerb_mesh(kerbs, ground_z, config.kerb_height_m) if len(kerbs) else (
            far.astype(np.float64), np.array([[0, 1, 2]]))
        kerb_ids = scene.add_triangles(o3d_tensor(kv.astype(np.float32)), o3d_tensor(kt.astype(np.uint32)))
        if len(buildings):
            bv = buildings.corners().reshape(-1, 3)
            bt = (BOX_SHAPE.triangles[None] + 8 * np.arange(len(buildings))[:, None, None]).reshape(-1, 3)
        else:
            bv, bt = far.astype(np.float64), np.array([[0, 1, 2]])
        building_ids = scene.add_triangles(o3d_tensor(bv.astype(np.float32)),
                                           o3d_tensor(bt.astype(np.uint32)))
        if (ground_ids, kerb_ids, building_ids) != (StaticKind.GROUND, StaticKind.KERB, StaticKind.BUILDING):
            raise RuntimeError("unexpected open3d geometry ids")
        return StaticWorld(ground_z, raster, buildings, kerbs, config.kerb_height_m, scene)
