"""The static world of the sensor simulation, built once per log from its vector map, in the city frame.

- a ground plane at the ego's ground height, with the material raster of :mod:`scenes.sensorsim.ground`;
- kerbs: low walls along the edges of the union of the drivable areas;
- building blocks on a lattice, kept ``building_setback_m`` away from the drivable area;

all in one open3d ray-casting scene. The world assumes flat ground (simulated logs are planar): the
ground lies at the median height of the ego origin over the log.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from scenes.geometry import FloatArray
from scenes.map import VectorMap
from scenes.sensorsim.config import WorldConfig
from scenes.sensorsim.ground import GroundRaster, build_ground_raster, kerb_segments
from scenes.sensorsim.objects import BOX_CORNERS, BOX_SHAPE


def o3d_tensor(array: NDArray[np.generic]) -> o3d.core.Tensor:
    """An open3d tensor sharing a contiguous copy of ``array``."""
    return o3d.core.Tensor(np.ascontiguousarray(array))  # type: ignore[call-overload]


class StaticKind(IntEnum):
    """Geometry ids of the static ray-casting scene, in the order they are added."""

    GROUND = 0
    KERB = 1
    BUILDING = 2


#: LiDAR reflectivity (0–255) of the kerbs and of the buildings.
KERB_REFLECTIVITY = 55.0
BUILDING_REFLECTIVITY = 60.0


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
        return self.center_xyz_m[:, None, :] + BOX_CORNERS[None] * self.size_lwh_m[:, None, :]


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
