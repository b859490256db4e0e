"""The clips folder: every file name in it, the clip id, and the readers of its manifest and clip table.

Writers and readers of a clips folder (``scenesearch clips``, the dataset, tagging, retrieval) take
the names from here::

    CLIPS_DIR/clips.parquet           the clip table, one row per clip (:data:`encoders.clips.table.CLIP_SCHEMA`)
    CLIPS_DIR/manifest.json           format version, camera and BEV sizes and channels, per-log stats and
                                      splits, the clips config, skipped inputs
    CLIPS_DIR/previews/<clip>.gif     an animated preview per clip (:func:`preview_file_name`), with `previews`
                                      only; otherwise previews are drawn from the arrays when shown
    CLIPS_DIR/logs/<log_id>/          each log's rendered arrays (:func:`rendered_log_dir`), below

For a log with F frames (its annotation timestamps) :func:`encoders.clips.render.render_log` writes these
arrays, each in zstd blocks of frames (:mod:`encoders.clips.blocks`, read by :func:`load_rendered_array`;
the RGB images, ``camera`` and ``camera_crops``, as differences from the pixel to their left):

===========================  =====================  =========================================================
file                         shape, dtype           content
===========================  =====================  =========================================================
camera.blocks                (F, Hc, Wc, 3) uint8   front camera RGB, resized (F = 0 when the log has no camera)
camera_instances.blocks      (F, Hc, Wc) uint16     instance masks: v ≥ 1 ↔ ``track_ids[v − 1]``, 0 = none
camera_pixel_counts.blocks   (F, K) int32           mask pixels of every track at the camera's full resolution
camera_crops.blocks          (N, Hc, Wc, 3) uint8   every seen track's crop around its box at full resolution
                                                    (:mod:`encoders.clips.crops`), one row per (frame, track)
camera_crop_masks.blocks     (N, Hc, Wc) uint8      the track's mask in its crop (1 = the object)
camera_crop_index.blocks     (F, K) int32           each (frame, track)'s row in the crops, −1 where none
camera_crop_box.blocks       (F, K, 3) float32      the crop's centre in the full image (x, y in [−1, 1]) and the
                                                    track's pixels there, log(1 + px) / log(1 + image px)
bev_lidar.blocks             (F, Z, Hb, Wb) uint8   occupancy per height bin (log-scaled point density)
bev_map.blocks               (F, Cm, Hb, Wb) uint8  map layers (:data:`~encoders.clips.raster.MAP_CHANNELS`)
bev_instances.blocks         (F, Hb, Wb) uint16     box footprints: v ≥ 1 ↔ ``track_ids[v − 1]`` (overlaps: the
                                                    smaller box wins)
track_boxes.blocks           (F, K, 5) float32      every track's ``x_m, y_m, length_m, width_m, yaw_rad`` in
                                                    the frame's ego frame, NaN when not observed; the dataset
                                                    draws the object of interest from it (never hidden by
                                                    an overlapping box)
track_ids.json               list[str]              K track ids
frames.parquet               F rows                 frame_index, timestamp_ns, city_SE3_ego (qw..tz_m), x_m, y_m,
                                                    yaw_rad, speed_mps, has_sweep, has_camera_frame
render.json                  dict                   stats and the rendering config's fingerprint
===========================  =====================  =========================================================

and the tagging stage adds the ground-truth tag rasters beside them (:mod:`encoders.tagging.targets`):
``bev_attributes.blocks`` (F, A, H, W) float16 in compressed frame blocks
(:mod:`encoders.clips.blocks`) and its ``bev_attributes.json`` sidecar (other stems for
attributes added later).

Every BEV grid is in its own frame's ego frame; ego motion is recoverable from ``frames.parquet``.

A clip's id is ``log_id:track_id:start_ns`` (:func:`clip_id`); caption rows without a clip use the
same form, so an id names the same moment everywhere.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from encoders.clips.blocks import BlockArray, BlockFileError
from scenes.bev import BevGrid
from scenes.categories import CATEGORY_NAMES
from scenesearch_base.folders import FolderKind

CLIPS_FILE = "clips.parquet"
#: Format of a clips folder, in its manifest: 2 keeps every rendered per-frame array in ``.blocks`` files,
#: 3 stores the RGB images among them with the Sub filter (:mod:`encoders.clips.blocks`), which readers
#: of format 2 would take for pixels.
CLIPS_FORMAT_VERSION = 3
#: Formats this release reads: a format-2 folder's block files carry no filter.
READABLE_CLIPS_FORMATS = (2, 3)
MANIFEST_FILE = "manifest.json"
PREVIEWS_DIR = "previews"
#: Folder of rendered logs inside CLIPS_DIR.
LOGS_DIR = "logs"
#: The folder ``scenesearch clips`` writes (:mod:`scenesearch_base.folders`).
CLIPS_FOLDER = FolderKind("clips", signature=CLIPS_FILE, entries=(CLIPS_FILE, MANIFEST_FILE, PREVIEWS_DIR, LOGS_DIR))

# Per-log files in CLIPS_DIR/logs/<log_id>/ (the table in the module docstring).
CAMERA_FILE = "camera.blocks"
CAMERA_INSTANCES_FILE = "camera_instances.blocks"
CAMERA_PIXEL_COUNTS_FILE = "camera_pixel_counts.blocks"
CAMERA_CROPS_FILE = "camera_crops.blocks"
CAMERA_CROP_MASKS_FILE = "camera_crop_masks.blocks"
CAMERA_CROP_INDEX_FILE = "camera_crop_index.blocks"
CAMERA_CROP_BOX_FILE = "camera_crop_box.blocks"
BEV_LIDAR_FILE = "bev_lidar.blocks"
BEV_MAP_FILE = "bev_map.blocks"
BEV_INSTANCES_FILE = "bev_instances.blocks"
TRACK_BOXES_FILE = "track_boxes.blocks"
TRACK_IDS_FILE = "track_ids.json"
FRAMES_FILE = "frames.parquet"
RENDER_FILE = "render.json"
#: Stem of the built-in tag targets: ``<stem>.blocks`` holds the rasters, ``<stem>.json`` their sidecar.
TARGETS_STEM = "bev_attributes"


def clip_id(log_id: str, track_id: str, start_ns: int) -> str:
    """The stable id of a moment: ``f"{log_id}:{track_id}:{start_ns}"``."""
    return f"{log_id}:{track_id}:{int(start_ns)}"


def parse_clip_id(value: str) -> tuple[str, str, int]:
    """``(log_id, track_id, start_ns)`` of a clip id (a log id may itself hold colons).

    Raises:
        ValueError: not of the form ``log_id:track_id:start_ns``.
    """
    log_id, _, rest = str(value).rpartition(":")
    log_id, _, track_id = log_id.rpartition(":")
    if not log_id or not track_id or not rest.lstrip("-").isdigit():
        raise ValueError(f"clip_id {value!r}: expected 'log_id:track_id:start_ns' with an integer start_ns")
    return log_id, track_id, int(rest)


class RenderedArrayError(ValueError):
    """A rendered array of a clips folder that cannot be read; the message names the file."""


def load_rendered_array(folder: Path, name: str) -> BlockArray:
    """The array ``folder / name`` of a rendered log, read by the frames indexed (:mod:`encoders.clips.blocks`).

    Raises:
        RenderedArrayError: the file is missing, truncated or not a block file (naming it, and how
            to render it again).
    """
    path = folder / name
    try:
        return BlockArray(path)
    except FileNotFoundError:
        reason = "missing"
    except (BlockFileError, OSError) as exc:
        reason = f"unreadable as an array, truncated or damaged ({exc})"
    raise RenderedArrayError(f"{path}: {reason}; run `scenesearch clips` again to render the log anew")


def rendered_log_dir(clips_dir: Path | str, log_id: str) -> Path:
    """``CLIPS_DIR/logs/<log_id>``: a log's rendered arrays."""
    return Path(clips_dir) / LOGS_DIR / log_id


