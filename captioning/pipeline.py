"""Caption a log end to end: per-frame tags, unified sequences, windows and caption text.

>>> from captioning import caption_log, CaptioningConfig
>>> result = caption_log(Log.open("logs/7fab2350-..."), CaptioningConfig())
>>> [c.caption for c in result.captions if c.track_id == "ego"][1]
'The ego vehicle is decelerating straight.'

Output files (``write_outputs``), both Parquet:

``frame_tags.parquet``: one row per (log, timestamp, track), the ego included as track ``ego``:
``log_id, timestamp_ns, track_id, category, x_m, y_m`` (ego frame; null for the ego),
``host_motion, host_direction`` (ego rows), ``stationary`` (object rows; null for tracks of
single frames), ``baseline_lane, lane, motion`` (tagged object rows, else null). Under
``rules: behavior`` (the default) object rows also carry the object's own behaviour
(:mod:`captioning.behavior`): ``parked, stopped, braking, keeping_lane, left_turn, right_turn,
left_lane_change, right_lane_change, blocked_by, braking_for`` (bool) and ``speed_mps``, and its map
context (:mod:`captioning.map_context`): ``at_intersection, on_crosswalk`` (bool) and
``junction_kind`` (``three_way``, ``four_way``, ``multi_way`` or null); null where a tag could not be
computed (frames of too short runs; lane tags and context on a log without a map); and ``action``,
``context``: the own action and the context that the frame's unified tag carries (``left:approach:braking``:
``braking``, ``none``), flicker suppressed as in the captions, null on untagged frames.

``captions.parquet``: one row per caption: ``log_id, track_id, category, start_ns, end_ns,
num_frames, tags`` (the unified sequence), ``host_tags`` (the host's over the same window),
``caption`` (= ``canonical_caption``), ``canonical_caption, paraphrases, window``. Host captions
have track id ``ego``, one per host segment; neighbour captions one per (track, window) where the
track is tagged in at least ``segments.min_s`` worth of frames of the window (moving tracks only under
``rules: paper``); the interval is the track's first and last tagged frame inside the window, and
(log, track, start) is unique (of sliding windows that clip a track to the same start, the longest
is kept). Under ``rules: behavior`` the neighbour tags carry the own action and context
(``left:approach:braking``) and each row has one column per behaviour label and
``at_intersection, on_crosswalk`` (true when it holds in some tagged frame of the window, null when
never known) and ``junction_kind`` (the most frequent in the window), for filters such as
``braking == true``. Under ``rules: paper`` both files are exactly those of the paper's rules.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from captioning.assemble import host_captions, neighbor_captions, unique_starts
from captioning.behavior import NO_MAP_NOTE, BehaviorTags, behavior_tags, skip_short_reason
from captioning.config import CaptioningConfig, RuleSet
from captioning.errors import TrackDataError
from captioning.frames import FrameCounts
from captioning.host import host_kinematics, host_tags_of
from captioning.map_context import rasterize_map
from captioning.neighbors import NeighborTags, neighbor_tags, track_motion
from captioning.smoothing import BoolArray, FloatArray, IntArray, suppress_flicker
from captioning.tables import (
    EGO_CATEGORY,
    EGO_TRACK_ID,
    FRAME_TAGS_BEHAVIOR_SCHEMA,
    FRAME_TAGS_SCHEMA,
    Caption,
    behavior_frame_columns,
    captions_to_table,
    strings_column,
    unified_action_columns,
)
from captioning.tags import (
    ACTIONS,
    BASELINE_LANES,
    CONTEXTS,
    HOST_DIRECTIONS,
    HOST_MOTIONS,
    LANES,
    MOTIONS,
    NO_TAG,
    unified_neighbor_tag,
)
from captioning.unify import Segment, caption_windows
from scenes.log import Log
from scenes.map import VectorMap
from scenes.tracks import DenseTracks

FRAME_TAGS_FILENAME = "frame_tags.parquet"
#: Why a track gets no tags: no two observations close enough to differentiate.
SKIP_ISOLATED = "observed only in single frames too far apart to differentiate"
CAPTIONS_FILENAME = "captions.parquet"
#: log id → the log's folder, for the stages that read the logs again (scenario queries).
LOGS_FILENAME = "logs.json"

_NEIGHBOR_STRINGS = [f"{lane.value}:{m.value}" for lane in LANES for m in MOTIONS]
#: Unified tags with action and context: code ((lane·M + motion)·(A + 1) + action + 1)·(C + 1) + context + 1.
_BEHAVIOR_STRINGS = [
    unified_neighbor_tag(lane, m, action, context)
    for lane in LANES for m in MOTIONS for action in [None, *ACTIONS] for context in [None, *CONTEXTS]
]


@dataclass(frozen=True)
class LogCaptions:
    """Everything the rules say about one log.

    Attributes:
        log_id: the log.
        timestamps_ns: (T,) frame grid.
        track_ids: (K,) track ids.
        categories: (K,) public categories.
        valid: (K, T) observed mask.
        center_ego_xy_m: (K, T, 2) centres in the ego frame.
        host_motion: (T,) host motion codes (:data:`~captioning.tags.HOST_MOTIONS`, −1 = none).
        host_direction: (T,) host direction codes.
        neighbors: per-frame neighbour tags.
        host_segments: host segments (frame index ranges).
        captions: host captions first, then neighbour captions by window and track.
        skipped_tracks: track id → why it got no tags (or no own-behaviour tags).
        behavior: own behaviour and map context (None under ``rules: paper``).
        notes: statements about the whole log (e.g. that it has no map with lanes).
        action_code: (K, T) :data:`~captioning.tags.ACTIONS` code in the tags, −1 none (None under ``paper``).
        context_code: (K, T) :data:`~captioning.tags.CONTEXTS` code in the tags, −1 none.
    """

    log_id: str
    timestamps_ns: IntArray
    track_ids: NDArray[np.str_]
    categories: NDArray[np.str_]
    valid: BoolArray
    center_ego_xy_m: FloatArray
    host_motion: IntArray
    host_direction: IntArray
    neighbors: NeighborTags
    host_segments: list[Segment]
    captions: list[Caption]
    skipped_tracks: dict[str, str] = field(default_factory=dict)
    behavior: BehaviorTags | None = None
    notes: list[str] = field(default_factory=list)
    action_code: IntArray | None = None
    context_code: IntArray | None = None

    @property
    def host_code(self) -> IntArray:
        """(T,) unified host codes (index into ``motion:direction`` strings), −1 = none."""
        ok = (self.host_motion != NO_TAG) & (self.host_direction != NO_TAG)
        return np.where(ok, self.host_motion * len(HOST_DIRECTIONS) + self.host_direction, NO_TAG)

    @property
    def neighbor_code(self) -> IntArray:
        """(K, T) unified neighbour codes (index into ``lane:motion`` strings), −1 = none."""
        nb = self.neighbors
        return np.where(nb.tagged, nb.lane.astype(np.int64) * len(MOTIONS) + nb.motion, NO_TAG)

    def tag_codes(self) -> tuple[IntArray, list[str]]:
        """(K, T) codes of the unified neighbour tags and their strings: ``lane:motion`` under
        ``rules: paper``, with the own action and context otherwise."""
        codes = self.neighbor_code
        if self.action_code is None or self.context_code is None:
            return codes, _NEIGHBOR_STRINGS
        a, c = len(ACTIONS) + 1, len(CONTEXTS) + 1
        return (np.where(codes >= 0, (codes * a + self.action_code + 1) * c + self.context_code + 1, NO_TAG),
                _BEHAVIOR_STRINGS)

    def frame_tags_table(self) -> pa.Table:
        """``frame_tags.parquet`` rows of this log (ego rows first at each timestamp)."""
        t = self.timestamps_ns.shape[0]
        rows, cols = np.nonzero(self.valid.T)  # (frame, track) order: by timestamp, then track
        frame_idx, track_idx = rows, cols
        n_obj = frame_idx.shape[0]
        ego_frame = np.arange(t)
        all_frame = np.r_[ego_frame, frame_idx]
        order = np.argsort(all_frame, kind="stable")  # ego row first at each timestamp
        is_ego = np.r_[np.ones(t, bool), np.zeros(n_obj, bool)][order]
        nb = self.neighbors
        track_col = np.r_[np.full(t, EGO_TRACK_ID, dtype=object), self.track_ids[track_idx].astype(object)][order]
        cat_col = np.r_[np.full(t, EGO_CATEGORY, dtype=object), self.categories[track_idx].astype(object)][order]
        xy = self.center_ego_xy_m[track_idx, frame_idx]
        x = np.r_[np.zeros(t), xy[:, 0]][order]
        y = np.r_[np.zeros(t), xy[:, 1]][order]
        host_m = np.r_[self.host_motion, np.full(n_obj, NO_TAG)][order]
        host_d = np.r_[self.host_direction, np.full(n_obj, NO_TAG)][order]
        stationary = np.r_[np.zeros(t, bool), nb.stationary[track_idx]][order]
        stationary_null = np.r_[np.ones(t, bool), ~nb.taggable[track_idx]][order]
        lane = np.r_[np.full(t, NO_TAG), nb.lane[track_idx, frame_idx]][order]
        base = np.r_[np.full(t, NO_TAG), nb.baseline_lane[track_idx, frame_idx]][order]
        motion = np.r_[np.full(t, NO_TAG), nb.motion[track_idx, frame_idx]][order]
        n = t + n_obj
        columns = {
            "log_id": pa.array([self.log_id] * n, pa.string()),
            "timestamp_ns": pa.array(self.timestamps_ns[all_frame[order]], pa.int64()),
            "track_id": pa.array(track_col, pa.string()),
            "category": pa.array(cat_col, pa.string()),
            "x_m": pa.array(x, pa.float64(), mask=is_ego),
            "y_m": pa.array(y, pa.float64(), mask=is_ego),
            "host_motion": strings_column(host_m, [m.value for m in HOST_MOTIONS]),
            "host_direction": strings_column(host_d, [d.value for d in HOST_DIRECTIONS]),
            "stationary": pa.array(stationary, pa.bool_(), mask=stationary_null),
            "baseline_lane": strings_column(base, [b.value for b in BASELINE_LANES]),
            "lane": strings_column(lane, [lane_.value for lane_ in LANES]),
            "motion": strings_column(motion, [m.value for m in MOTIONS]),
        }
        beh = self.behavior
        if beh is None:
            return pa.table(columns, schema=FRAME_TAGS_SCHEMA)
        columns.update(behavior_frame_columns(beh, t, track_idx, frame_idx, order))
        assert self.action_code is not None and self.context_code is not None  # set with ``behavior``
        columns.update(unified_action_columns(self.action_code[track_idx, frame_idx],
                                              self.context_code[track_idx, frame_idx],
                                              nb.tagged[track_idx, frame_idx], t, order))
        return pa.table(columns, schema=FRAME_TAGS_BEHAVIOR_SCHEMA)

    def captions_table(self) -> pa.Table:
        """``captions.parquet`` rows of this log."""
        return captions_to_table(self.captions, self.behavior is not None)


def action_context_codes(behavior: BehaviorTags, tagged: BoolArray, min_run_frames: int) -> tuple[IntArray, IntArray]:
    """(K, T) :data:`~captioning.tags.ACTIONS` and (K, T) :data:`~captioning.tags.CONTEXTS` codes of the
    tagged frames (−1 none), flicker suppressed on the pair (what the unified tag says)."""
    width = len(CONTEXTS) + 1
    pair = (behavior.action.astype(np.int64) + 1) * width + behavior.context + 1
    pair = suppress_flicker(np.where(tagged, pair, NO_TAG), min_run_frames)
    return np.where(tagged, pair // width - 1, NO_TAG), np.where(tagged, pair % width - 1, NO_TAG)


def check_finite(
    log_id: str,
    timestamps_ns: IntArray,
    track_ids: NDArray[np.str_],
    valid: BoolArray,
    center_ego_xy_m: FloatArray,
    yaw_ego_rad: FloatArray,
    city_SE3_ego: FloatArray,
) -> None:
    """Raise :class:`TrackDataError` at the first NaN/inf pose, naming log, track, frame and field."""
    bad_pose = ~np.isfinite(city_SE3_ego.reshape(-1, 16)).all(axis=1)
    if bad_pose.any():
        f = int(np.argmax(bad_pose))
        raise TrackDataError(log_id, EGO_TRACK_ID, f, int(timestamps_ns[f]), "city_SE3_ego", "ego pose is not finite")
    for name, values in (("center_ego_xy_m", center_ego_xy_m), ("yaw_ego_rad", yaw_ego_rad)):
        finite = np.isfinite(values) if values.ndim == 2 else np.isfinite(values).all(axis=2)
        bad = valid & ~finite
        if bad.any():
            k, f = (int(i) for i in np.argwhere(bad)[0])
            raise TrackDataError(log_id, str(track_ids[k]), f, int(timestamps_ns[f]), name, "value is not finite")


def caption_arrays(
    log_id: str,
    timestamps_ns: IntArray,
    track_ids: NDArray[np.str_],
    categories: NDArray[np.str_],
    valid: BoolArray,
    center_ego_xy_m: FloatArray,
    yaw_ego_rad: FloatArray,
    city_SE3_ego: FloatArray,
    config: CaptioningConfig,
    vector_map: VectorMap | None = None,
    length_m: FloatArray | None = None,
) -> LogCaptions:
    """Caption in-memory tracks.

    Args:
        log_id: names the log in errors and outputs.
        timestamps_ns: (T,) strictly increasing frame timestamps.
        track_ids: (K,) track ids.
        categories: (K,) public category values.
        valid: (K, T) observed mask.
        center_ego_xy_m: (K, T, 2) centres in the ego frame.
        yaw_ego_rad: (K, T) headings in the ego frame.
        city_SE3_ego: (T, 4, 4) ego poses.
        vector_map: the log's map (``rules: behavior``: lanes and context; None: the lane tags are null).
        length_m: (K, T) box lengths (``rules: behavior``: the box front decides where a vehicle
            is, and gaps are bumper to bumper; None: the centre, and gaps between centres).

    Raises:
        TrackDataError: a NaN or infinite value where a track is observed, or in an ego pose.
    """
    timestamps_ns = np.asarray(timestamps_ns, dtype=np.int64)
    valid = np.asarray(valid, dtype=bool)
    center_ego_xy_m = np.asarray(center_ego_xy_m, dtype=np.float64)
    yaw_ego_rad = np.asarray(yaw_ego_rad, dtype=np.float64)
    city_SE3_ego = np.asarray(city_SE3_ego, dtype=np.float64)
    track_ids = np.asarray(track_ids, dtype=np.str_)
    categories = np.asarray(categories, dtype=np.str_)
    if timestamps_ns.size > 1 and not (np.diff(timestamps_ns) > 0).all():
        f = int(np.argmax(np.diff(timestamps_ns) <= 0)) + 1
        raise TrackDataError(log_id, EGO_TRACK_ID, f, int(timestamps_ns[f]), "timestamp_ns", "timestamps must increase")
    check_finite(log_id, timestamps_ns, track_ids, valid, center_ego_xy_m, yaw_ego_rad, city_SE3_ego)
    partial = tag_arrays(log_id, timestamps_ns, track_ids, categories, valid, center_ego_xy_m, yaw_ego_rad,
                         city_SE3_ego, config, vector_map, length_m)
    host_code = partial.host_code
    segments, windows = caption_windows(timestamps_ns, host_code, config)
    captions = host_captions(partial, segments, host_code, config)
    captions += unique_starts(neighbor_captions(partial, windows, host_code, config))
    return dataclasses.replace(partial, host_segments=segments, captions=captions)


def tag_arrays(
    log_id: str,
    timestamps_ns: IntArray,
    track_ids: NDArray[np.str_],
    categories: NDArray[np.str_],
    valid: BoolArray,
    center_ego_xy_m: FloatArray,
    yaw_ego_rad: FloatArray,
    city_SE3_ego: FloatArray,
    config: CaptioningConfig,
    vector_map: VectorMap | None = None,
    length_m: FloatArray | None = None,
) -> LogCaptions:
    """The per-frame tags of :func:`caption_arrays` (host, neighbour, own behaviour), without windows
    and captions; the arguments are checked and converted already."""
    kin = host_kinematics(timestamps_ns, city_SE3_ego, config)
    host_motion, host_direction = host_tags_of(kin, config)
    rich = config.rules == RuleSet.BEHAVIOR
    k, t = valid.shape
    # The own behaviour starts from the same bridged, differentiated tracks as the neighbour tags.
    motion = track_motion(timestamps_ns, valid, center_ego_xy_m, yaw_ego_rad, city_SE3_ego, config) if k and t else None
    nb = neighbor_tags(motion, (k, t), config, stationary_objects=rich)
    skipped = {str(tid): SKIP_ISOLATED for tid in track_ids[~nb.taggable]}
    behavior: BehaviorTags | None = None
    notes: list[str] = []
    action = context = None
    if rich:
        raster = None
        if vector_map is not None and k and t:
            raster = rasterize_map(vector_map, _city_xy(center_ego_xy_m, valid, city_SE3_ego), config.map)
        if raster is None:
            notes.append(NO_MAP_NOTE)
        if length_m is not None:
            length_m = np.asarray(length_m, dtype=np.float64)
        if motion is None:
            behavior = BehaviorTags.empty(k, t, raster is not None)
        else:
            behavior = behavior_tags(timestamps_ns, motion, length_m, categories, city_SE3_ego, raster, config,
                                     kin.speed_mps, kin.accel_mps2)
        frames = FrameCounts.of(config, kin.interval_s)
        short = skip_short_reason(config, frames)
        skipped.update({str(tid): short for tid in track_ids[nb.taggable & ~behavior.taggable]})
        action, context = action_context_codes(behavior, nb.tagged, frames.min_run)
    return LogCaptions(
        log_id, timestamps_ns, track_ids, categories, valid, center_ego_xy_m,
        host_motion, host_direction, nb, [], [], skipped, behavior, notes, action, context,
    )


def _city_xy(center_ego_xy_m: FloatArray, valid: BoolArray, city_SE3_ego: FloatArray) -> FloatArray:
    """(N, 2) the observed centres in the city frame (``city_SE3_ego · ego_SE3_object``, planar)."""
    rows, cols = np.nonzero(valid)
    p = center_ego_xy_m[rows, cols]
    pose = city_SE3_ego[cols]
    return np.stack([pose[:, 0, 0] * p[:, 0] + pose[:, 0, 1] * p[:, 1] + pose[:, 0, 3],
                     pose[:, 1, 0] * p[:, 0] + pose[:, 1, 1] * p[:, 1] + pose[:, 1, 3]], axis=1)


def caption_dense(
    log_id: str, dense: DenseTracks, config: CaptioningConfig, vector_map: VectorMap | None = None
) -> LogCaptions:
    """Caption :class:`~scenes.tracks.DenseTracks` (with the log's map, when it has one)."""
    return caption_arrays(
        log_id, dense.timestamps_ns, dense.track_ids, dense.categories, dense.valid,
        dense.center_ego_xyz_m[..., :2], dense.yaw_ego_rad, dense.city_SE3_ego, config,
        vector_map=vector_map, length_m=dense.size_lwh_m[..., 0],
    )


def caption_log(log: Log, config: CaptioningConfig | None = None) -> LogCaptions:
    """Caption one opened log (its annotation frame grid; ego poses interpolated onto it).

    Under ``rules: behavior`` the log's map is read (a log without one gets null lane tags).
    """
    config = config or CaptioningConfig()
    vector_map = log.map if config.rules == RuleSet.BEHAVIOR else None
    result = caption_dense(log.log_id, log.dense_tracks(), config, vector_map)
    if log.unknown_categories:  # said here as `validate` says it: their objects are captioned as "object"
        listed = ", ".join(f"{k}={v}" for k, v in sorted(log.unknown_categories.items()))
        result.notes.append(f"unknown categories captioned as 'other': {listed}")
    return result
