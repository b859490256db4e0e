"""Partial queries: each half of a clip's caption as a query of its own.

A caption is the ego's sentence, then the object's ("The ego vehicle is cruising straight. A car in
the left lane approaches, then moves into the ego lane."), but people type one half: "a stopped car
in the ego lane", "we brake and come to a stop". Trained on whole captions only, the demo's model
finds the clips of an object sentence typed alone far less well than those of a whole caption
(``docs/research/partial-queries.md``).

Each training step therefore adds, beside the clips' captions, the object sentence of every clip's
caption (``object_share``) and the ego sentence of some (``host_share``; a log's clips share it, so
a few carry it), cut from the caption the clip trains with (a paraphrase or the canonical one). They
train as extra queries of the batch's clips (:func:`encoders.loss.partial_query_loss`); a half's
positives are the clips whose canonical caption has the same half, whatever the other half says.
The whole captions, their hard negatives and the order loss stay as they were: a half is a query
beside them, not instead of them (in place of a quarter of the captions, the same halves cost
temporal order on the demo's split).
"""

from __future__ import annotations

import random
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

from captioning.text import HOST_HALF, OBJECT_HALF, caption_halves

#: What a clip (a dataset item) needs for its partial queries.
PARTIAL_FIELDS = ("clip_id", "category", "caption", "canonical_caption")


class BatchPartials(NamedTuple):
    """The partial queries of a training batch (:func:`batch_partials`)."""

    texts: list[str]  #: (M,) the halves, clip by clip in batch order
    positives: list[list[bool]]  #: (B, M): clip i answers half m


def chosen_halves(clip_id: str, category: str, canonical: str, seed: int, step: int, object_share: float,
                  host_share: float) -> list[int]:
    """The halves of one clip's caption that train as queries at ``step`` (:data:`HOST_HALF`,
    :data:`OBJECT_HALF`), drawn from (seed, step, clip) alone, so that every process of a data-parallel
    run draws the same for the same clip, and a resumed run the same as before."""
    if category == "ego" or None in caption_halves(canonical):  # one sentence: no half to ask for apart
        return []
    rng = random.Random(f"{seed}\x1fpartial queries\x1f{step}\x1f{clip_id}")
    halves = [OBJECT_HALF] if rng.random() < object_share else []
    return halves + ([HOST_HALF] if rng.random() < host_share else [])


def _halves(clips: Mapping[str, Sequence[Any]], seed: int, step: int, object_share: float,
            host_share: float) -> list[tuple[int, int]]:
    """(clip index, half) of every partial query of ``clips`` at ``step``, clip by clip."""
    return [(i, half) for i, (clip, category, canonical) in
            enumerate(zip(clips["clip_id"], clips["category"], clips["canonical_caption"]))
            for half in chosen_halves(str(clip), str(category), str(canonical), seed, step, object_share, host_share)]


def batch_partials(batch: Mapping[str, Any], seed: int, step: int, object_share: float, host_share: float,
                   whole: Mapping[str, Sequence[Any]] | None = None) -> BatchPartials:
    """The halves of ``batch``'s captions that train as queries at ``step``, and which clips answer each.

    A half's text is cut from the caption the clip trains with (``caption``: a paraphrase or the
    canonical caption); which clips answer it, from their canonical captions. In data-parallel
    training, ``whole`` is the whole batch (``clip_id``, ``category``, ``canonical_caption`` of every
    process's clips, rank order): the texts stay this process's and the positives are the whole
    batch's, (whole B, whole M), as every process's texts gathered in rank order are its halves.

    Raises:
        KeyError: the batch lacks one of :data:`PARTIAL_FIELDS`.
    """
    missing = [k for k in PARTIAL_FIELDS if k not in batch]
    if missing:
        raise KeyError(f"partial queries need the clips' {missing} (the batch has {sorted(batch)})")
    mine = _halves(batch, seed, step, object_share, host_share)
    texts: list[str] = []
    for i, half in mine:
        # A paraphrase has both halves as its canonical caption has; the canonical half should one not.
        texts.append(caption_halves(str(batch["caption"][i]))[half] or
                     str(caption_halves(str(batch["canonical_caption"][i]))[half]))
    rows, chosen = (batch, mine) if whole is None else (whole, _halves(whole, seed, step, object_share, host_share))
    answers = [caption_halves(str(c)) for c in rows["canonical_caption"]]  # an ego clip answers its ego sentence
    keys = [(half, answers[i][half]) for i, half in chosen]
    positives = [[key is not None and a[half] == key for half, key in keys] for a in answers]
    return BatchPartials(texts, positives)
