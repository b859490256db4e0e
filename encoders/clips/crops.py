"""Object-centred camera crops: each track's box in the full-resolution image, cut out at the clips' camera size.

At the clips' 64 × 32 camera, many objects are too small to see: on the demo's test split the object
covers at most half a pixel in nearly half the clips with a camera (a 66-pixel object at 640 × 360 is
under one pixel there; ``docs/research/camera-small-objects.md``), so the camera tower reads the ego's
motion and little of the object. A crop around the object's box at full resolution shows the same
object at about 16 × 16 pixels, and the crop's place and the object's size in the full image
(:data:`CROP_BOX_COLUMNS`) keep what the crop drops: where the object is and how near.

The crop is the object's box grown by :data:`CROP_CONTEXT`, at least :data:`CROP_MIN_HALF_HEIGHT_PX`
high on each side of its centre, at the camera's aspect (Wc / Hc); parts outside the image are black.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

#: The crop's size over the object's box (the rest is context: the road, the lane, what is next to it).
CROP_CONTEXT = 1.5
#: The smallest half height of a crop, full-resolution pixels: a far object is magnified at most
#: Hc / 16 times (2× at 32 pixels high), so its few pixels are not blown up into blur.
CROP_MIN_HALF_HEIGHT_PX = 8.0
#: Per (frame, track): the crop's centre in the full image (x and y in [−1, 1]) and the object's
#: full-resolution pixels on a log scale, log(1 + pixels) / log(1 + image pixels).
CROP_BOX_COLUMNS = ("center_x", "center_y", "log_pixels")

Pixel = TypeVar("Pixel", np.uint8, np.uint16)


def crop_affine(box_xyxy_px: tuple[float, float, float, float], height_px: int, width_px: int) -> NDArray[np.float64]:
    """(2, 3) the affine map from full-resolution image pixels to the crop's pixels.

    Args:
        box_xyxy_px: the object's box in the full image, ``x0, y0, x1, y1`` (x1, y1 exclusive).
        height_px, width_px: the crop's size (the clips' camera size).
    """
    x0, y0, x1, y1 = box_xyxy_px
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    half_h = max(0.5 * CROP_CONTEXT * max(y1 - y0, (x1 - x0) * height_px / width_px), CROP_MIN_HALF_HEIGHT_PX)
    half_w = half_h * width_px / height_px
    scale = height_px / (2.0 * half_h)
    return np.array([[scale, 0.0, -scale * (cx - half_w)], [0.0, scale, -scale * (cy - half_h)]])


def crop_image(image: NDArray[Pixel], affine: NDArray[np.float64], height_px: int, width_px: int,
               nearest: bool = False) -> NDArray[Pixel]:
    """Cut ``image`` (H, W[, 3]) through ``affine`` into (height_px, width_px[, 3]) of its dtype: area
    averaging where the crop shrinks the image, bilinear where it magnifies, nearest for labels."""
    if nearest:
        flags = cv2.INTER_NEAREST
    else:
        flags = cv2.INTER_AREA if affine[0, 0] < 1.0 else cv2.INTER_LINEAR
    return np.asarray(cv2.warpAffine(image, affine, (width_px, height_px), flags=flags,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0), dtype=image.dtype)


def box_columns(box_xyxy_px: tuple[float, float, float, float], pixels: float, image_hw: tuple[int, int]
                ) -> tuple[float, float, float]:
    """:data:`CROP_BOX_COLUMNS` of an object in ``box_xyxy_px`` covering ``pixels`` of an image of ``image_hw``."""
    h, w = image_hw
    x0, y0, x1, y1 = box_xyxy_px
    return (float((x0 + x1) / w - 1.0), float((y0 + y1) / h - 1.0),
            float(np.log1p(max(pixels, 0.0)) / np.log1p(h * w)))


@dataclass
class ObjectCrops:
    """The crops of one log as they are cut, then as arrays (:meth:`arrays`; the files of
    :mod:`encoders.clips.layout`).

    Attributes:
        index: (F, K) int32 each (frame, track)'s row among the crops, −1 where none.
        box: (F, K, 3) float32 :data:`CROP_BOX_COLUMNS` where a crop exists, else 0.
    """

    frames: int
    tracks: int
    height_px: int
    width_px: int
    index: NDArray[np.int32] = field(init=False)
    box: NDArray[np.float32] = field(init=False)
    _rgb: list[NDArray[np.uint8]] = field(init=False, default_factory=list)
    _mask: list[NDArray[np.uint8]] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        self.index = np.full((self.frames, self.tracks), -1, np.int32)
        self.box = np.zeros((self.frames, self.tracks, len(CROP_BOX_COLUMNS)), np.float32)

    def add(self, frame: int, track: int, rgb: NDArray[np.uint8], mask: NDArray[np.bool_] | NDArray[np.uint8],
            box: tuple[float, float, float]) -> None:
        """Keep the crop of ``track`` in ``frame``: (Hc, Wc, 3) RGB, (Hc, Wc) object mask, its box columns."""
        self.index[frame, track] = len(self._rgb)
        self._rgb.append(rgb)
        self._mask.append(np.asarray(mask, dtype=np.uint8))
        self.box[frame, track] = box

    def arrays(self) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.int32], NDArray[np.float32]]:
        """(N, Hc, Wc, 3) RGB crops, (N, Hc, Wc) uint8 masks (1 = the object), the (F, K) index, the (F, K, 3) boxes."""
        shape = (self.height_px, self.width_px)
        rgb = np.stack(self._rgb) if self._rgb else np.zeros((0, *shape, 3), np.uint8)
        mask = np.stack(self._mask) if self._mask else np.zeros((0, *shape), np.uint8)
        return rgb, mask, self.index, self.box


def crop_instances(crops: ObjectCrops, frame: int, bgr: NDArray[np.uint8], instances: NDArray[np.uint16],
                   track_of_value: NDArray[np.uint16]) -> NDArray[np.int32]:
    """Cut every track seen in a full-resolution instance mask, and count each track's pixels.

    The pixels are counted inside each track's own bounding box, found in the same pass over the
    mask: objects' boxes cover a small part of the image, so this is cheaper than counting every
    value of the whole image (boxes that together cover the image several times would cost more).
    The mask is read as stored, through ``track_of_value``: remapping a whole full-resolution mask
    to the log's tracks would cost a pass over every pixel.

    Args:
        crops: receives the crops.
        frame: the frame's index.
        bgr: (H, W, 3) the full-resolution image (OpenCV's BGR).
        instances: (H, W) instance values at full resolution, each below ``len(track_of_value)``.
        track_of_value: (V,) mask value v → 1 + its track's index (0: no track of the log); no two
            values name the same track.

    Returns:
        (K,) int32 each track's pixels in ``instances``.
    """
    from scipy.ndimage import find_objects

    pixels = np.zeros(crops.tracks, np.int32)
    found = find_objects(instances, max_label=track_of_value.shape[0] - 1)
    seen = sorted((int(track_of_value[v]) - 1, v, where) for v, where in enumerate(found, start=1)
            if where is not None)
    for k, v, where in seen:  # in track order, however the mask numbers them
        if not 0 <= k < crops.tracks:
            continue
        pixels[k] = np.count_nonzero(instances[where] == v)
        box = (float(where[1].start), float(where[0].start), float(where[1].stop), float(where[0].stop))
        affine = crop_affine(box, crops.height_px, crops.width_px)
        rgb = cv2.cvtColor(crop_image(bgr, affine, crops.height_px, crops.width_px), cv2.COLOR_BGR2RGB)
        # The labels are cut through the RGB's own map, so that both sample the same pixels.
        mask = crop_image(instances, affine, crops.height_px, crops.width_px, nearest=True) == v
        crops.add(frame, k, np.asarray(rgb, np.uint8), mask, box_columns(box, float(pixels[k]), instances.shape))
    return pixels


def crop_projected(crops: ObjectCrops, frame: int, bgr: NDArray[np.uint8], corners_uv_px: NDArray[np.floating],
                   tracks: NDArray[np.integer], pixels: NDArray[np.integer]) -> None:
    """Cut every track whose box projects into the image (logs with images and no instance masks).

    Args:
        crops: receives the crops.
        frame: the frame's index.
        bgr: (H, W, 3) the full-resolution image.
        corners_uv_px: (K, 8, 2) each track's box corners in full-resolution pixels.
        tracks: the tracks in front of the camera in this frame.
        pixels: (K,) each track's full-resolution pixels in the projected masks (0: hidden or outside).
    """
    h, w = bgr.shape[:2]
    for k in tracks:
        if pixels[k] <= 0:
            continue
        uv = np.asarray(corners_uv_px[k], dtype=np.float64)
        x0, y0 = np.clip(uv.min(axis=0), 0, (w, h))
        x1, y1 = np.clip(uv.max(axis=0), 0, (w, h))
        if x1 <= x0 or y1 <= y0:
            continue
        box = (float(x0), float(y0), float(x1), float(y1))
        affine = crop_affine(box, crops.height_px, crops.width_px)
        rgb = cv2.cvtColor(crop_image(bgr, affine, crops.height_px, crops.width_px), cv2.COLOR_BGR2RGB)
        in_crop = uv @ affine[:, :2].T + affine[:, 2]
        mask = np.zeros((crops.height_px, crops.width_px), np.uint8)
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(in_crop * 16).astype(np.int32)), 1,
                           lineType=cv2.LINE_8, shift=4)
        crops.add(frame, int(k), np.asarray(rgb, np.uint8), mask, box_columns(box, float(pixels[k]), (h, w)))