def preview_file_name(clip_id: str) -> str:
    """File name of a clip's preview: the id with characters unsafe in URLs replaced."""
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in clip_id)
    return f"{safe}.gif"


def read_manifest(clips_dir: Path | str) -> dict[str, Any]:
    """``CLIPS_DIR/manifest.json``.

    Raises:
        FileNotFoundError: there is no manifest (the folder was never built, or its build never finished).
        ValueError: the manifest is not valid JSON, or it describes a folder of another format.
    """
    path = Path(clips_dir) / MANIFEST_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: clips manifest not found (run `scenesearch clips` first)")
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: unreadable clips manifest ({exc})") from None
    found = data.get("format_version") if isinstance(data, dict) else None
    if found is not None and found not in READABLE_CLIPS_FORMATS:
        raise ValueError(f"{path}: format_version {found}, and this release reads clips folders of format "
                         f"{' or '.join(map(str, READABLE_CLIPS_FORMATS))}: run `scenesearch clips` again to "
                         "build the folder anew")
    return data


def grid_from_manifest(manifest: dict[str, Any]) -> BevGrid:
    """The clip stage's BEV grid from the ``bev`` field of ``CLIPS_DIR/manifest.json``."""
    bev = manifest["bev"]
    return BevGrid(float(bev["x_min_m"]), float(bev["x_max_m"]), float(bev["y_min_m"]), float(bev["y_max_m"]),
                   float(bev["resolution_m"]))


