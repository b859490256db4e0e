"""Ground-truth tag targets in a clips folder: the step after ``scenesearch clips``.

:func:`add_attribute_targets` rasterises every rendered log (:mod:`encoders.tagging.rasterize`) and
writes, per log::

    CLIPS_DIR/logs/<log_id>/bev_attributes.blocks (F, A, H, W) float16, in zstd blocks of frames
                                                  (:mod:`encoders.clips.blocks`: most of the cells are 0)
    CLIPS_DIR/logs/<log_id>/bev_attributes.json   {"attributes": [names], "present": (F, A) 0/1 lists,
                                                  "version": TARGETS_VERSION, "source": "labels" | "rules"}

The behaviour attributes come from the simulator's behaviour labels where the log has them
(``source: labels``) and from the captioning rules' own-behaviour tags otherwise (``source: rules``,
:mod:`captioning.behavior`: tracks and map only, so every log with tracks gets targets); the junction
kinds then come from the map (:mod:`captioning.map_context`) instead of ``junctions.feather``.

``present[f][a]`` says whether attribute ``a`` is non-zero anywhere in frame ``f`` (what the
task-balanced sampler draws from). Both files are written atomically. Attributes added later
(:mod:`encoders.tagging.extend`) use the same pair of files under their own stem.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from captioning.behavior import LABELS, BehaviorTags
from captioning.config import CaptioningConfig, RuleSet
from captioning.map_context import JUNCTION_KINDS, junction_kind_codes, lookup, rasterize_map
from captioning.pipeline import tag_arrays
from encoders.clips.blocks import BlockArray, BlockFileError, write_blocks
from encoders.clips.layout import (
    FRAMES_FILE,
    TARGETS_STEM,
    RenderedArrayError,
    grid_from_manifest,
    read_manifest,
    rendered_log_dir,
)
from encoders.tagging.attributes import ATTRIBUTES, BEHAVIOR_ATTRIBUTES, JUNCTION_ATTRIBUTES, TagError
from encoders.tagging.rasterize import BehaviorGrid, rasterize_targets
from scenes.behavior import BEHAVIOR_FILENAME, BehaviorLabel
from scenes.bev import BevGrid
from scenes.errors import ScenesError
from scenes.log import Log
from scenes.tracks import DenseTracks
from scenesearch_base.atomic import atomic_write_text
from scenesearch_base.checksums import checksum_problem, file_checksums
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_runner import TaskSkipped, TaskStatus, run_tasks
from scenesearch_base.storage import name_of, staged_input

#: Version of the target definitions; targets written by another version are recomputed, not reused.
#: 2: junction kinds cover the junction's approaches, not only its outline.
#: 3: logs without behaviour labels get targets from the captioning rules; the sidecar names the source.
#: 4: the rasters in compressed frame blocks (``.blocks``), not a ``.npy``.
TARGETS_VERSION = 4
#: Frames whose BEV cells are looked up in the map at once (bounds the scratch memory).
_CHUNK_FRAMES = 16


class TargetSource(StrEnum):
    """Where a log's behaviour targets come from."""

    #: The simulator's behaviour labels (``behavior_labels.feather``) and junction kinds.
    LABELS = "labels"
    #: The captioning rules on the log's tracks and map.
    RULES = "rules"


@dataclass
class TargetsReport:
    """What :func:`add_attribute_targets` did."""

    written: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)
    #: log id → :class:`TargetSource` value, for every written or reused log.
    sources: dict[str, str] = field(default_factory=dict)

    def table(self) -> str:
        """One line per log: the log, whether written or reused, and where its targets come from."""
        lines = ["log_id                                  targets  source"]
        for log_id in [*self.written, *self.reused]:
            done = "written" if log_id in self.written else "reused"
            lines.append(f"{log_id:<39} {done:<8} {self.sources.get(log_id, '?')}")
        return "\n".join(lines)


def target_files(folder: Path, stem: str = TARGETS_STEM) -> tuple[Path, Path]:
    """``<stem>.blocks`` (the rasters) and ``<stem>.json`` (their sidecar) in a log's ``CLIPS_DIR/logs/<log_id>``."""
    return folder / f"{stem}.blocks", folder / f"{stem}.json"


