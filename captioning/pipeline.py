"""Caption a log end to end: per-frame tags, unified sequences, windows and caption text.

>>> from captioning import caption_log, CaptioningConfig
>>> result = caption_log(Log.open("logs/7fab2350-..."), CaptioningConfig())
>>> [c.caption for c in result.captions if c.track_id == "ego"][1]
'The ego vehicle is decelerating straight.'

Output files (``write_outputs``), both Parquet:

``frame_tags.parquet``: one row per (log, timestamp, track), the ego included as track ``ego``:
``log_id, timestamp_ns, track_id, category, x_m, y_m`` (ego frame; null for the ego),
``host_motion, host_direction`` (ego rows), ``stationary`` (object rows; null for tracks of
single frames), ``baseline_lane, lane, motion`` (tagged object rows, else null).

``captions.parquet``: one row per caption: ``log_id, track_id, category, start_ns, end_ns,
num_frames, tags`` (the unified sequence), ``host_tags`` (the host's over the same window),
``caption`` (= ``canonical_caption``), ``canonical_caption, paraphrases, window``. Host captions
have track id ``ego``, one per host segment; neighbour captions one per (moving track, window)
where the track is tagged in at least ``segments.min_frames`` frames of the window; the
interval is the track's first and last tagged frame inside the window, and (log, track, start)
is unique (of sliding windows that clip a track to the same start, the longest is kept).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.errors import TrackDataError
from captioning.host import host_tags
from captioning.neighbors import NeighborTags, neighbor_tags
from captioning.smoothing import BoolArray, FloatArray, IntArray
from captioning.tags import BASELINE_LANES, HOST_DIRECTIONS, HOST_MOTIONS, LANES, MOTIONS, NO_TAG
from captioning.text import caption_text, paraphrases
from captioning.unify import Segment, caption_windows, collapse_codes
from common.atomic import atomic_path
from scenes.errors import ScenesError
from scenes.log import Log
from scenes.tracks import DenseTracks

EGO_TRACK_ID = "ego"
#: Category value of the ego's rows in both files (the ego is not an object category).
EGO_CATEGORY = "ego"
FRAME_TAGS_FILENAME = "frame_tags.parquet"
#: Why a track gets no tags: no two observations close enough to differentiate.
SKIP_ISOLATED = "observed only in single frames too far apart to differentiate"
CAPTIONS_FILENAME = "captions.parquet"

FRAME_TAGS_SCHEMA = pa.schema(
    [
        pa.field("log_id", pa.string(), nullable=False),
        pa.field("timestamp_ns", pa.int64(), nullable=False),
        pa.field("track_id", pa.string(), nullable=False),
        pa.field("category", pa.string(), nullable=False),
        pa.field("x_m", pa.float64()),
        pa.field("y_m", pa.float64()),
        pa.field("host_motion", pa.string()),
        pa.field("host_direction", pa.string()),
        pa.field("stationary", pa.bool_()),
        pa.field("baseline_lane", pa.string()),
        pa.field("lane", pa.string()),
        pa.field("motion", pa.string()),
    ]
)
CAPTIONS_SCHEMA = pa.schema(
    [
        pa.field("log_id", pa.string(), nullable=False),
        pa.field("track_id", pa.string(), nullable=False),
        pa.field("category", pa.string(), nullable=False),
        pa.field("start_ns", pa.int64(), nullable=False),
        pa.field("end_ns", pa.int64(), nullable=False),
        pa.field("num_frames", pa.int64(), nullable=False),
        pa.field("tags", pa.list_(pa.string()), nullable=False),
        pa.field("host_tags", pa.list_(pa.string()), nullable=False),
        pa.field("caption", pa.string(), nullable=False),
        pa.field("canonical_caption", pa.string(), nullable=False),
        pa.field("paraphrases", pa.list_(pa.string()), nullable=False),
        pa.field("window", pa.string(), nullable=False),
    ]
)


_HOST_STRINGS = [f"{m.value}:{d.value}" for m in HOST_MOTIONS for d in HOST_DIRECTIONS]
_NEIGHBOR_STRINGS = [f"{lane.value}:{m.value}" for lane in LANES for m in MOTIONS]


@dataclass(frozen=True)
class Caption:
    """One caption row (see the module docstring)."""

    log_id: str
    track_id: str
    category: str
    start_ns: int
    end_ns: int
    num_frames: int
    tags: tuple[str, ...]
    host_tags: tuple[str, ...]
    canonical_caption: str
    paraphrases: tuple[str, ...]
    window: str

    @property
    def caption(self) -> str:
        return self.canonical_caption


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
        skipped_tracks: track id → why it got no tags.
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
        return pa.table(
            {
                "log_id": pa.array([self.log_id] * n, pa.string()),
                "timestamp_ns": pa.array(self.timestamps_ns[all_frame[order]], pa.int64()),
                "track_id": pa.array(track_col, pa.string()),
                "category": pa.array(cat_col, pa.string()),
                "x_m": pa.array(x, pa.float64(), mask=is_ego),
                "y_m": pa.array(y, pa.float64(), mask=is_ego),
                "host_motion": _strings(host_m, [m.value for m in HOST_MOTIONS]),
                "host_direction": _strings(host_d, [d.value for d in HOST_DIRECTIONS]),
                "stationary": pa.array(stationary, pa.bool_(), mask=stationary_null),
                "baseline_lane": _strings(base, [b.value for b in BASELINE_LANES]),
                "lane": _strings(lane, [lane_.value for lane_ in LANES]),
                "motion": _strings(motion, [m.value for m in MOTIONS]),
            },
            schema=FRAME_TAGS_SCHEMA,
        )

    def captions_table(self) -> pa.Table:
        """``captions.parquet`` rows of this log."""
        return captions_to_table(self.captions)


def captions_to_table(captions: Sequence[Caption]) -> pa.Table:
    return pa.table(
        {
            "log_id": pa.array([c.log_id for c in captions], pa.string()),
            "track_id": pa.array([c.track_id for c in captions], pa.string()),
            "category": pa.array([c.category for c in captions], pa.string()),
            "start_ns": pa.array([c.start_ns for c in captions], pa.int64()),
            "end_ns": pa.array([c.end_ns for c in captions], pa.int64()),
            "num_frames": pa.array([c.num_frames for c in captions], pa.int64()),
            "tags": pa.array([list(c.tags) for c in captions], pa.list_(pa.string())),
            "host_tags": pa.array([list(c.host_tags) for c in captions], pa.list_(pa.string())),
            "caption": pa.array([c.canonical_caption for c in captions], pa.string()),
            "canonical_caption": pa.array([c.canonical_caption for c in captions], pa.string()),
            "paraphrases": pa.array([list(c.paraphrases) for c in captions], pa.list_(pa.string())),
            "window": pa.array([c.window for c in captions], pa.string()),
        },
        schema=CAPTIONS_SCHEMA,
    )


def _strings(codes: IntArray, vocabulary: list[str]) -> pa.Array:
    lookup = np.array([*vocabulary, None], dtype=object)
    return pa.array(lookup[np.where(codes == NO_TAG, len(vocabulary), codes)], pa.string())


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

    host_motion, host_direction = host_tags(timestamps_ns, city_SE3_ego, config)
    nb = neighbor_tags(timestamps_ns, valid, center_ego_xy_m, yaw_ego_rad, city_SE3_ego, config)
    skipped = {str(tid): SKIP_ISOLATED for tid in track_ids[~nb.taggable]}
    partial = LogCaptions(
        log_id, timestamps_ns, track_ids, categories, valid, center_ego_xy_m,
        host_motion, host_direction, nb, [], [], skipped,
    )
    host_code = partial.host_code
    segments, windows = caption_windows(timestamps_ns, host_code, config)
    captions = _host_captions(partial, segments, host_code, config)
    captions += _unique_starts(_neighbor_captions(partial, windows, host_code, config))
    return LogCaptions(
        log_id, timestamps_ns, track_ids, categories, valid, center_ego_xy_m,
        host_motion, host_direction, nb, segments, captions, skipped,
    )


def _host_tags_in(host_code: IntArray, segment: Segment) -> tuple[str, ...]:
    codes = host_code[segment.start : segment.end + 1]
    return tuple(_HOST_STRINGS[c] for c in collapse_codes(codes[codes != NO_TAG]))


def _make_caption(
    result: LogCaptions, track_id: str, category: str, start: int, end: int, num_frames: int,
    tags: tuple[str, ...], host: tuple[str, ...], window: str, config: CaptioningConfig,
) -> Caption:
    start_ns, end_ns = int(result.timestamps_ns[start]), int(result.timestamps_ns[end])
    neighbor_category = None if track_id == EGO_TRACK_ID else category
    canonical = caption_text(neighbor_category, tags, host)
    variants = paraphrases(
        neighbor_category, tags, host, config.text.num_paraphrases, config.text.seed,
        (result.log_id, track_id, start_ns, end_ns), canonical,
    )
    return Caption(result.log_id, track_id, category, start_ns, end_ns, num_frames, tags, host, canonical,
                   tuple(variants), window)


def _host_captions(
    result: LogCaptions, segments: list[Segment], host_code: IntArray, config: CaptioningConfig
) -> list[Caption]:
    return [
        _make_caption(result, EGO_TRACK_ID, EGO_CATEGORY, s.start, s.end, s.num_frames, (_HOST_STRINGS[s.code],),
                      (_HOST_STRINGS[s.code],), "host_segments", config)
        for s in segments
    ]


def _neighbor_captions(
    result: LogCaptions, windows: list[Segment], host_code: IntArray, config: CaptioningConfig
) -> list[Caption]:
    codes = result.neighbor_code
    tagged = result.neighbors.tagged
    out: list[Caption] = []
    for window in windows:
        sub_tagged = tagged[:, window.start : window.end + 1]
        counts = sub_tagged.sum(axis=1)
        host = _host_tags_in(host_code, window)
        for k in np.flatnonzero(counts >= config.segments.min_frames).tolist():
            frames = np.flatnonzero(sub_tagged[k]) + window.start
            tags = tuple(_NEIGHBOR_STRINGS[c] for c in collapse_codes(codes[k, frames]))
            out.append(
                _make_caption(result, str(result.track_ids[k]), str(result.categories[k]), int(frames[0]),
                              int(frames[-1]), int(counts[k]), tags, host, config.windows.strategy.value, config)
            )
    return out


def _unique_starts(captions: list[Caption]) -> list[Caption]:
    """One caption per (track, start): overlapping sliding windows can clip a track to the same
    start; downstream clip ids are ``log:track:start_ns``, so keep the longest of such captions."""
    best: dict[tuple[str, int], Caption] = {}
    for caption in captions:
        key = (caption.track_id, caption.start_ns)
        if key not in best or caption.num_frames > best[key].num_frames:
            best[key] = caption
    keep = {id(c) for c in best.values()}
    return [c for c in captions if id(c) in keep]


def caption_dense(log_id: str, dense: DenseTracks, config: CaptioningConfig) -> LogCaptions:
    """Caption :class:`~scenes.tracks.DenseTracks`."""
    return caption_arrays(
        log_id, dense.timestamps_ns, dense.track_ids, dense.categories, dense.valid,
        dense.center_ego_xyz_m[..., :2], dense.yaw_ego_rad, dense.city_SE3_ego, config,
    )


def caption_log(log: Log, config: CaptioningConfig | None = None) -> LogCaptions:
    """Caption one opened log (its annotation frame grid; ego poses interpolated onto it)."""
    return caption_dense(log.log_id, log.dense_tracks(), config or CaptioningConfig())


@dataclass(frozen=True)
class BatchResult:
    """Captions of many logs, and what was skipped.

    Attributes:
        results: captioned logs, in input order.
        skipped_logs: log folder → reason.
    """

    results: list[LogCaptions]
    skipped_logs: dict[str, str]


def caption_logs(log_dirs: Iterable[Path | str], config: CaptioningConfig | None = None) -> BatchResult:
    """Caption many log folders; a log that cannot be read or captioned is skipped with its reason."""
    config = config or CaptioningConfig()
    results: list[LogCaptions] = []
    skipped: dict[str, str] = {}
    for log_dir in log_dirs:
        try:
            log = Log.open(log_dir)
            if log.timestamps_ns.size == 0:
                skipped[str(log_dir)] = "log has no annotated frames"
                continue
            results.append(caption_log(log, config))
        except (ScenesError, ValueError, OSError) as exc:
            skipped[str(log_dir)] = str(exc).replace("\n", "; ")
    return BatchResult(results, skipped)


def write_outputs(out_dir: Path | str, results: Sequence[LogCaptions]) -> tuple[Path, Path]:
    """Write ``frame_tags.parquet`` and ``captions.parquet`` atomically (temp name, then rename)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = (
        pa.concat_tables([r.frame_tags_table() for r in results]) if results else FRAME_TAGS_SCHEMA.empty_table()
    )
    captions = captions_to_table([c for r in results for c in r.captions])
    paths = (out_dir / FRAME_TAGS_FILENAME, out_dir / CAPTIONS_FILENAME)
    for path, table in zip(paths, (frames, captions)):
        with atomic_path(path) as tmp:
            pq.write_table(table, tmp)
    return paths
