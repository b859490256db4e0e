"""Tag queries over logs: scene tags over time and log retrieval by compositional tags.

>>> from retrieval.tagging import TagSearch
>>> tags = TagSearch("run")
>>> times_ns, values = tags.series("logs/a", "pedestrian_density", "front")   # m² covered ahead
>>> spans = tags.find(["logs/a", "logs/b"], "blocked_by & four_way", region="front")

A log's BEV frames are built exactly as the clip stage builds them (:func:`encoders.clips.render.render_log`
over the whole log, once): they are reused from the clips folder the model was trained on when that
folder holds the log rendered with the same settings, else rendered into a cache folder
(``RUN_DIR/tag_cache`` unless given) and reused from there.

Ranking (the paper's retrieval setting): for every frame, the composed tag tensor (per cell, see
:func:`encoders.tagging.scene_tags.compose`) is pooled over the region; runs of consecutive frames
whose value is at least ``threshold`` and that last at least ``min_duration_s`` are spans, scored by
their mean value; spans of all logs are ranked by score.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from encoders.clips.blocks import LOGS_KEPT, FrameArray
from encoders.tagging.attributes import Region, TagError, parse_attribute, parse_region
from encoders.tagging.inference import Tagger, load_tagger
from encoders.tagging.scene_tags import (
    TagExpression,
    coarse_grid,
    compose,
    downsample_max,
    map_channel_index,
    parse_tag_expression,
    pool_values,
    reduction_of,
    region_mask,
    region_masks,
    values_of,
)
from scenesearch_base.lru import Lru

CACHE_DIR = "tag_cache"


@dataclass(frozen=True)
class TagSpan:
    """A time span of a log where a tag holds.

    Attributes:
        log_id: the log.
        start_ns, end_ns: first and last frame of the span.
        score: mean pooled value over the span.
        peak: largest pooled value in the span.
        frames: frames in the span.
    """

    log_id: str
    start_ns: int
    end_ns: int
    score: float
    peak: float
    frames: int

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["duration_s"] = round(self.duration_s, 3)
        return d


@dataclass
class LogFrames:
    """A log's rendered BEV frames.

    Attributes:
        log_id: the log.
        timestamps_ns: (F,) frame times.
        bev_lidar: (F, Cl, H, W) uint8.
        bev_map: (F, Cm, H, W) uint8.
        has_map: whether the log has a map.
    """

    log_id: str
    timestamps_ns: NDArray[np.int64]
    bev_lidar: FrameArray
    bev_map: FrameArray
    has_map: bool


def spans_of(values: NDArray[np.floating], timestamps_ns: NDArray[np.int64], threshold: float,
             min_duration_s: float) -> list[tuple[int, int]]:
    """Runs of frames with ``values ≥ threshold`` lasting at least ``min_duration_s``.

    Args:
        values: (F,) pooled values.
        timestamps_ns: (F,) frame times.

    Returns:
        (first, last) frame index pairs, inclusive.
    """
    on = np.asarray(values) >= threshold
    if not on.any():
        return []
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    dur = (timestamps_ns[ends] - timestamps_ns[starts]) * 1e-9
    keep = dur >= min_duration_s - 1e-9
    return list(zip(starts[keep].tolist(), ends[keep].tolist()))


#: Bytes of per-cell tag values a tag search keeps: queries over a fleet's logs would otherwise keep
#: every log's (sizes: docs/research/ingest-profile.md).
VALUES_KEPT_BYTES = 1 << 30


class TagSearch:
    """Tag queries with one trained model; per-log frames and tag tensors are kept in memory, the least
    recently used going first (:data:`VALUES_KEPT_BYTES`, :data:`encoders.clips.blocks.LOGS_KEPT` logs)."""

    def __init__(self, run_dir: Path | str, cache_dir: Path | str | None = None, clips_dir: Path | str | None = None,
                 device: str = "cpu", tagger: Tagger | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.tagger = tagger or load_tagger(self.run_dir, device)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else self.run_dir / CACHE_DIR
        clips = clips_dir or self.tagger.meta.get("clips_dir")
        self.clips_dir = Path(clips) if clips else None
        self.grid = coarse_grid(self.tagger.grid, self.tagger.downsample)
        self._frames: Lru[str, LogFrames] = Lru(LOGS_KEPT)
        self._values: Lru[tuple[str, str], NDArray[np.float32]] = Lru(VALUES_KEPT_BYTES, lambda v: v.nbytes)

    @property
    def attributes(self) -> tuple[str, ...]:
        return self.tagger.names

    # -- frames and tag tensors -------------------------------------------------------------------
    def frames(self, log_dir: Path | str) -> LogFrames:
        """The log's BEV frames, reused from the training clips folder or rendered once into the cache."""
        from encoders.clips import layout
        from encoders.clips.config import ClipsConfig
        from encoders.clips.render import render_log
        from encoders.clips.render_stats import reuse_problem
        from scenes.log import Log

        log_dir = Path(log_dir)
        log_id = log_dir.name
        kept = self._frames.get(log_id)
        if kept is not None:
            return kept
        log = Log.open(log_dir)
        config = ClipsConfig.from_dict(self.tagger.meta.get("clips_config") or {}, source=str(self.run_dir))
        dense = log.dense_tracks()
        folder = None
        for root in (self.clips_dir, self.cache_dir):
            if root is not None and reuse_problem(layout.rendered_log_dir(root, log_id), config, dense) is None:
                folder = layout.rendered_log_dir(root, log_id)
                break
        if folder is None:
            render_log(log, config, self.cache_dir, dense)
            folder = layout.rendered_log_dir(self.cache_dir, log_id)
        ts = pq.read_table(folder / layout.FRAMES_FILE, columns=["timestamp_ns"]).column(0).to_numpy()
        frames = LogFrames(log_id, ts.astype(np.int64), layout.load_rendered_array(folder, layout.BEV_LIDAR_FILE),
                           layout.load_rendered_array(folder, layout.BEV_MAP_FILE), log.map_path is not None)
        self._frames.put(log_id, frames)
        return frames

    def values(self, log_dir: Path | str, attribute: str) -> NDArray[np.float32]:
        """(F, h, w) per-cell values of an attribute (probabilities for discrete ones, values for continuous)."""
        return self.values_many(log_dir, [attribute])[0]

    def values_many(self, log_dir: Path | str, attributes: Sequence[str]) -> list[NDArray[np.float32]]:
        """Per-cell values of several attributes, from one pass of the backbone for those not cached."""
        names = [parse_attribute(a, list(self.attributes)) for a in attributes]
        fr = self.frames(log_dir)
        found = {n: self._values.get((fr.log_id, n)) for n in dict.fromkeys(names)}
        todo = [n for n, value in found.items() if value is None]
        if todo:
            rows = [self.tagger.names.index(n) for n in todo]
            v = self.tagger.tag_frames(fr.bev_lidar, fr.bev_map, attributes=rows)  # (F, len(todo), h, w)
            head, cell_m2 = self.tagger.head.config, self.grid.resolution_m**2
            for i, n in enumerate(todo):
                value = values_of(v[:, i], n, head.kind(n), head.footprint_share(n, cell_m2))
                self._values.put((fr.log_id, n), value)
                found[n] = value
        return [found[n] for n in names]  # type: ignore[misc]

    def mask(self, log_dir: Path | str, region: str | Region) -> NDArray[np.bool_]:
        """(h, w) or (F, h, w) region mask; map regions raise :class:`TagError` for a log without a map."""
        r = parse_region(region) if isinstance(region, str) else region
        fr = self.frames(log_dir)
        if not r.needs_map:
            return region_mask(region_masks(self.grid), r)
        if not fr.has_map:
            return region_mask(region_masks(self.grid), r, where=f"log {fr.log_id}")  # raises: no map
        ch = map_channel_index(self.tagger.map_channels or _default_channels(), r)
        return downsample_max(np.asarray(fr.bev_map[:, ch]), self.tagger.downsample) > 0

    # -- queries ----------------------------------------------------------------------------------
    def series(self, log_dir: Path | str, tag: str, region: str | Region = Region.FULL, h: str = "identity",
               kappa: float = 0.5) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """Pooled value of an attribute (or a composition such as ``"stopped & four_way"``) per frame.

        Returns:
            (F,) timestamps and (F,) values: m² covered for densities, m/s for speed, probability otherwise.
        """
        expr = parse_tag_expression(tag, list(self.attributes))
        mask = self.mask(log_dir, region)  # checks the region before any model work
        fr = self.frames(log_dir)
        tensors = self.values_many(log_dir, expr.attributes)
        composed = compose(tensors, expr.op, h, kappa)
        pooled = pool_values(composed, mask, reduction_of(expr.attributes), self.grid.resolution_m**2)
        return fr.timestamps_ns, pooled

    def find(self, log_dirs: Sequence[Path | str], tag: str, region: str | Region = Region.FRONT,
             threshold: float = 0.5, min_duration_s: float = 0.5, k: int | None = None, h: str = "identity",
             kappa: float = 0.5) -> list[TagSpan]:
        """Spans of the logs where the tag holds in the region, best first (see the module docstring)."""
        expr: TagExpression = parse_tag_expression(tag, list(self.attributes))
        region = parse_region(region) if isinstance(region, str) else region
        spans: list[TagSpan] = []
        for log_dir in log_dirs:
            ts, vals = self.series(log_dir, str(expr), region, h, kappa)
            log_id = Path(log_dir).name
            for a, b in spans_of(vals, ts, threshold, min_duration_s):
                seg = vals[a : b + 1]
                spans.append(TagSpan(log_id, int(ts[a]), int(ts[b]), round(float(seg.mean()), 4),
                                     round(float(seg.max()), 4), int(b - a + 1)))
        spans.sort(key=lambda s: (-s.score, -s.frames, s.log_id, s.start_ns))
        return spans[:k] if k is not None else spans


def _default_channels() -> list[str]:
    from encoders.clips.raster import MAP_CHANNELS

    return list(MAP_CHANNELS)


def tag_log(run_dir: Path | str, log_dir: Path | str, attribute: str, region: str = "full",
            cache_dir: Path | str | None = None) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """(F,) timestamps and (F,) pooled values of ``attribute`` over ``region`` in one log."""
    return TagSearch(run_dir, cache_dir).series(log_dir, attribute, region)


def find(run_dir: Path | str, log_dirs: Sequence[Path | str], tag_expr: str, region: str = "front",
         threshold: float = 0.5, min_duration_s: float = 0.5, cache_dir: Path | str | None = None,
         k: int | None = None) -> list[TagSpan]:
    """Ranked spans ``(log_id, start_ns, end_ns, score)`` of the logs where ``tag_expr`` holds in ``region``."""
    if not log_dirs:
        raise TagError("find needs at least one log folder")
    return TagSearch(run_dir, cache_dir).find(log_dirs, tag_expr, region, threshold, min_duration_s, k)
