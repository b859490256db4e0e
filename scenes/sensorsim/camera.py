"""A pinhole front camera drawn with OpenCV, with a per-pixel instance mask.

Per frame, in order:

1. **Ground**: the log's ground material raster (road, lane paint, crosswalk stripes, sidewalk,
   terrain), coloured once per log, is warped into the image by the ground plane's homography
   (one ``cv2.warpPerspective``); the sky gradient fills everything above the horizon and haze
   blends the ground toward the horizon colour with distance (fog: a short visibility).
2. **Contact shadows**: the ground under each object is darkened (its footprint, slightly grown).
3. **Buildings and objects**: convex faces (back faces culled, flat-shaded by the sun) filled with
   ``cv2.fillConvexPoly``, object by object from far to near (painter's order by the distance to
   each box's nearest point). Faces crossing the camera's near plane are clipped before projection.
   Objects write ``1 + track index`` into the instance mask; buildings write 0, so they hide what
   is behind them in the mask too.
4. **Effects**: rain streaks and sensor noise (one of a few noise tiles drawn once per log).

Image convention: OpenCV pixels, (u right, v down), pixel (u, v) centred on integer coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.calibration import CameraIntrinsics
from scenes.geometry import SE3, FloatArray
from scenes.sensorsim.appearance import Appearance, make_palette, object_colors
from scenes.sensorsim.config import CameraConfig
from scenes.sensorsim.ground import GroundMaterial
from scenes.sensorsim.objects import BOX_SHAPE, FrameObjects, ShapePart, object_vertices, shape_of
from scenes.sensorsim.world import StaticWorld

#: Points nearer than this to the camera plane are clipped away.
NEAR_PLANE_M = 0.1
#: Maximum number of tracks a 16-bit instance mask can tell apart.
MAX_TRACKS = 65534
_SHIFT = 4  # sub-pixel bits for cv2.fillConvexPoly
_SCALE = float(1 << _SHIFT)
_NOISE_TILES = 4


def clip_near_plane(polygon_cam: FloatArray, near_m: float = NEAR_PLANE_M) -> FloatArray:
    """Clip a convex polygon to the half-space in front of the camera (Sutherland–Hodgman, one plane).

    Args:
        polygon_cam: (K, 3) vertices in the camera frame, in order.
        near_m: keep the part with z ≥ near_m.

    Returns:
        (M, 3) the clipped polygon (M = 0 when nothing is in front).
    """
    p = np.asarray(polygon_cam, dtype=np.float64)
    z = p[:, 2]
    inside = z >= near_m
    if inside.all():
        return p
    if not inside.any():
        return np.zeros((0, 3))
    out = []
    k = p.shape[0]
    for i in range(k):
        j = (i + 1) % k
        if inside[i]:
            out.append(p[i])
        if inside[i] != inside[j]:
            t = (near_m - z[i]) / (z[j] - z[i])
            out.append(p[i] + t * (p[j] - p[i]))
    return np.array(out)


class _FaceTable:
    """The faces of a shape as index arrays: ``padded`` (P, k) repeats a face's last vertex up to the
    longest face, ``centroid`` (P, V) averages a face's vertices."""

    def __init__(self, faces: tuple[tuple[int, ...], ...], num_vertices: int) -> None:
        self.faces = [np.array(f, dtype=np.int64) for f in faces]
        k = max(len(f) for f in faces)
        self.padded = np.array([list(f) + [f[-1]] * (k - len(f)) for f in faces], dtype=np.int64)
        self.centroid = np.zeros((len(faces), num_vertices))
        for p, f in enumerate(faces):
            self.centroid[p, list(f)] = 1.0 / len(f)


_FACE_TABLES: dict[int, _FaceTable] = {}


def _face_table(faces: tuple[tuple[int, ...], ...], num_vertices: int) -> _FaceTable:
    key = hash((faces, num_vertices))
    if key not in _FACE_TABLES:
        _FACE_TABLES[key] = _FaceTable(faces, num_vertices)
    return _FACE_TABLES[key]