def read_clip_table(clips_dir: Path | str, columns: Sequence[str] | None = None) -> pa.Table:
    """``CLIPS_DIR/clips.parquet`` (only ``columns`` when given).

    Raises:
        FileNotFoundError: there is no clip table.
        ValueError: a requested column is missing (names the file and the columns).
    """
    path = Path(clips_dir) / CLIPS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no clip table (run `scenesearch clips` first)")
    if columns is not None:
        missing = [c for c in columns if c not in pq.read_schema(path).names]
        if missing:
            raise ValueError(f"{path}: missing column(s) {missing}")
        return pq.read_table(path, columns=list(columns))
    return pq.read_table(path)


def read_clip_rows(clips_dir: Path | str, clip_ids: Sequence[str]) -> list[dict[str, Any]]:
    """The clip-table rows of ``clip_ids``, in their order.

    Raises:
        KeyError: an id is not in the table (names the file and the id).
    """
    table = read_clip_table(clips_dir)
    wanted = pa.array(list(clip_ids), pa.string())
    found = {r["clip_id"]: r for r in table.filter(pc.is_in(table.column("clip_id"), value_set=wanted)).to_pylist()}
    for cid in clip_ids:
        if cid not in found:
            raise KeyError(f"{Path(clips_dir) / CLIPS_FILE}: no clip with clip_id {cid!r}")
    return [found[cid] for cid in clip_ids]


def check_categories(clips_dir: Path | str, clip_ids: Sequence[str], categories: Sequence[str]) -> None:
    """Every clip's ``category`` is one of the object categories (the captions and the model's category
    table know no other).

    Raises:
        ValueError: names the clip table, the field, the values outside and the first clip holding one.
    """
    unknown = sorted({str(c) for c in categories} - set(CATEGORY_NAMES))
    if unknown:
        first = next(cid for cid, c in zip(clip_ids, categories) if str(c) in unknown)
        raise ValueError(f"{Path(clips_dir) / CLIPS_FILE}: field 'category' holds {unknown} (first at clip "
                         f"{first!r}), not among the object categories {list(CATEGORY_NAMES)}; "
                         "cut the clips again with `scenesearch clips`")
