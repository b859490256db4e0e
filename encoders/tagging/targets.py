"""Ground-truth tag targets in a clips folder: the step after ``scenesearch clips``.

:func:`add_attribute_targets` rasterises every rendered log (:mod:`encoders.tagging.rasterize`) and
writes, per log::

    CLIPS_DIR/logs/<log_id>/bev_attributes.npy    (F, A, H, W) float16
    CLIPS_DIR/logs/<log_id>/bev_attributes.json   {"attributes": [names], "present": (F, A) 0/1 lists,
                                                  "version": TARGETS_VERSION}

``present[f][a]`` says whether attribute ``a`` is non-zero anywhere in frame ``f`` (what the
task-balanced sampler draws from). Both files are written atomically. Attributes added later
(:mod:`encoders.tagging.extend`) use the same pair of files under their own stem.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from common.atomic import atomic_path, atomic_write_text
from encoders.clips.layout import FRAMES_FILE, TARGETS_STEM, grid_from_manifest, read_manifest, rendered_log_dir
from encoders.tagging.attributes import ATTRIBUTES, TagError
from encoders.tagging.rasterize import rasterize_targets
from scenes.log import Log

#: Version of the target definitions; targets written by another version are recomputed, not reused.
#: 2: junction kinds cover the junction's approaches, not only its outline.
TARGETS_VERSION = 2


@dataclass
class TargetsReport:
    """What :func:`add_attribute_targets` did."""

    written: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)


def target_files(folder: Path, stem: str = TARGETS_STEM) -> tuple[Path, Path]:
    """``<stem>.npy`` (the rasters) and ``<stem>.json`` (their sidecar) in a log's ``CLIPS_DIR/logs/<log_id>``."""
    return folder / f"{stem}.npy", folder / f"{stem}.json"


def has_targets(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> bool:
    return all(path.is_file() for path in target_files(rendered_log_dir(clips_dir, log_id), stem))


def write_targets(folder: Path, targets: NDArray[np.floating], names: Sequence[str], stem: str = TARGETS_STEM) -> None:
    """Write ``<stem>.npy`` (float16) and its ``<stem>.json`` sidecar atomically.

    Args:
        folder: ``CLIPS_DIR/logs/<log_id>``.
        targets: (F, A, H, W) targets.
        names: A attribute names.
        stem: file stem (``bev_attributes``; attributes added later use their own).
    """
    arr = np.ascontiguousarray(np.asarray(targets, dtype=np.float16))
    present = (arr.reshape(arr.shape[0], arr.shape[1], -1) != 0).any(axis=2).astype(np.uint8)
    array_path, meta_path = target_files(folder, stem)
    with atomic_path(array_path) as tmp, open(tmp, "wb") as fh:
        np.save(fh, arr, allow_pickle=False)
    meta = {"attributes": list(names), "present": present.tolist(), "version": TARGETS_VERSION}
    atomic_write_text(meta_path, json.dumps(meta))


def targets_version(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> int:
    """The :data:`TARGETS_VERSION` a log's targets were written with (1 for files without one)."""
    meta = json.loads(target_files(rendered_log_dir(clips_dir, log_id), stem)[1].read_text())
    return int(meta.get("version", 1))


def add_attribute_targets(
    clips_dir: Path | str,
    log_dirs: Sequence[Path | str],
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> TargetsReport:
    """Write ``bev_attributes.npy`` for every given log that the clips folder has rendered.

    Logs not rendered in ``clips_dir``, without behaviour labels, or whose frames differ from the
    rendered ones are skipped and reported; nothing is half-written.
    """
    say = progress or (lambda _line: None)
    clips_dir = Path(clips_dir)
    grid = grid_from_manifest(read_manifest(clips_dir))
    report = TargetsReport()
    for log_dir in log_dirs:
        log_id = Path(log_dir).name
        folder = rendered_log_dir(clips_dir, log_id)
        if not (folder / FRAMES_FILE).is_file():
            report.skipped.append({"log_id": log_id, "reason": "not rendered in the clips folder"})
            continue
        if not overwrite and has_targets(clips_dir, log_id) and targets_version(clips_dir, log_id) == TARGETS_VERSION:
            report.reused.append(log_id)
            continue
        try:
            log = Log.open(log_dir)
            dense = log.dense_tracks()
            rendered = pq.read_table(folder / FRAMES_FILE, columns=["timestamp_ns"]).column(0).to_numpy()
            if not np.array_equal(rendered, dense.timestamps_ns):
                raise TagError(f"{folder / FRAMES_FILE}: frame timestamps differ from the log's annotations")
            targets = rasterize_targets(log, grid, dense)
        except (TagError, ValueError, OSError) as exc:
            report.skipped.append({"log_id": log_id, "reason": str(exc)})
            continue
        write_targets(folder, targets, [a.value for a in ATTRIBUTES])
        report.written.append(log_id)
        say(f"{log_id}: tag targets for {targets.shape[0]} frames")
    return report


@dataclass(frozen=True)
class LogTargets:
    """A log's targets opened with ``mmap_mode='r'``.

    Attributes:
        targets: (F, A, H, W) float16.
        names: A attribute names.
        present: (F, A) bool, attribute non-zero somewhere in the frame.
    """

    targets: NDArray[np.float16]
    names: tuple[str, ...]
    present: NDArray[np.bool_]


def open_targets(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> LogTargets:
    array_path, meta_path = target_files(rendered_log_dir(clips_dir, log_id), stem)
    if not has_targets(clips_dir, log_id, stem):
        raise FileNotFoundError(f"{array_path}: no tag targets (run `scenesearch eval-tags --logs` "
                                "or encoders.tagging.targets.add_attribute_targets first)")
    meta = json.loads(meta_path.read_text())
    arr = np.load(array_path, mmap_mode="r")
    present = np.asarray(meta["present"], dtype=bool).reshape(arr.shape[0], arr.shape[1])
    return LogTargets(arr, tuple(meta["attributes"]), present)
