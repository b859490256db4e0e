"""Objects of one frame for the sensor simulation: their shapes, placed at their boxes, as one mesh.

Objects are rebuilt every frame, in the ego frame, from their boxes: each category has its own
shape inside its box (cars: body and cabin; pedestrians: an octagonal prism; cyclists: a narrow
bicycle and a rider; trucks, buses and others: the box itself), so every surface point of a shape
lies inside (or on) the object's annotated box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from scenes.categories import Category
from scenes.geometry import FloatArray
from scenes.tracks import DenseTracks


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


#: (8, 3) corners of the unit box; corner index = ix + 2 iy + 4 iz.
BOX_CORNERS = np.array(
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
        verts.append(lo_a + (BOX_CORNERS + 0.5) * (hi_a - lo_a))
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
        verts.append(BOX_CORNERS * [length, width, height] + [ego_box_center_x_m, 0.0, 0.5 * height])
        tris.append(BOX_SHAPE.triangles.astype(np.int64) + offset)
        owners.append(np.full(BOX_SHAPE.triangles.shape[0], -1, dtype=np.int64))
    if not verts:
        return ObjectMesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros(0, np.int64))
    return ObjectMesh(
        np.concatenate(verts).astype(np.float32),
        np.concatenate(tris).astype(np.uint32),
        np.concatenate(owners),
    )
