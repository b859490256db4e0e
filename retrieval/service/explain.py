"""What the page says about a search: readable tag names, each result's object sentence and matching
tags, the scale of each mode's scores, a phrasing the index knows, and whether the best score is weak.

Weak results (:func:`calibrate`): for each search mode the service measures, once, how high the best
score is when the index holds a match and when it does not, on the index's validation clips
(``split == val``). Each distinct object sentence of those clips is a query (at most
:data:`CALIBRATION_QUERIES`, chosen by a hash, so the choice is stable); its matches are the indexed
clips whose caption tells the same object sentence. The query is searched twice: among its matches (the
best score when a match exists) and among every other clip (the best score when none does). The
threshold is the score that separates the two sets best (highest balanced accuracy); a search whose
best result scores below it is flagged as weak. An index without validation clips is never flagged.
"""

from __future__ import annotations

import hashlib
import re
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from captioning.tags import split_neighbor_tag
from captioning.text import CONTEXT_PHRASES, LANE_PHRASES, MOTION_PHRASES, caption_halves
from indexes.filters import Condition, Op
from retrieval.records import SearchResult

#: Most validation queries one mode is calibrated on.
CALIBRATION_QUERIES = 48
#: How each mode's score reads; the page shows it beside the results.
SCORE_SCALES: dict[str, str] = {
    "model": "cosine similarity of the sentence's and the clip's embeddings (trained model), from −1 to 1",
    "captions": "cosine similarity of the sentence and the clip's rule caption (sentence encoder), from −1 to 1",
    "hybrid": "model and rule-caption scores, each in standard deviations above the index's average clip, "
              "mixed by the hybrid weight: 0 is an average clip, 3 is far above it",
    "similar": "cosine similarity of the two clips' embeddings, from −1 to 1",
}
_HOST_WORDS = {"stationary": "standing", "accelerating": "accelerating", "decelerating": "decelerating",
               "cruising": "cruising", "steering_left": "steering left", "steering_right": "steering right",
               "heading_straight": "straight"}
_STOP_WORDS = frozenset({"a", "an", "the", "of", "in", "on", "at", "to", "into", "from", "is", "are", "its", "it",
                         "and", "then", "with", "while", "as", "by", "for", "ego", "vehicle", "lane", "we", "us",
                         "our"})


def tag_label(tag: str) -> str:
    """A tag of the unified sequence in words: ``left:approach:braking`` → ``left lane · approaches · braking``;
    host tags (``cruising:heading_straight``) → ``ego cruising · straight``."""
    parts = tag.split(":")
    if len(parts) == 2 and parts[0] in _HOST_WORDS and parts[1] in _HOST_WORDS:
        return f"ego {_HOST_WORDS[parts[0]]} · {_HOST_WORDS[parts[1]]}"
    lane, motion, action, context = split_neighbor_tag(tag)
    words = []
    if lane in LANE_PHRASES:
        words.append(LANE_PHRASES[lane][0].removeprefix("in the ").replace("ego lane", "ego lane"))
    elif lane:
        words.append(lane.replace("_", " "))
    if motion:
        words.append(MOTION_PHRASES[motion][0] if motion in MOTION_PHRASES else motion.replace("_", " "))
    if action:
        words.append(action.replace("_", " "))
    if context:
        words.append(CONTEXT_PHRASES[context][0] if context in CONTEXT_PHRASES else context.replace("_", " "))
    return " · ".join(words) or tag


def object_sentence(caption: str) -> str:
    """The caption's sentence about the object (the whole caption for the ego's own moments and for
    captions not written by the rules)."""
    _host, obj = caption_halves(caption)
    return obj or caption


def _words(text: str) -> set[str]:
    return {w.rstrip("s") for w in re.findall(r"[a-z]+", text.lower()) if w not in _STOP_WORDS and len(w) > 2}


def matching_tags(query: str, tags: Sequence[str]) -> list[str]:
    """The tags whose words the query uses (``approaches`` matches ``left lane · approaches``)."""
    wanted = _words(query)
    return [t for t in tags if wanted & _words(tag_label(t) + " " + t.replace(":", " ").replace("_", " "))]


def explain_result(query: str | None, result: SearchResult) -> dict[str, Any]:
    """What the page shows with a result: its object sentence, its tags in words, and which of them match."""
    out: dict[str, Any] = {"object_sentence": object_sentence(result.caption),
                           "tag_labels": [tag_label(t) for t in result.tags]}
    if query:
        out["matched_tags"] = matching_tags(query, result.tags)
    return out


