"""The BEV half of a clip's preview (:mod:`encoders.clips.preview`), forward up, in palette indices.

It draws every track's box from ``track_boxes.npy`` (so a log rendered from boxes alone, or without a
map, still shows its objects), the object filled in the highlight colour, an object outside the grid as
an arrow at the edge pointing to it, the ego, and says "no map" and "boxes, no LiDAR" where that is so.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from encoders.clips.config import ClipsConfig
from encoders.clips.preview_canvas import (
    BLACK,
    CROSSING,
    DRIVABLE,
    EGO,
    FONT,
    INTERSECTION,
    LANE,
    OBJECT,
    OCCUPANCY_FIRST,
    OCCUPANCY_LEVELS,
    OTHER,
    REFERRED,
    REFERRED_FILL,
    RELATED,
    RELATED_FILL,
    WHITE,
    PreviewLayout,
    put_text,
    resize_frames,
)
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.views import LogArrays

#: The ego's footprint in its own frame: x (rear, front) and y (right, left), metres; rear axle at the origin.
EGO_BOX_M = ((-0.5, 4.0), (-1.0, 1.0))


def _box_corners_px(boxes: NDArray[np.floating], config: ClipsConfig, px_per_m: float) -> NDArray[np.float64]:
    """(..., 4, 2) (column, row) preview pixels of the corners of (..., 5) ``x, y, length, width, yaw`` boxes."""
    b = np.asarray(boxes, dtype=np.float64)
    c, s = np.cos(b[..., 4]), np.sin(b[..., 4])
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=np.float64)  # front-left, front-right, …
    dx = signs[:, 0] * 0.5 * b[..., 2, None]
    dy = signs[:, 1] * 0.5 * b[..., 3, None]
    x = b[..., 0, None] + c[..., None] * dx - s[..., None] * dy
    y = b[..., 1, None] + s[..., None] * dx + c[..., None] * dy
    return np.stack([(config.bev.y_max_m - y) * px_per_m, (config.bev.x_max_m - x) * px_per_m], axis=-1)


def _fixed(points: NDArray[np.float64]) -> NDArray[np.int32]:
    """Pixel coordinates in OpenCV's fixed point (4 fractional bits, ``shift=4``)."""
    return np.round(points * 16).astype(np.int32)