def has_targets(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> bool:
    return all(path.is_file() for path in target_files(rendered_log_dir(clips_dir, log_id), stem))


def write_targets(folder: Path, targets: NDArray[np.floating], names: Sequence[str], stem: str = TARGETS_STEM,
                  source: TargetSource = TargetSource.LABELS) -> None:
    """Write ``<stem>.blocks`` (float16) and its ``<stem>.json`` sidecar atomically.

    Args:
        folder: ``CLIPS_DIR/logs/<log_id>``.
        targets: (F, A, H, W) targets.
        names: A attribute names.
        stem: file stem (``bev_attributes``; attributes added later use their own).
        source: where the behaviour targets come from (recorded in the sidecar).
    """
    arr = np.ascontiguousarray(np.asarray(targets, dtype=np.float16))
    present = (arr.reshape(arr.shape[0], arr.shape[1], -1) != 0).any(axis=2).astype(np.uint8)
    array_path, meta_path = target_files(folder, stem)
    write_blocks(array_path, arr)
    meta = {"attributes": list(names), "present": present.tolist(), "version": TARGETS_VERSION,
            "source": TargetSource(source).value, "files": file_checksums(folder, [array_path.name])}
    atomic_write_text(meta_path, json.dumps(meta))


def targets_reusable(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> bool:
    """Whether a log's targets were written by this :data:`TARGETS_VERSION` and their array still has
    the size and checksum its sidecar records (a truncated or changed array is written anew)."""
    folder = rendered_log_dir(clips_dir, log_id)
    meta_path = target_files(folder, stem)[1]
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return (isinstance(meta, dict) and meta.get("version") == TARGETS_VERSION
            and checksum_problem(folder, meta.get("files"), meta_path.name) is None)


def targets_source(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> str:
    """:class:`TargetSource` value of a log's targets (``labels`` for files written before rules could)."""
    meta = json.loads(target_files(rendered_log_dir(clips_dir, log_id), stem)[1].read_text())
    return str(meta.get("source", TargetSource.LABELS.value))


def rule_behavior(log: Log, dense: DenseTracks, config: CaptioningConfig | None = None) -> BehaviorGrid:
    """The captioning rules' own-behaviour tags of a log as a :class:`BehaviorGrid` (tags that could not be
    computed count as absent; the rules name no leader and give the ego none)."""
    config = dataclasses.replace(config or CaptioningConfig(), rules=RuleSet.BEHAVIOR)
    result = tag_arrays(log.log_id, dense.timestamps_ns, dense.track_ids, dense.categories, dense.valid,
                        dense.center_ego_xyz_m[..., :2], dense.yaw_ego_rad, dense.city_SE3_ego, config,
                        vector_map=log.map, length_m=dense.size_lwh_m[..., 0])
    beh = result.behavior
    assert isinstance(beh, BehaviorTags)
    k, f = dense.valid.shape
    order = [LABELS.index(BehaviorLabel(a.value)) for a in BEHAVIOR_ATTRIBUTES]  # the targets' channel order
    flags = (beh.flags & beh.known)[..., order]
    return BehaviorGrid(flags=flags, speed_mps=beh.speed_mps, leader_index=np.full((k, f), -1, np.int64),
                        ego_flags=np.zeros((f, len(BEHAVIOR_ATTRIBUTES)), bool),
                        ego_leader_index=np.full(f, -1, np.int64))


def map_junction_masks(log: Log, grid: BevGrid, city_SE3_ego: NDArray[np.floating], kinds: Sequence[str],
                       config: CaptioningConfig | None = None) -> NDArray[np.float32]:
    """Junction areas of each kind in every frame's ego grid, from the map (a junction and the lanes
    entering it within ``map.junction_approach_m``, as the rules' map context says); zeros without a map.

    Args:
        log: the log (its vector map).
        grid: the BEV grid.
        city_SE3_ego: (F, 4, 4) ego poses.
        kinds: junction kinds, e.g. ``("three_way", "four_way")``.

    Returns:
        (F, len(kinds), H, W) float32.
    """
    config = config or CaptioningConfig()
    poses = np.asarray(city_SE3_ego, dtype=np.float64)
    f = poses.shape[0]
    h, w = grid.shape
    out = np.zeros((f, len(kinds), h, w), np.float32)
    if log.map is None or f == 0:
        return out
    cells = grid.cell_centers_xy().reshape(-1, 2)  # (H*W, 2) ego x, y
    corners = cells[[0, -1]]
    reach = np.einsum("fij,nj->fni", poses[:, :2, :2], corners) + poses[:, None, :2, 3]
    raster = rasterize_map(log.map, reach.reshape(-1, 2), config.map)
    if raster is None:
        return out
    codes = [JUNCTION_KINDS.index(next(k for k in JUNCTION_KINDS if k.value == kind)) for kind in kinds]
    for lo in range(0, f, _CHUNK_FRAMES):
        p = poses[lo : lo + _CHUNK_FRAMES]
        xy = np.einsum("fij,nj->fni", p[:, :2, :2], cells) + p[:, None, :2, 3]  # (n, H*W, 2) city
        kind = junction_kind_codes(raster, lookup(raster, xy), config.map.junction_approach_m)
        for c, code in enumerate(codes):
            out[lo : lo + _CHUNK_FRAMES, c] = (kind == code).reshape(-1, h, w)
    return out


def add_attribute_targets(
    clips_dir: Path | str,
    log_dirs: Sequence[Path | str],
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
    execution: Execution | None = None,
) -> TargetsReport:
    """Write ``bev_attributes.npy`` for every given log that the clips folder has rendered.

    Logs with behaviour labels get targets from them, the others from the captioning rules (see the
    module docstring; ``report.sources`` says which). Logs not rendered in ``clips_dir`` or whose
    frames differ from the rendered ones are skipped and reported; nothing is half-written. One
    task per log (:func:`log_targets`), serially or on Ray (``execution``); the report keeps the
    input order. Log folders may be ``pyarrow.fs`` URIs; the clips folder is local (or shared).
    """
    say = progress or (lambda _line: None)
    clips_dir = Path(clips_dir)
    grid = grid_from_manifest(read_manifest(clips_dir))
    report = TargetsReport()
    ids = [name_of(d) for d in log_dirs]
    run = run_tasks(log_targets, list(log_dirs), execution, labels=ids, context=(clips_dir, grid, overwrite),
                    skip_on=(TagError, ScenesError, ValueError, OSError))
    for log_id, outcome in zip(ids, run.outcomes):
        if outcome.status is not TaskStatus.DONE or outcome.value is None:
            report.skipped.append({"log_id": log_id, "reason": outcome.reason})
            continue
        source, frames = outcome.value
        (report.written if frames is not None else report.reused).append(log_id)
        report.sources[log_id] = source
        if frames is not None:
            say(f"{log_id}: tag targets for {frames} frames from the {source}")
    return report


def log_targets(log_dir: Path | str, ctx: tuple[Path, BevGrid, bool]) -> tuple[str, int | None]:
    """One log's task of :func:`add_attribute_targets`: → (its :class:`TargetSource` value, frames
    written, or None when its targets were reused).

    Raises:
        TaskSkipped: the log is not rendered in the clips folder.
        TagError, ScenesError, ValueError, OSError: its targets cannot be made.
    """
    clips_dir, grid, overwrite = ctx
    log_id = name_of(log_dir)
    folder = rendered_log_dir(clips_dir, log_id)
    if not (folder / FRAMES_FILE).is_file():
        raise TaskSkipped("not rendered in the clips folder")
    if not overwrite and targets_reusable(clips_dir, log_id):
        return targets_source(clips_dir, log_id), None
    with staged_input(log_dir) as local:
        log = Log.open(local)
        dense = log.dense_tracks()
        rendered = pq.read_table(folder / FRAMES_FILE, columns=["timestamp_ns"]).column(0).to_numpy()
        if not np.array_equal(rendered, dense.timestamps_ns):
            raise TagError(f"{folder / FRAMES_FILE}: frame timestamps differ from the log's annotations")
        if (local / BEHAVIOR_FILENAME).is_file():
            source = TargetSource.LABELS
            targets = rasterize_targets(log, grid, dense)
        else:
            source = TargetSource.RULES
            targets = rasterize_targets(log, grid, dense, behavior=rule_behavior(log, dense))
            kinds = tuple(a.value for a in JUNCTION_ATTRIBUTES)
            channels = [ATTRIBUTES.index(a) for a in JUNCTION_ATTRIBUTES]
            targets[:, channels] = map_junction_masks(log, grid, dense.city_SE3_ego, kinds)
    write_targets(folder, targets, [a.value for a in ATTRIBUTES], source=source)
    return source.value, int(targets.shape[0])


@dataclass(frozen=True)
class LogTargets:
    """A log's targets, read by frames as they are indexed (:class:`encoders.clips.blocks.BlockArray`).

    Attributes:
        targets: (F, A, H, W) float16.
        names: A attribute names.
        present: (F, A) bool, attribute non-zero somewhere in the frame.
    """

    targets: BlockArray
    names: tuple[str, ...]
    present: NDArray[np.bool_]


def open_targets(clips_dir: Path | str, log_id: str, stem: str = TARGETS_STEM) -> LogTargets:
    array_path, meta_path = target_files(rendered_log_dir(clips_dir, log_id), stem)
    if not has_targets(clips_dir, log_id, stem):
        raise FileNotFoundError(f"{array_path}: no tag targets (run `scenesearch eval-tags --logs` "
                                "or encoders.tagging.targets.add_attribute_targets first)")
    meta = json.loads(meta_path.read_text())
    try:
        arr = BlockArray(array_path)
    except BlockFileError as exc:
        raise RenderedArrayError(f"{exc}; run `scenesearch clips --tag-targets` again to write it anew") from None
    present = np.asarray(meta["present"], dtype=bool).reshape(arr.shape[0], arr.shape[1])
    return LogTargets(arr, tuple(meta["attributes"]), present)
