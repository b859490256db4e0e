"""Previews of clips: an animated GIF per clip (camera and BEV side by side) and a still grid.

Layout of a preview frame, :data:`~encoders.clips.preview_canvas.PREVIEW_HEIGHT_PX` high whatever the clips'
own sizes::

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
below the camera. The BEV half is drawn by :mod:`encoders.clips.preview_bev`; the panels' sizes, the
colours and the palette are those of :mod:`encoders.clips.preview_canvas`.

Frames are drawn straight into palette indices (:func:`render_preview_indices`) and written as a GIF
whose later frames keep only the pixels that change (:func:`encode_gif`): only the camera's pixels are
ever quantised, and the camera at half the panel's size.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from encoders.clips.config import ClipsConfig
from encoders.clips.layout import read_clip_rows, read_manifest
from encoders.clips.preview_bev import bev_panel
from encoders.clips.preview_canvas import (
    BLACK,
    CAMERA_COLOURS,
    CAMERA_FIRST,
    EGO,
    FONT,
    GAP_PX,
    NO_CAMERA,
    OBJECT,
    OTHER,
    PANEL,
    REFERRED,
    RELATED,
    TEXT,
    TRANSPARENT,
    PreviewLayout,
    fixed_palette,
    put_text,
    resize_frames,
)
from encoders.clips.render import bev_grid
from encoders.clips.views import LogArrays, highlight_camera, object_footprint, open_log_arrays
from scenesearch_base.atomic import atomic_path


def _config(clips_dir: Path) -> ClipsConfig:
    """The config the clips folder was built with (its manifest's ``config`` field)."""
    return ClipsConfig.from_dict(read_manifest(clips_dir).get("config", {}))




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
    return resize_frames(rgb, layout.camera_w // 2, layout.camera_h // 2, cv2.INTER_LINEAR), mask


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
    rgb[ok] = resize_frames(np.asarray(crops.rgb[rows[ok]]), w, h, cv2.INTER_LINEAR)
    mask[ok] = resize_frames(np.asarray(crops.mask[rows[ok]]) * np.uint8(255), w, h, cv2.INTER_LINEAR) > 96
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
    mask_up = resize_frames(mask.astype(np.uint8) * np.uint8(255), cw, ch, cv2.INTER_LINEAR) > 96
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
        (tw, _), _ = cv2.getTextSize(text, FONT, scale, thick)
        put_text(panel[0], text, ((cw - tw) // 2, ch // 2 + dy), scale, index, thick)
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
        put_text(strip, label, (x + 16, y))
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
            cam_panel[:] = resize_frames(half, layout.camera_w, layout.camera_h, cv2.INTER_NEAREST)
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
        put_text(strip[j], f"t = {times[j]:.1f} s", (layout.camera_w - 92, strip.shape[1] - 10))
    canvas[:, :, layout.camera_w + GAP_PX:] = bev_panel(arrays, clip, config, layout, referred, related)
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