def bev_panel(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig, layout: PreviewLayout,
              referred: Sequence[str], related: Sequence[str]) -> NDArray[np.uint8]:
    """(T, height, bev_w) palette indices of the BEV half: map, occupancy, every track's box, the object, the ego."""
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    t, h, w = fi.shape[0], layout.height, layout.bev_w
    px_per_m = h / (config.bev.x_max_m - config.bev.x_min_m)
    bev_map = np.asarray(arrays.bev_map[fi])  # (T, Cm, Hb, Wb)
    has_map = bool(bev_map.any())
    bev = np.full((t, h, w), BLACK, np.uint8)
    if has_map:
        # Map layers scaled smoothly and cut at half: edges follow the cells without blocks.
        layers = [(DRIVABLE, "drivable_area"), (INTERSECTION, "intersection"), (CROSSING, "crossing"),
                  (LANE, "lane_boundary")]
        stack = np.moveaxis(bev_map[:, [MAP_CHANNELS.index(n) for _, n in layers]], 1, -1)  # (T, Hb, Wb, 4)
        up = resize_frames(stack, w, h, cv2.INTER_LINEAR) > 127  # (T, h, w, 4)
        for j, (index, _) in enumerate(layers):
            np.copyto(bev, np.uint8(index), where=up[..., j])
    lidar = np.asarray(arrays.bev_lidar[fi])  # (T, Z, Hb, Wb)
    occ = (lidar[:, 1:] if lidar.shape[1] > 1 else lidar).max(axis=1)  # above the ground bin: (T, Hb, Wb)
    level = np.where(occ > 0, OCCUPANCY_FIRST + occ.astype(np.uint16) * (OCCUPANCY_LEVELS - 1) // 255, 0)
    occ_up = resize_frames(level.astype(np.uint8), w, h, cv2.INTER_NEAREST)
    np.copyto(bev, occ_up, where=occ_up > 0)

    track = str(clip["track_id"])
    k_obj = arrays.track_value[track] - 1
    boxes = np.asarray(arrays.track_boxes[fi])  # (T, K, 5)
    corners = _box_corners_px(boxes, config, px_per_m)  # (T, K, 4, 2)
    seen: NDArray[np.bool_] = np.asarray(np.isfinite(boxes).all(axis=-1))  # (T, K)
    marks = {**{r: (RELATED, RELATED_FILL) for r in related}, **{r: (REFERRED, REFERRED_FILL) for r in referred}}
    marked = {arrays.track_value[r] - 1: m for r, m in marks.items() if r in arrays.track_value and r != track}
    others = np.array([k for k in range(boxes.shape[1]) if k != k_obj and k not in marked], dtype=np.int64)
    (x0, x1), (y0, y1) = EGO_BOX_M
    ego = _box_corners_px(np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), x1 - x0, y1 - y0, 0.0]), config, px_per_m)
    nose = ego[:2].mean(axis=0)
    for i in range(t):
        frame = bev[i]
        ring = [_fixed(corners[i, k]) for k in others if seen[i, k]]
        if ring:
            cv2.polylines(frame, ring, True, OTHER, 1, cv2.LINE_8, shift=4)
        for k, (edge, fill) in marked.items():
            if seen[i, k]:
                cv2.fillPoly(frame, [_fixed(corners[i, k])], fill, cv2.LINE_8, shift=4)
                cv2.polylines(frame, [_fixed(corners[i, k])], True, edge, 2, cv2.LINE_8, shift=4)
        cv2.fillPoly(frame, [_fixed(ego)], EGO, cv2.LINE_8, shift=4)
        cv2.line(frame, (int(nose[0]), int(nose[1])), (int(nose[0]), int(nose[1]) - 8), WHITE, 2, cv2.LINE_8)
        if not seen[i, k_obj]:
            continue
        centre = corners[i, k_obj].mean(axis=0)
        if 0 <= centre[0] < w and 0 <= centre[1] < h:
            cv2.fillPoly(frame, [_fixed(corners[i, k_obj])], OBJECT, cv2.LINE_8, shift=4)
            cv2.polylines(frame, [_fixed(corners[i, k_obj])], True, WHITE, 1, cv2.LINE_8, shift=4)
            cv2.circle(frame, (int(centre[0]), int(centre[1])), max(int(2.4 * px_per_m), 10), OBJECT, 2, cv2.LINE_8)
        else:
            _edge_arrow(frame, centre, boxes[i, k_obj])
    notes = ([] if has_map else ["no map"]) + (["boxes, no LiDAR"] if str(clip.get("bev_source")) == "boxes" else [])
    for j, note in enumerate(notes):
        for i in range(t):
            put_text(bev[i], note, (6, 16 + 16 * j), 0.4, OTHER)
    return bev


def _edge_arrow(frame: NDArray[np.uint8], centre: NDArray[np.float64], box: NDArray[np.floating]) -> None:
    """An arrow at the panel's edge pointing to an object outside it, with its distance."""
    h, w = frame.shape[:2]
    x, y = float(np.clip(centre[0], 14, w - 15)), float(np.clip(centre[1], 14, h - 15))
    dx, dy = centre[0] - x, centre[1] - y
    n = float(np.hypot(dx, dy)) or 1.0
    dx, dy = dx / n, dy / n
    cv2.arrowedLine(frame, (int(x - 10 * dx), int(y - 10 * dy)), (int(x + 10 * dx), int(y + 10 * dy)), OBJECT, 3,
                    cv2.LINE_8, tipLength=0.5)
    label = f"{float(np.hypot(box[0], box[1])):.0f} m"
    (tw, th), _ = cv2.getTextSize(label, FONT, 0.4, 1)
    lx, ly = x - 26 * dx - tw / 2, y - 26 * dy + th / 2  # inside the panel, behind the arrow
    put_text(frame, label, (int(np.clip(lx, 2, w - tw - 2)), int(np.clip(ly, th + 2, h - 3))), 0.4, OBJECT)
