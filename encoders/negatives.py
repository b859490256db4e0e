"""Temporal hard negatives: captions of a clip's steps edited so that only order or direction changes.

In-batch negatives almost never hold a clip's own caption with its steps reversed, so nothing in a
contrastive loss asks for order. These edits of a clip's step tags (``lane:motion[:action][:context]``)
are rendered by captioning's caption generator and train as extra negatives of the clip
(:func:`encoders.loss.contrastive_loss`):

    reverse   the steps in reverse order               left:approach, host:away → host:away, left:approach
    motion    one approach ↔ away step flipped         left:approach, host:away → left:approach, host:approach
              (repeats merged: the steps stay steps)                             → left:approach, host:approach
    mirror    lanes mirrored left ↔ right              left:approach, host:away → right:approach, host:away

An edit that changes nothing, or whose caption equals the clip's own, is no negative and is dropped.
For the ego's own clips (category ``ego``) the steps are host tags: only ``reverse`` applies.
"""

from __future__ import annotations

import random
import zlib
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from captioning.tags import Lane, Motion
from captioning.text import caption_text
from captioning.unify import collapse
from encoders.config import HardNegative

#: What a clip (a dataset item) needs for its hard negatives.
NEGATIVE_FIELDS = ("clip_id", "category", "tags", "host_tags")
#: Category of the ego's own clips: their tags are host tags and their caption is the host sentence.
EGO_CATEGORY = "ego"
#: approach ↔ away: the one motion edit, shared with :mod:`encoders.time_reversal`.
FLIP_MOTION = {Motion.APPROACH.value: Motion.AWAY.value, Motion.AWAY.value: Motion.APPROACH.value}
_MIRROR_LANE = {Lane.LEFT.value: Lane.RIGHT.value, Lane.RIGHT.value: Lane.LEFT.value,
                Lane.LEFT_LATERAL.value: Lane.RIGHT_LATERAL.value, Lane.RIGHT_LATERAL.value: Lane.LEFT_LATERAL.value}


@dataclass(frozen=True)
class Negative:
    """One edited caption of a clip.

    Attributes:
        kind: the edit.
        tags: the edited steps.
        canonical: their canonical caption (what positives compare with).
        text: the caption to encode: the canonical one or a paraphrase of it.
    """

    kind: HardNegative
    tags: tuple[str, ...]
    canonical: str
    text: str


def render_caption(category: str, tags: Sequence[str], host_tags: Sequence[str],
                   rng: random.Random | None = None) -> str:
    """captioning's caption of one clip's steps (a paraphrase when ``rng`` is given); for an ``ego``
    clip the steps are the host's own tags."""
    if category == EGO_CATEGORY:
        return caption_text(None, tags, list(tags), rng)
    return caption_text(category, tags, list(host_tags), rng)


def reversed_steps(tags: Sequence[str]) -> list[str] | None:
    """The steps in reverse order, or None when that changes nothing (fewer than 2 steps, a palindrome)."""
    out = list(tags)[::-1]
    return out if len(out) >= 2 and out != list(tags) else None


def _with_part(tag: str, index: int, table: dict[str, str]) -> str:
    parts = tag.split(":")
    parts[index] = table.get(parts[index], parts[index])
    return ":".join(parts)


def edited_steps(tags: Sequence[str], kind: HardNegative | str, key: str = "") -> list[str] | None:
    """``tags`` edited by ``kind``, or None when the edit changes nothing.

    ``motion`` flips one of the approach/away steps, chosen by a stable hash of ``key`` (the clip id),
    so a clip always gets the same edit.
    """
    tags = list(tags)
    kind = HardNegative(kind)
    if kind == HardNegative.REVERSE:
        return reversed_steps(tags)
    if kind == HardNegative.MOTION:
        steps = [i for i, t in enumerate(tags) if t.count(":") and t.split(":")[1] in FLIP_MOTION]
        if not steps:
            return None
        i = steps[zlib.crc32(key.encode()) % len(steps)]
        out = collapse([*tags[:i], _with_part(tags[i], 1, FLIP_MOTION), *tags[i + 1 :]])
    else:
        out = [_with_part(t, 0, _MIRROR_LANE) for t in tags]
    return out if out != tags else None


def hard_negatives(category: str, tags: Sequence[str], host_tags: Sequence[str], kinds: Sequence[HardNegative | str],
                   key: str = "", rng: random.Random | None = None, paraphrase_probability: float = 0.0,
                   caption: str | None = None) -> list[Negative]:
    """The edited captions of one clip, one per kind that changes its caption.

    ``caption`` is the clip's stored canonical caption, if any. With ``rng``, each
    negative is a paraphrase with ``paraphrase_probability``, as the positives are when augmenting.
    """
    if category == EGO_CATEGORY:  # host tags have no lanes and no approach/away to edit
        kinds = [k for k in kinds if k == HardNegative.REVERSE]
    # The clip's caption as stored and as rendered now: an edit that renders as either is no negative.
    own = {render_caption(category, tags, host_tags), caption}
    out: list[Negative] = []
    for kind in kinds:
        edited = edited_steps(tags, kind, key)
        if edited is None:
            continue
        canonical = render_caption(category, edited, host_tags)
        if canonical in own:
            continue
        text = canonical
        if rng is not None and rng.random() < paraphrase_probability:
            text = render_caption(category, edited, host_tags, rng)
        out.append(Negative(HardNegative(kind), tuple(edited), canonical, text))
    return out


class BatchNegatives(NamedTuple):
    """The hard negatives of a training batch (:func:`batch_negatives`)."""

    texts: list[str]  #: (M,) the captions
    own: list[list[bool]]  #: (B, M): negative j is clip i's positive
    reversed_of: list[int]  #: (M,) the clip whose steps negative j reverses, −1 for the other edits


def batch_negatives(batch: dict[str, Any], kinds: Sequence[HardNegative], keys: Sequence[Hashable],
                    by: str = "caption", seed: int = 0, step: int = 0,
                    paraphrase_probability: float = 0.0) -> BatchNegatives:
    """The hard negatives of a training batch: their texts, which clip each is a positive of, and
    which clip's steps each reverses (for :func:`encoders.loss.order_loss`).

    ``keys`` are the batch's positive keys (B,): canonical captions (``by="caption"``) or tag tuples
    (``by="tags"``). The paraphrases drawn depend only on (seed, step, clip), so a resumed run draws
    the same. The batch needs ``clip_id``, ``category``, ``tags`` and ``host_tags``.
    """
    missing = [k for k in NEGATIVE_FIELDS if k not in batch]
    if missing:
        raise KeyError(f"hard negatives need the clips' {missing} (the batch has {sorted(batch)})")
    texts: list[str] = []
    negative_keys: list[Hashable] = []
    reversed_of: list[int] = []
    for i, clip in enumerate(batch["clip_id"]):
        rng = random.Random(f"{seed}\x1fhard negatives\x1f{step}\x1f{clip}")
        own = batch["canonical_caption"][i] if "canonical_caption" in batch else None
        for neg in hard_negatives(str(batch["category"][i]), batch["tags"][i], batch["host_tags"][i], kinds,
                                  key=str(clip), rng=rng, paraphrase_probability=paraphrase_probability,
                                  caption=own):
            texts.append(neg.text)
            negative_keys.append(neg.canonical if by == "caption" else neg.tags)
            reversed_of.append(i if neg.kind == HardNegative.REVERSE else -1)
    return BatchNegatives(texts, [[k == n for n in negative_keys] for k in keys], reversed_of)
