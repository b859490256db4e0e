"""The canvas a clip's preview is drawn on (:mod:`encoders.clips.preview`): sizes, colours, palette, text.

Colours: the object of interest is the camera's highlight colour (magenta by default), the ego
green, other objects grey outlines; a preview drawn for a scenario query adds the tracks the program
refers to (orange) and relates them to (cyan). BEV map: drivable area dark grey, lane boundaries grey,
crossings olive, intersections dark blue; LiDAR (or box) occupancy above the lowest height bin white.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from encoders.clips.config import ClipsConfig

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
FONT = cv2.FONT_HERSHEY_SIMPLEX

# Frames are drawn as indices into one palette: fixed entries for everything but the camera's pixels,
# which take the rest (:data:`CAMERA_COLOURS`), chosen per clip. Marks and text are drawn straight
# into the indices, so only the camera's pixels are ever quantised.
(PANEL, BLACK, DRIVABLE, INTERSECTION, CROSSING, LANE, EGO, OTHER, REFERRED, RELATED, TEXT, WHITE, NO_CAMERA,
 OBJECT, REFERRED_FILL, RELATED_FILL) = range(16)
#: Occupancy levels: a grey ramp from 80 to 255 in :data:`OCCUPANCY_LEVELS` steps.
OCCUPANCY_FIRST, OCCUPANCY_LEVELS = 16, 16
CAMERA_FIRST = OCCUPANCY_FIRST + OCCUPANCY_LEVELS
#: The last entry: transparent in the GIF, where a frame repeats the one before it
#: (:func:`~encoders.clips.preview.encode_gif`).
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
    """Pixel sizes of a preview's panels (see :mod:`encoders.clips.preview`).

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


def resize_frames(frames: NDArray[Any], width: int, height: int, interpolation: int) -> NDArray[Any]:
    """(T, H, W[, C]) → (T, height, width[, C]), every frame alike."""
    if not len(frames):
        return np.zeros((0, height, width, *frames.shape[3:]), frames.dtype)
    return np.stack([cv2.resize(np.ascontiguousarray(f), (width, height), interpolation=interpolation)
                     for f in frames])


def put_text(image: NDArray[np.uint8], text: str, org: tuple[int, int], scale: float = 0.45, index: int = TEXT,
             thickness: int = 1) -> None:
    """Write ``text`` into (H, W) palette indices: OpenCV shades the edges of its letters whatever the line
    type, which in indices would be other colours, so the letters are cut from a mask."""
    (tw, th), base = cv2.getTextSize(text, FONT, scale, thickness)
    x0, y0 = max(org[0] - 2, 0), max(org[1] - th - 2, 0)
    x1, y1 = min(org[0] + tw + 2, image.shape[1]), min(org[1] + base + 2, image.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.putText(mask, text, (org[0] - x0, org[1] - y0), FONT, scale, 255, thickness, cv2.LINE_8)
    image[y0:y1, x0:x1][mask > 100] = index