@dataclass
class _Drawable:
    distance_m: float
    faces_uv: list[NDArray[np.int32]]
    colors: list[tuple[float, float, float]]
    value: int


class CameraRenderer:
    """Renders the frames of one log: holds the coloured ground texture, sky and palette.

    Args:
        world: the log's static world.
        config: the camera.
        appearance: time of day, weather and vehicle colours.
        track_ids: (K,) the log's track list; mask value v ≥ 1 is track ``track_ids[v − 1]``.
        categories: (K,) public category of each track.
        seed: seeds the noise tiles.
    """

    def __init__(self, world: StaticWorld, config: CameraConfig, appearance: Appearance, track_ids: list[str],
                 categories: list[str], seed: int = 0) -> None:
        if len(track_ids) > MAX_TRACKS:
            raise ValueError(f"{len(track_ids)} tracks do not fit a 16-bit instance mask (at most {MAX_TRACKS})")
        self.world = world
        self.config = config
        self.intrinsics: CameraIntrinsics = config.intrinsics
        self.ego_SE3_cam: SE3 = config.ego_SE3_sensor
        self.appearance = appearance
        self.palette = make_palette(appearance)
        self.track_colors = object_colors(list(track_ids), list(categories), appearance)
        raster = world.raster
        colors = np.clip(self.palette.ground, 0, 255).astype(np.uint8)
        # BGRA: OpenCV's bilinear warp is about twice as fast on 4 channels as on 3.
        self.texture = cv2.cvtColor(colors[raster.material], cv2.COLOR_BGR2BGRA)  # (Hr, Wr, 4)
        self.border = (*(float(c) for c in colors[GroundMaterial.TERRAIN]), 255.0)
        res = raster.resolution_m
        self._city_to_texel = np.array([[1 / res, 0, -raster.origin_x_m / res - 0.5],
                                        [0, 1 / res, -raster.origin_y_m / res - 0.5], [0, 0, 1]])
        k = self.intrinsics.K
        self._k_inv = np.linalg.inv(k)
        w, h = config.width_px, config.height_px
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        self._pix = np.stack([u, v, np.ones_like(u)], axis=-1)  # (H, W, 3)
        self._ray_norm = np.linalg.norm(self._pix @ np.ascontiguousarray(self._k_inv.T), axis=-1)  # (H, W)
        self._background_key: tuple[float, ...] | None = None
        self._background: tuple[NDArray[np.uint8], NDArray[np.uint8]] | None = None
        rng = np.random.default_rng(seed)
        noise = np.round(rng.normal(0.0, self.palette.noise_std, (_NOISE_TILES, h, w, 3)))
        self._noise_pos = np.clip(noise, 0, 255).astype(np.uint8)
        self._noise_neg = np.clip(-noise, 0, 255).astype(np.uint8)
        b = world.buildings
        self._building_corners = b.corners()
        facades = self.palette.facades[np.arange(len(b)) % len(self.palette.facades)]
        self._building_colors = facades * b.shade[:, None]

    # -----------------------------------------------------------------------------------------

    def _background_for(self, a_z: FloatArray, height_m: float) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """255 · (1 − haze weight) and haze colour × weight, both (H, W, 3) uint8, cached per camera tilt and
        height (constant over a log on flat ground)."""
        key = (*np.round(a_z, 7).tolist(), round(height_m, 4))
        if key == self._background_key and self._background is not None:
            return self._background
        pal = self.palette
        s = self._pix @ a_z  # (H, W): vertical component of each pixel's (unnormalised) ray
        ground = s < -1e-9
        dist = np.where(ground, height_m / np.where(ground, -s, 1.0) * self._ray_norm, np.inf)
        weight = 1.0 - np.exp(-dist / pal.visibility_m)
        elevation = np.arcsin(np.clip(s / self._ray_norm, -1.0, 1.0))
        frac = np.clip(elevation / np.deg2rad(35.0), 0.0, 1.0)[..., None] ** 0.7
        sky = pal.sky_horizon * (1 - frac) + pal.sky_top * frac
        far = np.where(ground[..., None], pal.sky_horizon, sky)
        keep = np.repeat(np.round(255.0 * (1.0 - weight))[..., None], 3, axis=2).astype(np.uint8)
        haze = np.round(far * weight[..., None]).astype(np.uint8)
        self._background_key, self._background = key, (keep, haze)
        return keep, haze

    def _first_ground_row(self, a_z: FloatArray) -> int:
        """First image row with a pixel looking below the horizon (rows below it may hold ground)."""
        w, h = self.config.width_px, self.config.height_px
        if abs(a_z[1]) < 1e-12:
            return 0 if a_z[2] < 0 else h
        # a_z · (u, v, 1) < 0 on the ground; the boundary row at the left and right image edges.
        v_edges = [-(a_z[0] * u + a_z[2]) / a_z[1] for u in (0.0, w - 1.0)]
        if a_z[1] > 0:  # ground below the horizon line, as usual
            return int(np.clip(np.floor(min(v_edges)), 0, h))
        return 0

    def _fog(self, colors: FloatArray, distance_m: FloatArray) -> FloatArray:
        w = 1.0 - np.exp(-np.asarray(distance_m) / self.palette.visibility_m)
        return colors * (1 - w)[..., None] + self.palette.sky_horizon * w[..., None]

    def _shade(self, normals_city: FloatArray) -> FloatArray:
        lam = np.maximum(normals_city @ self.palette.sun_dir, 0.0)
        return self.palette.ambient + self.palette.diffuse * lam

    def _faces_drawables(self, verts_cam: FloatArray, faces: _FaceTable, visible: NDArray[np.bool_],
                         colors: FloatArray, distance: FloatArray, values: NDArray[np.int64]) -> list[_Drawable]:
        """Drawables of N shapes sharing one face table.

        Args:
            verts_cam: (N, V, 3) vertices in the camera frame.
            faces: the shared faces.
            visible: (N, P) which faces face the camera.
            colors: (N, P, 3) BGR colour of each face.
            distance: (N,) painter's distance of each shape.
            values: (N,) mask value of each shape.
        """
        fx, fy, cx, cy = (self.intrinsics.fx_px, self.intrinsics.fy_px, self.intrinsics.cx_px,
                          self.intrinsics.cy_px)
        z = verts_cam[..., 2]
        safe = np.maximum(z, NEAR_PLANE_M)
        uv = np.stack([fx * verts_cam[..., 0] / safe + cx, fy * verts_cam[..., 1] / safe + cy], axis=-1)
        uv_fixed = np.round(np.clip(uv, -1e5, 1e5) * _SCALE).astype(np.int32)  # (N, V, 2)
        front = z >= NEAR_PLANE_M  # (N, V)
        face_front = front[:, faces.padded]  # (N, P, k)
        all_front: NDArray[np.bool_] = np.asarray(face_front.all(axis=-1))
        face_uv = uv_fixed[:, faces.padded]  # (N, P, k, 2)
        lo, hi = face_uv.min(axis=2), face_uv.max(axis=2)
        w, h = self.config.width_px * _SCALE, self.config.height_px * _SCALE
        on_screen = (hi[..., 0] >= 0) & (hi[..., 1] >= 0) & (lo[..., 0] <= w) & (lo[..., 1] <= h)
        draw = visible & face_front.any(axis=-1) & (on_screen | ~all_front)
        color_list = colors.tolist()
        out = []
        for i in np.flatnonzero(draw.any(axis=1)):
            polys: list[NDArray[np.int32]] = []
            cols: list[tuple[float, float, float]] = []
            for p in np.flatnonzero(draw[i]):
                face = faces.faces[p]
                if all_front[i, p]:
                    pts = uv_fixed[i, face]
                else:
                    clipped = clip_near_plane(verts_cam[i, face])
                    if clipped.shape[0] < 3:
                        continue
                    pts_f = np.stack([fx * clipped[:, 0] / clipped[:, 2] + cx, fy * clipped[:, 1] / clipped[:, 2] + cy],
                                     axis=1)
                    pts = np.round(np.clip(pts_f, -1e5, 1e5) * _SCALE).astype(np.int32)
                polys.append(pts)
                cols.append(tuple(color_list[i][p]))
            if polys:
                out.append(_Drawable(float(distance[i]), polys, cols, int(values[i])))
        return out

    # -----------------------------------------------------------------------------------------

    def render(self, objects: FrameObjects, city_SE3_ego: SE3,
               rng: np.random.Generator) -> tuple[NDArray[np.uint8], NDArray[np.uint16]]:
        """Render one frame.

        Args:
            objects: the frame's objects in the ego frame.
            city_SE3_ego: the ego pose.
            rng: draws the rain streaks and picks the noise tile.

        Returns:
            (H, W, 3) BGR image and (H, W) instance mask: 0 background, v ≥ 1 the track ``v − 1``.
        """
        cfg, pal = self.config, self.palette
        w, h = cfg.width_px, cfg.height_px
        city_SE3_cam = city_SE3_ego.compose(self.ego_SE3_cam)
        cam_SE3_city = city_SE3_cam.inverse()
        cam_SE3_ego = self.ego_SE3_cam.inverse()
        rot, origin = city_SE3_cam.rotation, city_SE3_cam.translation
        a = rot @ self._k_inv  # pixel (u, v, 1) → ray direction in the city frame
        g = self.world.ground_z_m
        height = float(origin[2] - g)

        # 1. Ground texture by homography, sky and haze.
        ground = np.zeros((h, w, 3), np.uint8)
        first_row = self._first_ground_row(a[2]) if height > 1e-3 else h
        if first_row < h:
            # Only rows that hold ground: the homography of the rows from first_row down.
            m = np.stack([origin[0] * a[2] - height * a[0], origin[1] * a[2] - height * a[1], a[2]])
            shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, first_row], [0.0, 0.0, 1.0]])
            homography = self._city_to_texel @ m @ shift
            warped = cv2.warpPerspective(self.texture, homography, (w, h - first_row),
                                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=self.border)
            ground[first_row:] = cv2.cvtColor(warped, cv2.COLOR_BGRA2BGR)
        keep, haze = self._background_for(a[2], max(height, 1e-3))
        image: NDArray[np.uint8] = np.asarray(cv2.add(cv2.multiply(ground, keep, scale=1.0 / 255.0), haze),
                                              dtype=np.uint8)
        mask = np.zeros((h, w), np.uint16)
        self._draw_shadows(image, objects, cam_SE3_ego, self.world.ground_z_m - city_SE3_ego.translation[2])

        # 2. Buildings and objects, far to near.
        drawables: list[_Drawable] = []
        drawables += self._building_drawables(cam_SE3_city, origin)
        drawables += self._object_drawables(objects, cam_SE3_ego, city_SE3_ego)
        drawables.sort(key=lambda d: -d.distance_m)
        for d in drawables:
            for pts, color in zip(d.faces_uv, d.colors):
                cv2.fillConvexPoly(image, pts, color, lineType=cv2.LINE_AA, shift=_SHIFT)
                cv2.fillConvexPoly(mask, pts, d.value, lineType=cv2.LINE_8, shift=_SHIFT)

        # 3. Rain and noise.
        if pal.rain_streaks:
            n = pal.rain_streaks
            start = rng.uniform([0, -20], [w, h], size=(n, 2))
            length = rng.uniform(8, 24, size=n)
            end = start + np.stack([0.15 * length, length], axis=1)
            segments = list(np.round(np.stack([start, end], axis=1)).astype(np.int32))
            streak = np.minimum(pal.sky_horizon * 1.1 + 20, 255)
            cv2.polylines(image, segments, False, (float(streak[0]), float(streak[1]), float(streak[2])), 1,
                          cv2.LINE_AA)
        if pal.noise_std > 0:
            k = int(rng.integers(0, _NOISE_TILES))
            cv2.add(image, self._noise_pos[k], dst=image)
            cv2.subtract(image, self._noise_neg[k], dst=image)
        return image, mask

    def _draw_shadows(self, image: NDArray[np.uint8], objects: FrameObjects, cam_SE3_ego: SE3,
                      ground_ego_z_m: float) -> None:
        """Darken the ground under every object (its footprint, a little enlarged): contact shadows."""
        if len(objects) == 0:
            return
        near = np.linalg.norm(objects.center_xyz_m[:, :2], axis=1) < self.config.max_distance_m
        if not near.any():
            return
        c, s = np.cos(objects.yaw_rad[near]), np.sin(objects.yaw_rad[near])
        half = 0.5 * objects.size_lwh_m[near, :2] + 0.15
        sign = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])
        lx, ly = sign[None, :, 0] * half[:, None, 0], sign[None, :, 1] * half[:, None, 1]
        centers = objects.center_xyz_m[near]
        corners = np.stack([centers[:, None, 0] + c[:, None] * lx - s[:, None] * ly,
                            centers[:, None, 1] + s[:, None] * lx + c[:, None] * ly,
                            np.full(lx.shape, ground_ego_z_m + 0.01)], axis=-1)  # (n, 4, 3)
        cam = corners @ np.ascontiguousarray(cam_SE3_ego.rotation.T) + cam_SE3_ego.translation
        intr = self.intrinsics
        shade = np.zeros(image.shape[:2], np.uint8)
        for quad in cam:
            clipped = clip_near_plane(quad)
            if clipped.shape[0] < 3:
                continue
            uv = np.stack([intr.fx_px * clipped[:, 0] / clipped[:, 2] + intr.cx_px,
                           intr.fy_px * clipped[:, 1] / clipped[:, 2] + intr.cy_px], axis=1)
            cv2.fillConvexPoly(shade, np.round(np.clip(uv, -1e5, 1e5) * _SCALE).astype(np.int32), 255,
                               lineType=cv2.LINE_AA, shift=_SHIFT)
        if shade.any():
            soft = np.asarray(cv2.blur(shade, (3, 3)), dtype=np.uint16)
            factor = (255 - soft * 115 // 255).astype(np.uint8)  # down to 55 % under the object
            cv2.multiply(image, cv2.merge([factor, factor, factor]), dst=image, scale=1.0 / 255.0)

    def _building_drawables(self, cam_SE3_city: SE3, origin_city: FloatArray) -> list[_Drawable]:
        corners = self._building_corners
        if corners.shape[0] == 0:
            return []
        center = self.world.buildings.center_xyz_m
        half = 0.5 * self.world.buildings.size_lwh_m
        nearest = np.clip(origin_city, center - half, center + half)
        distance = np.linalg.norm(nearest - origin_city, axis=1)
        cam = cam_SE3_city
        near = distance < self.config.max_distance_m
        idx = np.flatnonzero(near)
        if idx.size == 0:
            return []
        verts_cam = corners[idx] @ np.ascontiguousarray(cam.rotation.T) + cam.translation  # (n, 8, 3)
        keep = (verts_cam[..., 2] > NEAR_PLANE_M).any(axis=1)
        idx, verts_cam = idx[keep], verts_cam[keep]
        faces = _face_table(BOX_SHAPE.faces[1:], 8)  # no bottom face
        normals = BOX_SHAPE.face_normals[1:]  # (5, 3), axis-aligned in the city frame
        face_centers = np.einsum("pv,nvk->npk", faces.centroid, corners[idx])  # (n, 5, 3)
        visible = np.einsum("npk,pk->np", face_centers - origin_city, normals) < 0
        shade = self._shade(normals)  # (5,)
        colors = self._building_colors[idx][:, None, :] * shade[None, :, None]
        colors = self._fog(colors, distance[idx][:, None])
        return self._faces_drawables(verts_cam, faces, visible, colors, distance[idx],
                                     np.zeros(idx.shape[0], np.int64))

    def _object_drawables(self, objects: FrameObjects, cam_SE3_ego: SE3, city_SE3_ego: SE3) -> list[_Drawable]:
        if len(objects) == 0:
            return []
        cam_ego = self.ego_SE3_cam.translation
        half = 0.5 * objects.size_lwh_m
        rel = cam_ego - objects.center_xyz_m
        c, s = np.cos(objects.yaw_rad), np.sin(objects.yaw_rad)
        local = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], axis=1)
        distance = np.linalg.norm(local - np.clip(local, -half, half), axis=1)
        sun_ego = city_SE3_ego.rotation.T @ self.palette.sun_dir
        pal = self.palette
        out: list[_Drawable] = []
        for category in np.unique(objects.categories):
            sel = np.flatnonzero((objects.categories == category) & (distance < self.config.max_distance_m))
            if sel.size == 0:
                continue
            template = shape_of(str(category))
            sub = FrameObjects(objects.track_index[sel], objects.categories[sel], objects.center_xyz_m[sel],
                               objects.yaw_rad[sel], objects.size_lwh_m[sel])
            verts_ego = object_vertices(template, sub)  # (n, V, 3)
            verts_cam = verts_ego @ np.ascontiguousarray(cam_SE3_ego.rotation.T) + cam_SE3_ego.translation
            in_front = (verts_cam[..., 2] > NEAR_PLANE_M).any(axis=1)
            if not in_front.any():
                continue
            cs, sn = np.cos(sub.yaw_rad)[:, None], np.sin(sub.yaw_rad)[:, None]
            nt = template.face_normals  # (P, 3)
            normals = np.stack([cs * nt[:, 0] - sn * nt[:, 1], sn * nt[:, 0] + cs * nt[:, 1],
                                np.broadcast_to(nt[:, 2], cs.shape[:1] + nt[:, 2].shape)], axis=-1)  # (n, P, 3)
            faces = _face_table(template.faces, template.vertices.shape[0])
            face_centers = np.einsum("pv,nvk->npk", faces.centroid, verts_ego)
            visible = np.einsum("npk,npk->np", face_centers - cam_ego, normals) < 0
            lam = pal.ambient + pal.diffuse * np.maximum(normals @ sun_ego, 0.0)  # (n, P)
            paint = self.track_colors[sub.track_index] * pal.light
            base = np.broadcast_to(paint[:, None, :], (*lam.shape, 3)).copy()
            part = template.face_part
            glass = np.array([70.0, 55.0, 45.0]) * pal.light
            side = np.abs(nt[:, 2]) < 0.5
            base[:, (part == ShapePart.CABIN) & side] = 0.3 * base[:, (part == ShapePart.CABIN) & side] + 0.7 * glass
            base[:, part == ShapePart.FRAME] = np.array([45.0, 45.0, 50.0]) * pal.light
            colors = base * lam[..., None]
            lit = pal.headlight if pal.lights_on else np.array([205.0, 205.0, 200.0]) * pal.light
            colors[:, part == ShapePart.HEADLIGHT] = lit
            colors[:, part == ShapePart.TAILLIGHT] = pal.taillight * (1.0 if pal.lights_on else 0.6)
            colors = self._fog(colors, distance[sel][:, None])
            keep = np.flatnonzero(in_front)
            out += self._faces_drawables(verts_cam[keep], faces, visible[keep], colors[keep],
                                         distance[sel][keep], sub.track_index[keep] + 1)
        return out


def render_frame(renderer: CameraRenderer, objects: FrameObjects, city_SE3_ego: SE3,
                 rng: np.random.Generator) -> tuple[NDArray[np.uint8], NDArray[np.uint16]]:
    """One camera frame: (H, W, 3) BGR image and (H, W) instance mask (0 background, v ≥ 1 track v − 1)."""
    return renderer.render(objects, city_SE3_ego, rng)
