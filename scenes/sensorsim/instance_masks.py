"""Per-frame instance masks beside the camera frames.

Layout (beyond AV2; readers work when it is absent)::

    <log>/sensors/cameras/<camera>_instance/<timestamp_ns>.png   16-bit PNG, one value per pixel
    <log>/sensors/cameras/instance_track_ids.json                ["track id", ...]

A mask value of 0 is background (ground, sky, buildings); a value ``v ≥ 1`` is the track
``track_ids[v − 1]``, the object nearest the camera at that pixel. Note that the mask folder is a
subfolder of ``sensors/cameras``: camera listings must skip names ending in :data:`INSTANCE_SUFFIX`.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.av2_io import CAMERAS_DIR
from scenes.errors import LogFormatError
from scenesearch_base.atomic import atomic_write_bytes, atomic_write_text

INSTANCE_SUFFIX = "_instance"
TRACK_IDS_FILENAME = "instance_track_ids.json"


def instance_mask_dir(log_dir: Path | str, camera_name: str) -> Path:
    """The folder of a camera's instance masks."""
    return Path(log_dir) / CAMERAS_DIR / f"{camera_name}{INSTANCE_SUFFIX}"


def instance_mask_path(log_dir: Path | str, camera_name: str, timestamp_ns: int) -> Path:
    return instance_mask_dir(log_dir, camera_name) / f"{int(timestamp_ns)}.png"


def track_ids_path(log_dir: Path | str) -> Path:
    return Path(log_dir) / CAMERAS_DIR / TRACK_IDS_FILENAME


def write_instance_mask(log_dir: Path | str, camera_name: str, timestamp_ns: int, mask: NDArray[np.uint16]) -> Path:
    """Write one mask as a 16-bit PNG, atomically. ``mask``: (H, W) uint16."""
    if mask.dtype != np.uint16 or mask.ndim != 2:
        raise ValueError(f"instance mask must be (H, W) uint16, got {mask.shape} {mask.dtype}")
    ok, encoded = cv2.imencode(".png", mask, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError(f"cannot encode instance mask {camera_name}/{timestamp_ns} as PNG")
    path = instance_mask_path(log_dir, camera_name, timestamp_ns)
    atomic_write_bytes(path, encoded.tobytes())
    return path


def write_instance_track_ids(log_dir: Path | str, track_ids: list[str]) -> Path:
    """Write the track list that mask values index (value v ↔ ``track_ids[v − 1]``)."""
    path = track_ids_path(log_dir)
    atomic_write_text(path, json.dumps([str(t) for t in track_ids]))
    return path


def read_instance_track_ids(log_dir: Path | str) -> list[str]:
    path = track_ids_path(log_dir)
    if not path.is_file():
        raise LogFormatError.single(path, "file is missing (the log has no instance masks)")
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise LogFormatError.single(path, f"unreadable JSON: {exc}") from exc
    if not isinstance(data, list) or not all(isinstance(t, str) for t in data):
        raise LogFormatError.single(path, "expected a JSON list of track id strings")
    first: dict[str, int] = {}
    for row, track_id in enumerate(data):  # two mask values would name one track
        if first.setdefault(track_id, row) != row:
            raise LogFormatError.single(path, f"track id {track_id!r} is listed twice (first at row {first[track_id]})",
                                        field="track_id", row=row)
    return data


def read_instance_mask(
    log_dir: Path | str, camera_name: str, timestamp_ns: int, track_ids: list[str] | None = None
) -> tuple[NDArray[np.uint16], list[str]]:
    """One frame's instance mask and the track list it indexes (``track_ids``, when the caller read it
    already with :func:`read_instance_track_ids`: a log's frames share one list).

    Returns:
        (H, W) uint16 mask (0 background, v ≥ 1 the track ``track_ids[v − 1]``) and ``track_ids``.

    Raises:
        LogFormatError: naming the file when the mask or the track list is missing, unreadable, or
            holds a value beyond the track list.
    """
    track_ids = read_instance_track_ids(log_dir) if track_ids is None else track_ids
    path = instance_mask_path(log_dir, camera_name, timestamp_ns)
    if not path.is_file():
        raise LogFormatError.single(path, "file is missing")
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None or mask.ndim != 2 or mask.dtype != np.uint16:
        raise LogFormatError.single(path, "not a single-channel 16-bit PNG")
    top = int(mask.max()) if mask.size else 0
    if top > len(track_ids):
        raise LogFormatError.single(path, f"mask value {top} is beyond the {len(track_ids)} tracks of "
                                          f"{TRACK_IDS_FILENAME}", field="value")
    return np.asarray(mask, dtype=np.uint16), track_ids
