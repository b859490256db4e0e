"""Previews of clips: an animated GIF per clip (camera and BEV side by side) and a still grid.

Layout of a preview frame, :data:`PREVIEW_HEIGHT_PX` high whatever the clips' own sizes::

    +------------------------------+-----------+
    | camera: the object outlined  |  BEV,     |
    | and boxed, the rest dimmed   |  forward  |
    | ("no camera" and why, when   |  up: the  |
    | the clip has none)           |  object   |
    +----------+-------------------+  boxed,   |
    | close-up | legend, the time  |  the ego  |
    | of the   | in the log        |  marked   |
    | object   |                   |           |
    +----------+-------------------+-----------+

The camera is scaled up smoothly and every mark (outlines, boxes, the ego, text) is drawn at the
preview's own resolution, so the preview stays sharp however small the clips' arrays are. The camera
outlines the object's mask and boxes it; where the object covers no pixel of the small camera frame,
its box is placed by its full-resolution crop (:mod:`encoders.clips.crops`), whose close-up is shown
below the camera. The BEV draws every track's box from ``track_boxes.npy`` (so a log rendered from
boxes alone, or without a map, still shows its objects), the object filled in the highlight colour, an
object outside the grid as an arrow at the edge pointing to it, and says "no map" and "boxes, no LiDAR"
where that is so.

Colours: the object of interest is the camera's highlight colour (magenta by default), the ego
green, other objects grey outlines; a preview drawn for a scenario query adds the tracks the program
refers to (orange) and relates them to (cyan). BEV map: drivable area dark grey, lane boundaries grey,
crossings olive, intersections dark blue; LiDAR (or box) occupancy above the lowest height bin white.

Frames are drawn straight into palette indices (:func:`render_preview_indices`) and written as a GIF
whose later frames keep only the pixels that change (:func:`encode_gif`): only the camera's pixels are
ever quantised, and the camera at half the panel's size. The module is one job, from a clip's arrays
to its preview's bytes, and is read as one: panels, palette and encoding depend on each other's layout.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from common.atomic import atomic_path
from encoders.clips.config import ClipsConfig
from encoders.clips.layout import read_clip_rows, read_manifest
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.render import bev_grid
from encoders.clips.views import LogArrays, highlight_camera, object_footprint, open_log_arrays

#: Height of every preview, pixels (the BEV's 80 m at 4.8 px/m with the default grid).
PREVIEW_HEIGHT_PX = 384
#: Height of the strip under the camera (close-up and legend).
STRIP_PX = 96
#: The widest camera panel, pixels.
MAX_CAMERA_WIDTH_PX = 640
GAP_PX = 4

EGO_RGB = (40, 220, 40)
OTHER_RGB = (150, 150, 150)
REFERRED_RGB = (255, 160, 0)
RELATED_RGB = (0, 200, 255)
TEXT_RGB = (235, 235, 235)
PANEL_RGB = (20, 20, 20)
NO_CAMERA_RGB = (48, 48, 52)
MAP_RGB = {"drivable_area": (45, 45, 45), "intersection": (25, 35, 80), "crossing": (90, 90, 30),
           "lane_boundary": (110, 110, 110)}
#: The ego's footprint in its own frame: x (rear, front) and y (right, left), metres; rear axle at the origin.
EGO_BOX_M = ((-0.5, 4.0), (-1.0, 1.0))
_FONT = cv2.FONT_HERSHEY_SIMPLEX

# Frames are drawn as indices into one palette: fixed entries for everything but the camera's pixels,
# which take the rest (:data:`CAMERA_COLOURS`), chosen per clip. Marks and text are drawn straight
# into the indices, so only the camera's pixels are ever quantised.
(PANEL, BLACK, DRIVABLE, INTERSECTION, CROSSING, LANE, EGO, OTHER, REFERRED, RELATED, TEXT, WHITE, NO_CAMERA,
 OBJECT, REFERRED_FILL, RELATED_FILL) = range(16)
#: Occupancy levels: a grey ramp from 80 to 255 in :data:`OCCUPANCY_LEVELS` steps.
OCCUPANCY_FIRST, OCCUPANCY_LEVELS = 16, 16
CAMERA_FIRST = OCCUPANCY_FIRST + OCCUPANCY_LEVELS
#: The last entry: transparent in the GIF, where a frame repeats the one before it (see :func:`encode_gif`).
TRANSPARENT = 255
CAMERA_COLOURS = TRANSPARENT - CAMERA_FIRST


def fixed_palette(highlight_rgb: tuple[int, int, int]) -> NDArray[np.uint8]:
    """(CAMERA_FIRST, 3) the palette's fixed entries, in the order of the index names above."""
    hl = tuple(int(v) for v in highlight_rgb)
    entries = [PANEL_RGB, (0, 0, 0), MAP_RGB["drivable_area"], MAP_RGB["intersection"], MAP_RGB["crossing"],
               MAP_RGB["lane_boundary"], EGO_RGB, OTHER_RGB, REFERRED_RGB, RELATED_RGB, TEXT_RGB, (255, 255, 255),
               NO_CAMERA_RGB, hl, tuple(v // 3 for v in REFERRED_RGB), tuple(v // 3 for v in RELATED_RGB)]
    ramp = [(g, g, g) for g in np.linspace(80, 255, OCCUPANCY_LEVELS).round().astype(int)]
    return np.asarray(entries + ramp, dtype=np.uint8)


@dataclass(frozen=True)
class PreviewLayout:
    """Pixel sizes of a preview's panels (see the module docstring).

    Attributes:
        height: the preview's height.
        camera_w, camera_h: the camera panel.
        bev_w: the BEV panel's width (its height is ``height``).
        closeup_w, closeup_h: the object's close-up in the strip.
    """

    height: int
    camera_w: int
    camera_h: int
    bev_w: int
    closeup_w: int
    closeup_h: int

    @property
    def width(self) -> int:
        return self.camera_w + GAP_PX + self.bev_w

    @staticmethod
    def of(config: ClipsConfig) -> PreviewLayout:
        b, cam = config.bev, config.camera
        bev_w = max(round(PREVIEW_HEIGHT_PX * (b.y_max_m - b.y_min_m) / (b.x_max_m - b.x_min_m)), 32)
        aspect = cam.width_px / cam.height_px
        camera_w = min(round((PREVIEW_HEIGHT_PX - STRIP_PX) * aspect), MAX_CAMERA_WIDTH_PX)
        camera_h = round(camera_w / aspect)
        closeup_w = min(round((STRIP_PX - 8) * aspect), camera_w // 2)
        return PreviewLayout(PREVIEW_HEIGHT_PX, camera_w, camera_h, bev_w, closeup_w, round(closeup_w / aspect))


def _config(clips_dir: Path) -> ClipsConfig:
    """The config the clips folder was built with (its manifest's ``config`` field)."""
    return ClipsConfig.from_dict(read_manifest(clips_dir).get("config", {}))


def _resize(frames: NDArray[Any], width: int, height: int, interpolation: int) -> NDArray[Any]:
    """(T, H, W[, C]) → (T, height, width[, C]), every frame alike."""
    if not len(frames):
        return np.zeros((0, height, width, *frames.shape[3:]), frames.dtype)
    return np.stack([cv2.resize(np.ascontiguousarray(f), (width, height), interpolation=interpolation)
                     for f in frames])


def _text(image: NDArray[np.uint8], text: str, org: tuple[int, int], scale: float = 0.45, index: int = TEXT,
          thickness: int = 1) -> None:
    """Write ``text`` into (H, W) palette indices: OpenCV shades the edges of its letters whatever the line
    type, which in indices would be other colours, so the letters are cut from a mask."""
    (tw, th), base = cv2.getTextSize(text, _FONT, scale, thickness)
    x0, y0 = max(org[0] - 2, 0), max(org[1] - th - 2, 0)
    x1, y1 = min(org[0] + tw + 2, image.shape[1]), min(org[1] + base + 2, image.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.putText(mask, text, (org[0] - x0, org[1] - y0), _FONT, scale, 255, thickness, cv2.LINE_8)
    image[y0:y1, x0:x1][mask > 100] = index


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


def _bev_panel(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig, layout: PreviewLayout,
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
        up = _resize(stack, w, h, cv2.INTER_LINEAR) > 127  # (T, h, w, 4)
        for j, (index, _) in enumerate(layers):
            np.copyto(bev, np.uint8(index), where=up[..., j])
    lidar = np.asarray(arrays.bev_lidar[fi])  # (T, Z, Hb, Wb)
    occ = (lidar[:, 1:] if lidar.shape[1] > 1 else lidar).max(axis=1)  # above the ground bin: (T, Hb, Wb)
    level = np.where(occ > 0, OCCUPANCY_FIRST + occ.astype(np.uint16) * (OCCUPANCY_LEVELS - 1) // 255, 0)
    occ_up = _resize(level.astype(np.uint8), w, h, cv2.INTER_NEAREST)
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
            _text(bev[i], note, (6, 16 + 16 * j), 0.4, OTHER)
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
    (tw, th), _ = cv2.getTextSize(label, _FONT, 0.4, 1)
    lx, ly = x - 26 * dx - tw / 2, y - 26 * dy + th / 2  # inside the panel, behind the arrow
    _text(frame, label, (int(np.clip(lx, 2, w - tw - 2)), int(np.clip(ly, th + 2, h - 3))), 0.4, OBJECT)


def _camera_rgb(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig, layout: PreviewLayout
                ) -> tuple[NDArray[np.uint8], NDArray[np.bool_]] | None:
    """(T, camera_h / 2, camera_w / 2, 3) the camera scaled up smoothly to half the panel (it is quantised
    there and doubled: a quarter of the work, and pixel pairs do not show at the sizes pages show previews),
    the object tinted and the rest dimmed, and (T, Hc, Wc) the object's mask in the clip's own frames; None
    when the clip has no camera view."""
    if not (bool(clip["has_camera"]) and arrays.camera.shape[0]):
        return None
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    cam = config.camera
    mask = np.asarray(arrays.camera_instances[fi]) == arrays.track_value[str(clip["track_id"])]  # (T, Hc, Wc)
    rgb = highlight_camera(np.asarray(arrays.camera[fi]), mask, cam.highlight_rgb, 0.35, cam.dim_factor)
    return _resize(rgb, layout.camera_w // 2, layout.camera_h // 2, cv2.INTER_LINEAR), mask


def _closeup_rgb(arrays: LogArrays, clip: Mapping[str, Any], layout: PreviewLayout
                 ) -> tuple[NDArray[np.uint8], NDArray[np.bool_], NDArray[np.bool_]] | None:
    """(T, closeup_h, closeup_w, 3) the object's full-resolution crops scaled to the close-up, (T, h, w) its
    mask there and (T,) the frames that have one; None when no frame has a crop."""
    crops = arrays.crops
    if crops is None or not bool(clip["has_camera"]):
        return None
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    rows = np.asarray(crops.index[fi, arrays.track_value[str(clip["track_id"])] - 1])  # (T,)
    ok = rows >= 0
    if not ok.any():
        return None
    w, h = layout.closeup_w, layout.closeup_h
    rgb = np.zeros((fi.shape[0], h, w, 3), np.uint8)
    mask = np.zeros((fi.shape[0], h, w), bool)
    rgb[ok] = _resize(np.asarray(crops.rgb[rows[ok]]), w, h, cv2.INTER_LINEAR)
    mask[ok] = _resize(np.asarray(crops.mask[rows[ok]]) * np.uint8(255), w, h, cv2.INTER_LINEAR) > 96
    return rgb, mask, ok


def _outline(frame: NDArray[np.uint8], mask: NDArray[np.bool_], index: int, thickness: int) -> None:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(frame, contours, -1, index, thickness, cv2.LINE_8)


def _camera_marks(panel: NDArray[np.uint8], mask: NDArray[np.bool_], arrays: LogArrays, clip: Mapping[str, Any],
                  layout: PreviewLayout) -> None:
    """Outline and box the object in the camera panel's (T, camera_h, camera_w) indices; where it covers no
    pixel of the clip's small frame, box the place of its full-resolution crop."""
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    cw, ch = layout.camera_w, layout.camera_h
    sx, sy = cw / mask.shape[2], ch / mask.shape[1]
    mask_up = _resize(mask.astype(np.uint8) * np.uint8(255), cw, ch, cv2.INTER_LINEAR) > 96
    crops, k = arrays.crops, arrays.track_value[str(clip["track_id"])] - 1
    for i in range(fi.shape[0]):
        if mask_up[i].any():
            _outline(panel[i], mask_up[i], OBJECT, 2)
            ys, xs = np.nonzero(mask_up[i])
            box = (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))
        elif mask[i].any():
            ys, xs = np.nonzero(mask[i])
            box = (int(xs.min() * sx), int(ys.min() * sy), int((xs.max() + 1) * sx), int((ys.max() + 1) * sy))
        elif crops is not None and int(crops.index[fi[i], k]) >= 0:
            cx, cy = (float(v) for v in crops.box[fi[i], k, :2])  # the crop's centre, x and y in [−1, 1]
            x, y = int((cx + 1) * 0.5 * cw), int((cy + 1) * 0.5 * ch)
            box = (x, y, x, y)
        else:
            continue
        grow = 10 if box[2] - box[0] < 24 else 6
        cv2.rectangle(panel[i], (box[0] - grow, box[1] - grow), (box[2] + grow, box[3] + grow), OBJECT, 2, cv2.LINE_8)


def _no_camera(panel: NDArray[np.uint8], arrays: LogArrays) -> None:
    """Fill the camera panel's (T, h, w) indices with "no camera" and why."""
    ch, cw = panel.shape[1:]
    panel[:] = NO_CAMERA
    why = "this log has no camera" if not arrays.camera.shape[0] else "the object is out of the camera's view"
    for text, scale, thick, dy, index in (("no camera", 1.2, 2, 0, TEXT), (why, 0.5, 1, 30, OTHER)):
        (tw, _), _ = cv2.getTextSize(text, _FONT, scale, thick)
        _text(panel[0], text, ((cw - tw) // 2, ch // 2 + dy), scale, index, thick)
    panel[1:] = panel[0]


def _legend(strip: NDArray[np.uint8], x: int, clip: Mapping[str, Any], referred: Sequence[str],
            related: Sequence[str]) -> None:
    """The colours' meanings into a (h, w) strip of indices, from column ``x``."""
    entries = [(OBJECT, f"object ({clip.get('category') or 'track ' + str(clip['track_id'])})"), (EGO, "ego")]
    if any(r != str(clip["track_id"]) for r in referred):
        entries.append((REFERRED, "referred to"))
    if related:
        entries.append((RELATED, "related"))
    entries.append((OTHER, "other objects"))
    y = 20
    for index, label in entries:
        if y > strip.shape[0] - 22:
            break
        cv2.rectangle(strip, (x, y - 10), (x + 10, y), index, -1)
        _text(strip, label, (x + 16, y))
        y += 18


def render_preview_indices(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig,
                           referred: Sequence[str] = (), related: Sequence[str] = ()
                           ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """(T, H, W) palette indices of one clip's preview frames (layout in the module docstring) and the
    (256, 3) palette: the fixed colours, then the camera's and the close-up's pixels quantised to the rest.

    Args:
        arrays: the clip's log.
        clip: its clip-table row.
        config: the clips config.
        referred: tracks to mark as referred to by a scenario query (orange), besides the clip's own.
        related: tracks to mark as related to those (cyan).
    """
    from PIL import Image

    layout = PreviewLayout.of(config)
    t = len(clip["frame_indices"])
    canvas = np.full((t, layout.height, layout.width), PANEL, np.uint8)
    palette = np.zeros((256, 3), np.uint8)
    palette[:CAMERA_FIRST] = fixed_palette(config.camera.highlight_rgb)
    camera, closeup = _camera_rgb(arrays, clip, config, layout), _closeup_rgb(arrays, clip, layout)
    cam_panel = canvas[:, : layout.camera_h, : layout.camera_w]
    # The camera's and the close-up's pixels, quantised together to one palette chosen from their source pixels.
    sources = [x.reshape(-1, x.shape[-2], 3) for x in (camera[0] if camera else None, closeup[0] if closeup else None)
               if x is not None]
    if sources:
        width = max(s.shape[1] for s in sources)
        mosaic = np.concatenate([np.pad(s, ((0, 0), (0, width - s.shape[1]), (0, 0))) for s in sources], axis=0)
        step = max(1, mosaic.shape[0] // 512)  # a palette from every step-th row: enough, and cheap
        pal = Image.fromarray(np.ascontiguousarray(mosaic[::step])).quantize(CAMERA_COLOURS,
                                                                           Image.Quantize.FASTOCTREE)
        colours = np.asarray(pal.getpalette() or [], dtype=np.uint8).reshape(-1, 3)[:CAMERA_COLOURS]
        palette[CAMERA_FIRST: CAMERA_FIRST + len(colours)] = colours
        indices = np.asarray(Image.fromarray(mosaic).quantize(palette=pal, dither=Image.Dither.NONE),
                             dtype=np.uint8) + np.uint8(CAMERA_FIRST)
        rows = 0
        if camera is not None:
            t_, h_, w_ = camera[0].shape[:3]  # rows of the mosaic: T frames of camera_h / 2
            half = indices[: t_ * h_, :w_].reshape(t_, h_, w_)
            cam_panel[:] = _resize(half, layout.camera_w, layout.camera_h, cv2.INTER_NEAREST)
            rows = t_ * h_
        if closeup is not None:
            rgb, mask, ok = closeup
            box = indices[rows: rows + rgb.shape[0] * rgb.shape[1], : rgb.shape[2]].reshape(rgb.shape[:3])
            box[~ok] = BLACK
            for i in np.flatnonzero(ok):
                _outline(box[i], mask[i], OBJECT, 1)
            y0 = layout.camera_h + (layout.height - layout.camera_h - rgb.shape[1]) // 2
            canvas[:, y0: y0 + rgb.shape[1], 4: 4 + rgb.shape[2]] = box
            cv2.rectangle(canvas[0], (3, y0 - 1), (4 + rgb.shape[2], y0 + rgb.shape[1]), OTHER, 1)
    if camera is not None:
        _camera_marks(cam_panel, camera[1], arrays, clip, layout)
    else:
        _no_camera(cam_panel, arrays)
    strip = canvas[:, layout.camera_h:, : layout.camera_w]
    _legend(strip[0], layout.closeup_w + 16 if closeup else 8, clip, referred, related)
    legend_x = layout.closeup_w + 14 if closeup else 0
    strip[1:, :, legend_x: layout.camera_w - 100] = strip[0, :, legend_x: layout.camera_w - 100]
    if closeup is not None:  # the close-up's frame, drawn on the first frame above
        strip[1:, :, 3] = strip[0, :, 3]
        strip[1:, :, 4 + layout.closeup_w] = strip[0, :, 4 + layout.closeup_w]
    times = np.asarray(arrays.time_s)[np.asarray(clip["frame_indices"], dtype=np.int64)] if len(arrays.time_s) \
        else np.zeros(t)
    for j in range(t):
        _text(strip[j], f"t = {times[j]:.1f} s", (layout.camera_w - 92, strip.shape[1] - 10))
    canvas[:, :, layout.camera_w + GAP_PX:] = _bev_panel(arrays, clip, config, layout, referred, related)
    return canvas, palette


def render_preview_frames(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig,
                          referred: Sequence[str] = (), related: Sequence[str] = ()) -> NDArray[np.uint8]:
    """(T, H, W, 3) uint8 RGB preview frames of one clip (:func:`render_preview_indices` in colour)."""
    indices, palette = render_preview_indices(arrays, clip, config, referred, related)
    return palette[indices]


def encode_gif(indices: NDArray[np.uint8], palette: NDArray[np.uint8], fps: float) -> bytes:
    """(T, H, W) palette indices (never :data:`TRANSPARENT`) and their (256, 3) palette as a looping animated GIF.

    Each frame after the first keeps only the pixels that change; the rest are transparent and show the
    frame before (GIF disposal 1), which keeps files small at no cost in quality.
    """
    from PIL import Image

    flat = palette.reshape(-1).tolist()
    images = []
    for i, frame in enumerate(indices):
        if i:
            frame = np.where(frame == indices[i - 1], np.uint8(TRANSPARENT), frame)
        image = Image.fromarray(np.ascontiguousarray(frame), mode="L")
        image.putpalette(flat)
        images.append(image)
    out = io.BytesIO()
    images[0].save(out, format="GIF", save_all=True, append_images=images[1:], duration=round(1000.0 / max(fps, 0.1)),
                   loop=0, optimize=False, disposal=1, transparency=TRANSPARENT)
    return out.getvalue()


def preview_gif(clips_dir: Path | str, clip: str | Mapping[str, Any], config: ClipsConfig | None = None,
                arrays: LogArrays | None = None, referred: Sequence[str] = (), related: Sequence[str] = ()) -> bytes:
    """The animated GIF of one clip (by id or by its clip-table row), marking ``referred`` and ``related``
    tracks as :func:`render_preview_indices` does; what the service draws on demand for a scenario query."""
    clips_dir = Path(clips_dir)
    row = read_clip_rows(clips_dir, [clip])[0] if isinstance(clip, str) else clip
    config = config or _config(clips_dir)
    arrays = arrays if arrays is not None else open_log_arrays(clips_dir, str(row["log_id"]))
    indices, palette = render_preview_indices(arrays, row, config, referred, related)
    return encode_gif(indices, palette, config.preview_fps)


def write_preview(
    clips_dir: Path | str, clip: str | Mapping[str, Any], out_path: Path | str, config: ClipsConfig | None = None,
    arrays: LogArrays | None = None,
) -> Path:
    """Write an animated GIF of one clip (by id or by its clip-table row) atomically.

    ``arrays``: the clip's log, opened once by a caller that previews many of its clips (opening it
    reads its frames table and track ids: a third of a preview's time).
    """
    data = preview_gif(clips_dir, clip, config, arrays)
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp:
        Path(tmp).write_bytes(data)
    return out_path


def best_frame(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig) -> int:
    """Index (0 … T − 1) of the sampled frame where the object is most visible: largest camera mask
    when the clip has a camera view, else largest BEV footprint."""
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    value = arrays.track_value[str(clip["track_id"])]
    if bool(clip["has_camera"]) and arrays.camera.shape[0]:
        area = (np.asarray(arrays.camera_instances[fi]) == value).sum(axis=(1, 2))
    else:
        area = object_footprint(arrays, bev_grid(config), str(clip["track_id"]), fi).sum(axis=(1, 2))
    return int(np.argmax(area))


def write_preview_grid(
    clips_dir: Path | str, clip_ids: Sequence[str], out_path: Path | str, columns: int = 2,
    frame_fraction: float | None = None,
) -> Path:
    """A still PNG grid: one preview frame per clip, at ``frame_fraction`` of the clip or, when None,
    where the object is most visible (:func:`best_frame`)."""
    clips_dir = Path(clips_dir)
    config = _config(clips_dir)
    tiles = []
    logs: dict[str, LogArrays] = {}
    for row in read_clip_rows(clips_dir, clip_ids):
        if row["log_id"] not in logs:  # a grid often shows several clips of one log
            logs[row["log_id"]] = open_log_arrays(clips_dir, row["log_id"])
        arrays = logs[row["log_id"]]
        frames = render_preview_frames(arrays, row, config)
        if frame_fraction is None:
            tiles.append(frames[best_frame(arrays, row, config)])
        else:
            tiles.append(frames[min(int(frame_fraction * len(frames)), len(frames) - 1)])
    if not tiles:
        raise ValueError("no clips for the preview grid")
    h, w = tiles[0].shape[:2]
    rows_n = (len(tiles) + columns - 1) // columns
    grid = np.full((rows_n * (h + GAP_PX), columns * (w + GAP_PX), 3), 255, np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, columns)
        grid[r * (h + GAP_PX) : r * (h + GAP_PX) + h, c * (w + GAP_PX) : c * (w + GAP_PX) + w] = tile
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    return out_path
