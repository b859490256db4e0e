"""Caption rows of a tagged log: one per host segment, one per (neighbour, window), text and paraphrases."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from captioning.behavior import BehaviorTags
from captioning.config import CaptioningConfig
from captioning.frames import FrameCounts
from captioning.neighbors import NeighborTags
from captioning.smoothing import IntArray
from captioning.tables import EGO_CATEGORY, EGO_TRACK_ID, HOST_STRINGS, Caption, window_attributes
from captioning.tags import NO_TAG
from captioning.text import caption_text, paraphrases
from captioning.unify import Segment, collapse_codes


class TaggedLog(Protocol):
    """What captions are made of: a log's per-frame tags (:class:`captioning.pipeline.LogCaptions`)."""

    @property
    def log_id(self) -> str: ...
    @property
    def timestamps_ns(self) -> IntArray: ...
    @property
    def track_ids(self) -> NDArray[np.str_]: ...
    @property
    def categories(self) -> NDArray[np.str_]: ...
    @property
    def neighbors(self) -> NeighborTags: ...
    @property
    def behavior(self) -> BehaviorTags | None: ...
    def tag_codes(self) -> tuple[IntArray, list[str]]: ...


def host_tags_in(host_code: IntArray, segment: Segment) -> tuple[str, ...]:
    codes = host_code[segment.start : segment.end + 1]
    return tuple(HOST_STRINGS[c] for c in collapse_codes(codes[codes != NO_TAG]))


def make_caption(
    result: TaggedLog, track_id: str, category: str, start: int, end: int, num_frames: int,
    tags: tuple[str, ...], host: tuple[str, ...], window: str, config: CaptioningConfig,
    attributes: dict[str, bool | str | None] | None = None,
) -> Caption:
    start_ns, end_ns = int(result.timestamps_ns[start]), int(result.timestamps_ns[end])
    neighbor_category = None if track_id == EGO_TRACK_ID else category
    canonical = caption_text(neighbor_category, tags, host)
    variants = paraphrases(
        neighbor_category, tags, host, config.text.num_paraphrases, config.text.seed,
        (result.log_id, track_id, start_ns, end_ns), canonical,
    )
    return Caption(result.log_id, track_id, category, start_ns, end_ns, num_frames, tags, host, canonical,
                   tuple(variants), window, attributes)


def host_captions(
    result: TaggedLog, segments: list[Segment], host_code: IntArray, config: CaptioningConfig
) -> list[Caption]:
    return [
        make_caption(result, EGO_TRACK_ID, EGO_CATEGORY, s.start, s.end, s.num_frames, (HOST_STRINGS[s.code],),
                      (HOST_STRINGS[s.code],), "host_segments", config)
        for s in segments
    ]


def neighbor_captions(
    result: TaggedLog, windows: list[Segment], host_code: IntArray, config: CaptioningConfig
) -> list[Caption]:
    codes, strings = result.tag_codes()
    tagged = result.neighbors.tagged
    least = FrameCounts.of_log(config, result.timestamps_ns).segment_min  # tagged frames a caption needs
    out: list[Caption] = []
    for window in windows:
        sub_tagged = tagged[:, window.start : window.end + 1]
        counts = sub_tagged.sum(axis=1)
        host = host_tags_in(host_code, window)
        chosen = np.flatnonzero(counts >= least)
        attributes = (None if result.behavior is None
                      else window_attributes(result.behavior, chosen, window, sub_tagged[chosen]))
        for j, k in enumerate(chosen.tolist()):
            frames = np.flatnonzero(sub_tagged[k]) + window.start
            tags = tuple(strings[c] for c in collapse_codes(codes[k, frames]))
            out.append(
                make_caption(result, str(result.track_ids[k]), str(result.categories[k]), int(frames[0]),
                              int(frames[-1]), int(counts[k]), tags, host, config.windows.strategy.value, config,
                              None if attributes is None else attributes[j])
            )
    return out


def unique_starts(captions: list[Caption]) -> list[Caption]:
    """One caption per (track, start): overlapping sliding windows can clip a track to the same
    start; downstream clip ids are ``log:track:start_ns``, so keep the longest of such captions."""
    best: dict[tuple[str, int], Caption] = {}
    for caption in captions:
        key = (caption.track_id, caption.start_ns)
        if key not in best or caption.num_frames > best[key].num_frames:
            best[key] = caption
    keep = {id(c) for c in best.values()}
    return [c for c in captions if id(c) in keep]
