"""Waymo Open Motion Dataset scenarios into log folders in the AV2 layout (see :mod:`scenes.womd`)."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scenes import av2_io
from scenes.categories import CATEGORY_TO_AV2, Category
from scenes.errors import ScenesError
from scenes.geometry import FloatArray, wrap_angle_rad, yaw_to_quat
from scenes.log import Log
from scenes.map import VectorMap
from scenes.metadata import LogMetadata
from scenes.tracks import Annotations, EgoTrajectory
from scenes.womd.proto import DecodeError, ObjectType, parse_scenario
from scenes.womd.roadmap import WomdMap, vector_map_from_womd, womd_map_from_features
from scenes.womd.tfrecord import WomdFormatError, iter_records
from scenesearch_base.folders import claimed_directory

#: WOMD object types as public categories. WOMD does not tell cars from trucks or buses, so every
#: vehicle is a car; an unset type is counted and becomes ``other``.
WOMD_TO_CATEGORY: dict[int, Category] = {
    ObjectType.VEHICLE: Category.CAR,
    ObjectType.PEDESTRIAN: Category.PEDESTRIAN,
    ObjectType.CYCLIST: Category.CYCLIST,
    ObjectType.OTHER: Category.OTHER,
}
#: The ego origin (rear axle, on the ground) lies this far behind the centre of the ego's box, as in
#: the default ego body of :class:`scenes.sensorsim.config.LidarConfig` (``ego_box_center_x_m``).
EGO_BOX_CENTER_AHEAD_M = 1.4
CITY_NAME = "WOMD"
LOG_PREFIX = "womd_"
_SCENARIO_ID = re.compile(r"[A-Za-z0-9_.-]+")


@dataclass(frozen=True)
class ScenarioTracks:
    """The tracks of one scenario on its time grid (WOMD's world frame = our city frame).

    Attributes:
        scenario_id: the scenario's id.
        timestamps_ns: (T,) strictly increasing step times.
        track_ids: (K,) WOMD track ids.
        object_types: (K,) :class:`~scenes.womd.proto.ObjectType` values.
        center_xyz_m: (K, T, 3) box centres.
        size_lwh_m: (K, T, 3) box length, width, height.
        heading_rad: (K, T) box headings, counter-clockwise from +x.
        velocity_xy_mps: (K, T, 2) velocities.
        valid: (K, T) which states are valid.
        sdc_index: index of the self-driving car's track.
        current_time_index: the scenario's "now" step (history before, future after).
    """

    scenario_id: str
    timestamps_ns: NDArray[np.int64]
    track_ids: NDArray[np.int64]
    object_types: NDArray[np.int64]
    center_xyz_m: FloatArray
    size_lwh_m: FloatArray
    heading_rad: FloatArray
    velocity_xy_mps: FloatArray
    valid: NDArray[np.bool_]
    sdc_index: int
    current_time_index: int


_STATE_FIELDS = ("center_x", "center_y", "center_z", "length", "width", "height", "heading",
                 "velocity_x", "velocity_y", "valid")


def scenario_tracks(scenario: Any, path: Path, record: int) -> ScenarioTracks:
    """The tracks of a parsed ``Scenario``, checked.

    Raises:
        WomdFormatError: naming ``path``, ``record`` and the field: no scenario id (or one that
            cannot name a folder), no or non-increasing timestamps, a track whose state count
            differs from the timestamp count, repeated track ids, an ``sdc_track_index`` that is
            unset or names no track.
    """
    sid = str(scenario.scenario_id)
    if not sid:
        raise WomdFormatError(path, "scenario has no id", record, "scenario_id")
    if not _SCENARIO_ID.fullmatch(sid):
        raise WomdFormatError(path, f"scenario id {sid!r} cannot name a log folder", record, "scenario_id")
    times_s = np.asarray(scenario.timestamps_seconds, dtype=np.float64)
    if times_s.shape[0] == 0:
        raise WomdFormatError(path, "scenario has no timestamps", record, "timestamps_seconds")
    if not np.isfinite(times_s).all():
        raise WomdFormatError(path, "timestamp is NaN or inf", record, "timestamps_seconds")
    timestamps_ns = np.round(times_s * 1e9).astype(np.int64)
    if (np.diff(timestamps_ns) <= 0).any():
        step = int(np.argmax(np.diff(timestamps_ns) <= 0)) + 1
        raise WomdFormatError(path, f"timestamps not increasing at step {step}", record, "timestamps_seconds")
    num_steps = timestamps_ns.shape[0]
    num_tracks = len(scenario.tracks)
    if not scenario.HasField("sdc_track_index"):
        raise WomdFormatError(path, "no self-driving car track (sdc_track_index is unset)", record, "sdc_track_index")
    sdc = int(scenario.sdc_track_index)
    if not 0 <= sdc < num_tracks:
        raise WomdFormatError(
            path, f"sdc_track_index {sdc} names no track (the scenario has {num_tracks})", record, "sdc_track_index"
        )
    states = np.zeros((num_tracks, num_steps, len(_STATE_FIELDS)), dtype=np.float64)
    track_ids = np.zeros(num_tracks, dtype=np.int64)
    object_types = np.zeros(num_tracks, dtype=np.int64)
    for k, track in enumerate(scenario.tracks):
        if len(track.states) != num_steps:
            raise WomdFormatError(
                path, f"track {track.id} has {len(track.states)} states for {num_steps} timestamps",
                record, f"tracks[{k}].states",
            )
        track_ids[k] = int(track.id)
        object_types[k] = int(track.object_type)
        # Protobuf messages are read field by field; one tuple per state is the cheapest way out.
        states[k] = [tuple(getattr(s, name) for name in _STATE_FIELDS) for s in track.states]
    ids, counts = np.unique(track_ids, return_counts=True)
    if (counts > 1).any():
        dup = int(ids[np.argmax(counts > 1)])
        k = int(np.flatnonzero(track_ids == dup)[1])
        raise WomdFormatError(path, f"track id {dup} is used by more than one track", record, f"tracks[{k}].id")
    return ScenarioTracks(
        scenario_id=sid,
        timestamps_ns=timestamps_ns,
        track_ids=track_ids,
        object_types=object_types,
        center_xyz_m=states[..., 0:3],
        size_lwh_m=states[..., 3:6],
        heading_rad=states[..., 6],
        velocity_xy_mps=states[..., 7:9],
        valid=states[..., 9] > 0.5,
        sdc_index=sdc,
        current_time_index=int(scenario.current_time_index),
    )


def _usable(tracks: ScenarioTracks) -> NDArray[np.bool_]:
    """(K, T) valid states with finite values and positive sizes."""
    finite = np.isfinite(tracks.center_xyz_m).all(axis=2) & np.isfinite(tracks.heading_rad)
    sized = np.isfinite(tracks.size_lwh_m).all(axis=2) & (tracks.size_lwh_m > 0).all(axis=2)
    return tracks.valid & finite & sized


@dataclass(frozen=True)
class ConvertedTracks:
    """The ego trajectory and the annotations of a scenario, and what was left out.

    Attributes:
        ego: ``city_SE3_ego`` at the steps where the self-driving car is valid.
        annotations: every other track's usable states at those steps, in the ego frame.
        type_counts: rows per WOMD object type name.
        unknown_types: rows of object types with no category (mapped to ``other``), by type number.
        dropped_unusable: valid states with a non-finite value or a non-positive size, left out.
        dropped_without_ego: usable states at steps where the self-driving car is not valid, left out.
    """

    ego: EgoTrajectory
    annotations: Annotations
    type_counts: dict[str, int]
    unknown_types: dict[str, int]
    dropped_unusable: int
    dropped_without_ego: int


def convert_tracks(tracks: ScenarioTracks, path: Path, record: int) -> ConvertedTracks:
    """Ego poses from the self-driving car's track, annotations from all others.

    The ego origin is the rear axle on the ground: :data:`EGO_BOX_CENTER_AHEAD_M` behind the
    centre of the ego's box, half its height below. Boxes are upright (WOMD gives heading only).

    Raises:
        WomdFormatError: the self-driving car has no usable state.
    """
    usable = _usable(tracks)
    sdc = tracks.sdc_index
    ego_steps = usable[sdc]
    if not ego_steps.any():
        raise WomdFormatError(
            path, f"the self-driving car (track {tracks.track_ids[sdc]}) has no valid state", record,
            f"tracks[{sdc}].states",
        )
    ego_yaw = tracks.heading_rad[sdc, ego_steps]  # (E,)
    ego_dir = np.stack([np.cos(ego_yaw), np.sin(ego_yaw)], axis=1)  # (E, 2)
    ego_xyz = tracks.center_xyz_m[sdc, ego_steps].copy()  # (E, 3)
    ego_xyz[:, :2] -= EGO_BOX_CENTER_AHEAD_M * ego_dir
    ego_xyz[:, 2] -= 0.5 * tracks.size_lwh_m[sdc, ego_steps, 2]
    ego = EgoTrajectory(tracks.timestamps_ns[ego_steps], yaw_to_quat(ego_yaw), ego_xyz)

    others = np.ones(tracks.track_ids.shape[0], dtype=bool)
    others[sdc] = False
    valid_others = tracks.valid[others]
    usable_others = usable[others]
    keep = usable_others & ego_steps[None, :]  # (K-1, T)
    dropped_unusable = int(valid_others.sum() - usable_others.sum())
    dropped_without_ego = int(usable_others.sum() - keep.sum())

    k_idx, t_idx = np.nonzero(keep)  # rows in (track, step) order
    track_rows = np.flatnonzero(others)[k_idx]
    ego_at = np.cumsum(ego_steps) - 1  # step → index into the ego arrays
    e = ego_at[t_idx]
    cos, sin = ego_dir[e, 0], ego_dir[e, 1]
    delta = tracks.center_xyz_m[track_rows, t_idx] - ego_xyz[e]  # (N, 3)
    center_ego = np.stack([cos * delta[:, 0] + sin * delta[:, 1], -sin * delta[:, 0] + cos * delta[:, 1],
                           delta[:, 2]], axis=1)
    yaw_ego = wrap_angle_rad(tracks.heading_rad[track_rows, t_idx] - ego_yaw[e])

    types = tracks.object_types[track_rows]
    names = {int(t): (ObjectType(int(t)).name if int(t) in ObjectType._value2member_map_ else str(int(t)))
             for t in np.unique(types)}
    labels = {t: CATEGORY_TO_AV2[WOMD_TO_CATEGORY.get(t, Category.OTHER)] for t in names}
    values, counts = np.unique(types, return_counts=True)
    type_counts = {names[int(t)]: int(c) for t, c in zip(values, counts)}
    unknown = {names[int(t)]: int(c) for t, c in zip(values, counts) if int(t) not in WOMD_TO_CATEGORY}
    annotations = Annotations.from_yaw(
        timestamp_ns=tracks.timestamps_ns[t_idx],
        track_id=np.array([str(i) for i in tracks.track_ids[track_rows]], dtype=np.str_),
        category=np.array([labels[int(t)] for t in types], dtype=np.str_),
        center_xyz_m=center_ego,
        size_lwh_m=tracks.size_lwh_m[track_rows, t_idx],
        yaw_rad=yaw_ego,
    )
    return ConvertedTracks(ego, annotations, type_counts, unknown, dropped_unusable, dropped_without_ego)


@dataclass(frozen=True)
class WomdImportReport:
    """What the import of one scenario wrote and left out."""

    log_dir: Path
    scenario_id: str
    source: Path
    record: int
    steps: int
    ego_poses: int
    tracks: int
    rows: int
    lanes: int
    crossings: int
    drivable_areas: int
    type_counts: dict[str, int] = field(default_factory=dict)
    unknown_types: dict[str, int] = field(default_factory=dict)
    dropped_unusable: int = 0
    dropped_without_ego: int = 0

    def summary(self) -> str:
        types = ", ".join(f"{k}={v}" for k, v in sorted(self.type_counts.items())) or "none"
        text = (
            f"{self.log_dir}: scenario {self.scenario_id} ({self.source}, record {self.record}): "
            f"{self.steps} steps, {self.ego_poses} ego poses, {self.tracks} tracks, {self.rows} boxes ({types}); "
            f"map: {self.lanes} lanes, {self.crossings} crossings, {self.drivable_areas} drivable areas"
        )
        left_out = []
        if self.dropped_unusable:
            left_out.append(f"{self.dropped_unusable} valid states with non-finite values or non-positive sizes")
        if self.dropped_without_ego:
            left_out.append(f"{self.dropped_without_ego} states at steps without a valid ego state")
        if self.unknown_types:
            left_out.append("unknown types mapped to 'other': "
                            + ", ".join(f"{k}={v}" for k, v in sorted(self.unknown_types.items())))
        return text + ("; " + "; ".join(left_out) if left_out else "")


@dataclass(frozen=True)
class SkippedScenario:
    """A scenario (or a whole file) that was not imported, and why.

    Attributes:
        path: the input file.
        record: the 0-based record, or None when the whole file (or its rest) could not be read.
        reason: what went wrong, naming the file, the record and the field.
    """

    path: Path
    record: int | None
    reason: str

    def __str__(self) -> str:
        where = str(self.path) if self.record is None else f"{self.path}, record {self.record}"
        return f"skipped {where}: {self.reason}"


@dataclass(frozen=True)
class WomdImportBatch:
    """The outcome of importing several files: one report per log written, one entry per skip."""

    imported: list[WomdImportReport]
    skipped: list[SkippedScenario]


def log_id_for(scenario_id: str) -> str:
    """The log folder of a scenario: ``womd_<scenario_id>``."""
    return f"{LOG_PREFIX}{scenario_id}"


def write_womd_log(
    out_dir: Path | str,
    converted: ConvertedTracks,
    vector_map: VectorMap,
    metadata: LogMetadata,
    overwrite: bool = False,
) -> Path:
    """Write ``<out_dir>/<metadata.log_id>/`` atomically; it is opened and its map read back (and so
    validated) before it replaces anything at the target. Returns the log folder.

    Raises:
        FileExistsError: the log folder exists and ``overwrite`` is false.
        LogFormatError: the converted log breaks the log contract (nothing is written).
    """
    target = Path(out_dir) / metadata.log_id
    with claimed_directory(target, av2_io.LOG_FOLDER, overwrite=overwrite) as tmp:
        av2_io.write_annotations(tmp, converted.annotations)
        av2_io.write_ego_poses(tmp, converted.ego)
        map_path = av2_io.write_map(tmp, vector_map, metadata.log_id, CITY_NAME)
        av2_io.write_metadata(tmp, metadata)
        Log.open(tmp)
        av2_io.read_map(map_path)
    return target


def import_womd_scenario(
    data: bytes, out_dir: Path | str, source: Path | str, record: int = 0, overwrite: bool = False
) -> WomdImportReport:
    """Convert one serialised ``Scenario`` into ``<out_dir>/womd_<scenario_id>/`` (written atomically).

    Args:
        data: the record's payload.
        out_dir: folder that receives the log.
        source: the file the record came from (for messages and the log's metadata).
        record: the record's 0-based index in ``source``.
        overwrite: replace an existing log of the same name.

    Raises:
        WomdFormatError: the record is not a ``Scenario`` or breaks one of the checks of
            :func:`scenario_tracks` and :func:`convert_tracks`.
        FileExistsError: the log folder exists and ``overwrite`` is false.
        LogFormatError: the converted log breaks the log contract.
    """
    source = Path(source)
    try:
        scenario = parse_scenario(data)
    except DecodeError as exc:
        raise WomdFormatError(source, f"not a Scenario protobuf message: {exc}", record) from exc
    tracks = scenario_tracks(scenario, source, record)
    converted = convert_tracks(tracks, source, record)
    womd_map: WomdMap = womd_map_from_features(scenario.map_features)
    vector_map = vector_map_from_womd(womd_map)
    log_id = log_id_for(tracks.scenario_id)
    sdc_id = int(tracks.track_ids[tracks.sdc_index])
    metadata = LogMetadata(
        log_id=log_id,
        source="womd",
        city_name=CITY_NAME,
        extra={
            "scenario_id": tracks.scenario_id,
            "source_file": str(source),
            "record": record,
            "steps": int(tracks.timestamps_ns.shape[0]),
            "current_time_index": tracks.current_time_index,
            "current_timestamp_ns": int(tracks.timestamps_ns[min(max(tracks.current_time_index, 0),
                                                                 tracks.timestamps_ns.shape[0] - 1)]),
            "sdc_track_id": sdc_id,
            "ego_box_center_ahead_m": EGO_BOX_CENTER_AHEAD_M,
            "object_type_counts": converted.type_counts,
            "unknown_types": converted.unknown_types,
            "dropped_unusable_states": converted.dropped_unusable,
            "dropped_states_without_ego": converted.dropped_without_ego,
            "map_features_not_converted": womd_map.other_counts,
        },
    )
    target = write_womd_log(out_dir, converted, vector_map, metadata, overwrite)
    return WomdImportReport(
        log_dir=target,
        scenario_id=tracks.scenario_id,
        source=source,
        record=record,
        steps=int(tracks.timestamps_ns.shape[0]),
        ego_poses=len(converted.ego),
        tracks=len(converted.annotations.track_ids),
        rows=len(converted.annotations),
        lanes=len(vector_map.lane_segments),
        crossings=len(vector_map.pedestrian_crossings),
        drivable_areas=len(vector_map.drivable_areas),
        type_counts=converted.type_counts,
        unknown_types=converted.unknown_types,
        dropped_unusable=converted.dropped_unusable,
        dropped_without_ego=converted.dropped_without_ego,
    )


def _reason(exc: BaseException) -> str:
    """The message of an error, without the file and record that the skip entry names already."""
    if isinstance(exc, WomdFormatError):
        return exc.reason if exc.field is None else f"field '{exc.field}': {exc.reason}"
    if isinstance(exc, FileExistsError):
        return f"{exc} (use --overwrite to replace it)"
    return str(exc)


def import_womd_files(
    paths: Sequence[Path | str] | Iterable[Path | str], out_dir: Path | str, overwrite: bool = False
) -> WomdImportBatch:
    """Import every scenario of every TFRecord file, one log each, into ``out_dir``.

    Nothing stops the batch: a file that is missing, a record that fails its CRC or does not hold a
    valid scenario, and a scenario whose log exists are each listed in ``skipped`` with the reason,
    and the rest is imported. A file that ends inside a record, or whose record length fails its
    CRC, cannot be framed past that point: its earlier scenarios are imported, the rest is one skip.
    Each log is written atomically, so no half log is ever left behind.
    """
    imported: list[WomdImportReport] = []
    skipped: list[SkippedScenario] = []
    for raw in paths:
        path = Path(raw)
        records = 0
        try:
            for item in iter_records(path):
                records += 1
                if isinstance(item, WomdFormatError):
                    skipped.append(SkippedScenario(path, item.record, _reason(item)))
                    continue
                try:
                    imported.append(import_womd_scenario(item.data, out_dir, path, item.index, overwrite))
                except (ScenesError, FileExistsError, ValueError) as exc:
                    skipped.append(SkippedScenario(path, item.index, _reason(exc)))
        except WomdFormatError as exc:
            skipped.append(SkippedScenario(path, exc.record, _reason(exc) + "; the rest of the file is not read"))
        except OSError as exc:
            skipped.append(SkippedScenario(path, None, f"unreadable: {exc}"))
        else:
            if records == 0:
                skipped.append(SkippedScenario(path, None, "the file holds no records"))
    return WomdImportBatch(imported, skipped)
