"""Whether a log's rendered arrays can be reused: what rendering did, and fingerprints of its inputs.

``CLIPS_DIR/logs/<log_id>/render.json`` holds a :class:`LogRenderStats`; a rendering is reused when
its fingerprints (the rendering config's and the log content's) match the current ones and every
file it lists still has its size and SHA-256: a truncated, deleted or changed array is rendered
again, never reused.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from encoders.clips.config import BevSource, ClipsConfig
from encoders.clips.layout import RENDER_FILE
from scenes.tracks import DenseTracks
from scenesearch_base.checksums import checksum_problem

#: Version of the per-log files; bump when their content or their format changes (6: `.blocks` files).
RENDER_VERSION = 6


def render_fingerprint(config: ClipsConfig) -> str:
    """Hash of everything that changes the per-log arrays (not splits, previews or clip sampling)."""
    payload = {"version": RENDER_VERSION, "camera": asdict(config.camera), "bev": config.to_dict()["bev"]}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def log_fingerprint(dense: DenseTracks) -> str:
    """Hash of a log's content as rendering sees it: frame times, track ids, boxes and ego poses.

    A log written again into the same folder (e.g. simulated anew) gets a new fingerprint, so its
    old rendering is never reused.
    """
    h = hashlib.sha256()
    for array in (dense.timestamps_ns, dense.valid, dense.center_city_xyz_m, dense.size_lwh_m, dense.city_SE3_ego):
        h.update(np.ascontiguousarray(array).tobytes())
    h.update("\0".join(map(str, dense.track_ids)).encode())
    return h.hexdigest()[:16]


@dataclass
class LogRenderStats:
    """What rendering one log did; kept in ``render.json`` and the manifest.

    Attributes:
        log_id: the log.
        frames: F.
        tracks: K.
        bev_source: ``lidar`` or ``boxes``.
        sweeps: sweeps on disk.
        sweep_coverage: fraction of frames with a usable sweep within tolerance.
        corrupt_sweeps: file names of sweeps that could not be read (skipped).
        frames_without_sweep: frames whose BEV occupancy is empty because no usable sweep was near
            (only for ``lidar`` logs).
        camera_frames: frames with a camera image.
        camera_frames_missing: frames without one (black, no masks) when the log has a camera.
        camera_mask_source: ``instance_masks``, ``projected_boxes`` or ``none``.
        corrupt_camera_frames: file names of images or masks that could not be decoded (skipped).
        bytes: disk used by the log's arrays.
        render_s: wall time.
        fingerprint: :func:`render_fingerprint` of the config used.
        log_fingerprint: :func:`log_fingerprint` of the log rendered.
        files: every other file of the rendering: name → ``{"size_bytes", "sha256"}``.
    """

    log_id: str
    frames: int = 0
    tracks: int = 0
    bev_source: str = BevSource.BOXES.value
    sweeps: int = 0
    sweep_coverage: float = 0.0
    corrupt_sweeps: list[str] = field(default_factory=list)
    frames_without_sweep: int = 0
    camera_frames: int = 0
    camera_frames_missing: int = 0
    camera_mask_source: str = "none"
    corrupt_camera_frames: list[str] = field(default_factory=list)
    bytes: int = 0
    render_s: float = 0.0
    fingerprint: str = ""
    log_fingerprint: str = ""
    files: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def reuse_problem(folder: Path, config: ClipsConfig, dense: DenseTracks) -> str | None:
    """Why ``folder`` does not hold a reusable rendering of this log's content (``dense``) made with an
    equivalent config, or None when it does: every file that ``render.json`` lists must still have its
    size and checksum."""
    path = folder / RENDER_FILE
    if not path.is_file():
        return "not rendered before"
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return f"{RENDER_FILE} is unreadable"
    if not isinstance(data, dict) or data.get("fingerprint") != render_fingerprint(config):
        return "rendered with another config"
    if data.get("log_fingerprint") != log_fingerprint(dense):
        return "the log changed since it was rendered"
    return checksum_problem(folder, data.get("files"), RENDER_FILE)


def read_render_stats(folder: Path) -> LogRenderStats:
    data = json.loads((folder / RENDER_FILE).read_text())
    return LogRenderStats(**{k: v for k, v in data.items() if k in LogRenderStats.__dataclass_fields__})
