"""Temporal hard negatives: captions of a clip's steps edited so that only their order changes.

In-batch negatives almost never hold a clip's own caption with its steps reversed, so nothing in a
contrastive loss asks for order. An edit of a clip's step tags (``lane:motion[:action][:context]``)
is rendered by captioning's caption generator and trains as an extra negative of the clip
(:func:`encoders.loss.contrastive_loss`):

    reverse   the steps in reverse order               left:approach, host:away → host:away, left:approach

An edit that changes nothing, or whose caption equals the clip's own, is no negative and is dropped.
For the ego's own clips (category ``ego``) the steps are host tags, and they reverse as a neighbour's do.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from captioning.text import caption_text
from encoders.train_config import HardNegative

#: What a clip (a dataset item) needs for its hard negatives.
NEGATIVE_FIELDS = ("clip_id", "category", "tags", "host_tags")
#: Category of the ego's own clips: their tags are host tags and their caption is the host sentence.
EGO_CATEGORY = "ego"


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


#: Each edit: a clip's steps → the edited steps, or None when the edit changes nothing.
_EDITS: dict[HardNegative, Callable[[Sequence[str]], list[str] | None]] = {HardNegative.REVERSE: reversed_steps}


def edited_steps(tags: Sequence[str], kind: HardNegative | str) -> list[str] | None:
    """``tags`` edited by ``kind``, or None when the edit changes nothing."""
    return _EDITS[HardNegative(kind)](list(tags))


def hard_negatives(category: str, tags: Sequence[str], host_tags: Sequence[str], kinds: Sequence[HardNegative | str],
                   rng: random.Random | None = None, paraphrase_probability: float = 0.0,
                   caption: str | None = None) -> list[Negative]:
    """The edited captions of one clip, one per kind that changes its caption.

    ``caption`` is the clip's stored canonical caption, if any. With ``rng``, each
    negative is a paraphrase with ``paraphrase_probability``, as the positives are when augmenting.
    """
    # The clip's caption as stored and as rendered now: an edit that renders as either is no negative.
    own = {render_caption(category, tags, host_tags), caption}
    out: list[Negative] = []
    for kind in kinds:
        edited = edited_steps(tags, kind)
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
    reversed_of: list[int]  #: (M,) the clip whose steps negative j reverses, −1 for an edit that is no reversal


def batch_negatives(batch: dict[str, Any], kinds: Sequence[HardNegative], keys: Sequence[str],
                    seed: int = 0, step: int = 0, paraphrase_probability: float = 0.0) -> BatchNegatives:
    """The hard negatives of a training batch: their texts, which clip each is a positive of, and
    which clip's steps each reverses (for :func:`encoders.loss.order_loss`).

    ``keys`` are the batch's canonical captions (B,), which positives compare. The paraphrases drawn
    depend only on (seed, step, clip), so a resumed run draws the same. The batch needs ``clip_id``,
    ``category``, ``tags`` and ``host_tags``.
    """
    missing = [k for k in NEGATIVE_FIELDS if k not in batch]
    if missing:
        raise KeyError(f"hard negatives need the clips' {missing} (the batch has {sorted(batch)})")
    texts: list[str] = []
    negative_keys: list[str] = []
    reversed_of: list[int] = []
    for i, clip in enumerate(batch["clip_id"]):
        rng = random.Random(f"{seed}\x1fhard negatives\x1f{step}\x1f{clip}")
        own = batch["canonical_caption"][i] if "canonical_caption" in batch else None
        for neg in hard_negatives(str(batch["category"][i]), batch["tags"][i], batch["host_tags"][i], kinds,
                                  rng=rng, paraphrase_probability=paraphrase_probability, caption=own):
            texts.append(neg.text)
            negative_keys.append(neg.canonical)
            reversed_of.append(i if neg.kind == HardNegative.REVERSE else -1)
    return BatchNegatives(texts, [[k == n for n in negative_keys] for k in keys], reversed_of)