# ---------------------------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class Calibration:
    """Where a mode's best score separates searches with a match from searches without one.

    Attributes:
        mode: ``model``, ``captions`` or ``hybrid``.
        threshold: best scores below it are weak.
        queries: validation queries measured.
        matched: the fraction of them whose best match scored at or above the threshold.
        unmatched: the fraction whose best non-matching clip scored below it.
        matched_median: the median best score when a match exists.
        unmatched_median: the median best score when none does.
    """

    mode: str
    threshold: float
    queries: int
    matched: float
    unmatched: float
    matched_median: float
    unmatched_median: float

    def judge(self, best: float | None) -> dict[str, Any]:
        """Whether a search whose best score is ``best`` is weak, and on what basis."""
        weak = best is None or best < self.threshold
        return {"weak": weak, "best": best, "threshold": round(self.threshold, 4),
                "basis": (f"calibrated on {self.queries} validation queries: with a match in the index the best "
                          f"score was at least {self.threshold:.3f} in {self.matched:.0%} of them (median "
                          f"{self.matched_median:.3f}); without one, the best score stayed below it in "
                          f"{self.unmatched:.0%} (median {self.unmatched_median:.3f})")}


def best_threshold(matched: np.ndarray, unmatched: np.ndarray) -> float:
    """The score that best separates ``matched`` best scores (above) from ``unmatched`` ones (below):
    the highest balanced accuracy, halfway between neighbouring scores."""
    scores = np.unique(np.concatenate([matched, unmatched]))
    cuts = np.concatenate([[scores[0] - 1e-6], (scores[1:] + scores[:-1]) / 2, [scores[-1] + 1e-6]])
    tpr = (matched[None, :] >= cuts[:, None]).mean(axis=1)
    tnr = (unmatched[None, :] < cuts[:, None]).mean(axis=1)
    return float(cuts[int(np.argmax(tpr + tnr))])


#: A search of one mode: (query, k, filter) → results.
Rank = Callable[[str, int, list[Condition]], list[SearchResult]]


def calibrate(mode: str, rows: Sequence[dict[str, Any]], rank: Rank,
              max_queries: int = CALIBRATION_QUERIES) -> Calibration | None:
    """Calibrate ``mode`` (see the module docstring) on metadata ``rows`` (``clip_id``, ``caption``,
    ``split``) with ``rank``; None without validation clips or without both kinds of outcome."""
    sentence_of = {str(r["clip_id"]): object_sentence(str(r.get("caption") or "")) for r in rows}
    by_sentence: dict[str, list[str]] = {}
    for clip_id, sentence in sentence_of.items():
        by_sentence.setdefault(sentence, []).append(clip_id)
    queries = sorted({sentence_of[str(r["clip_id"])] for r in rows if r.get("split") == "val"} - {""},
                     key=lambda s: hashlib.blake2b(s.encode(), digest_size=8).digest())[:max_queries]
    matched, unmatched = [], []
    for sentence in queries:
        ids = tuple(by_sentence[sentence])
        if len(ids) == len(sentence_of):
            continue
        inside = rank(sentence, 1, [Condition("clip_id", Op.IN, ids)])
        outside = rank(sentence, 1, [Condition("clip_id", Op.NOT_IN, ids)])
        if inside and outside:
            matched.append(inside[0].score)
            unmatched.append(outside[0].score)
    if not matched:
        return None
    m, u = np.asarray(matched), np.asarray(unmatched)
    t = best_threshold(m, u)
    return Calibration(mode, t, len(m), float((m >= t).mean()), float((u < t).mean()), float(np.median(m)),
                       float(np.median(u)))


class Calibrations:
    """Each mode's :class:`Calibration`, measured when a search of that mode first needs it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._done: dict[tuple[Any, ...], Calibration | None] = {}

    def get(self, key: tuple[Any, ...], measure: Callable[[], Calibration | None]) -> Calibration | None:
        with self._lock:
            if key not in self._done:
                self._done[key] = measure()
            return self._done[key]


# ---------------------------------------------------------------------------------------------- phrasing


def suggestion(query: str, unused: Sequence[str], search_captions: Callable[[str], list[SearchResult]],
               encode: Callable[[Sequence[str]], np.ndarray]) -> dict[str, Any] | None:
    """For a query some of whose words the program leaves unused: those words and a phrasing the index
    knows: of the nearest rule captions (``search_captions``), the sentence (the ego's or the object's) that
    the sentence encoder ``encode`` finds closest to the query."""
    if not unused:
        return None
    sentences = list(dict.fromkeys(h for r in search_captions(query) for h in (caption_halves(r.caption) if
                                                                                caption_halves(r.caption)[0] else
                                                                                (r.caption,)) if h))
    phrasing = None
    if sentences:
        x = np.asarray(encode([query, *sentences]), dtype=np.float32)
        phrasing = sentences[int(np.argmax(x[1:] @ x[0]))].rstrip(".")
    return {"unused_words": list(unused), "phrasing": phrasing,
            "note": f"no meaning was found for {', '.join(repr(w) for w in unused)}: the search used the rest"
                    + (f"; a phrasing the index knows: “{phrasing}”" if phrasing else "")}
