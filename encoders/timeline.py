"""Time slots: embeddings in which *when* something happens is a part of the vector.

A caption says what happens in order ("approaches, then moves away"), never when. One pooled vector
per side keeps the order weakly: the frozen sentence encoder gives a caption and its steps reversed
a cosine of nearly 1 (``docs/research/text-order-options.md``), and a clip's query token mixes all its
frames. With ``time_slots: K`` each embedding is the concatenation

    [ global (D − K·S) | slot 1 (S) | … | slot K (S) ]

where slot k stands for the k-th of K equal stretches of the clip:

    text   each sentence's steps are stretched over the K slots (step ⌊k·n/K⌋ of n goes to slot k),
           (:func:`encoders.text.sentence_steps`), and one head reads, per slot, the whole text and
           the mean of what its sentences say there;
    video  each slot pools the frame tokens of a temporal stream with an attention whose prior is
           centred on a point of the clip, the first slot's on its first frame and the last slot's on
           its last (a learnable centre and width), and one head maps the pooled token.

Both sides use one head for every slot, so a caption with its steps reversed is the same slot
vectors in reverse order: the dot product then scores the order directly, and the reversed caption
matches a clip only where the clip's stretches look alike. Free text of any form still gives one
vector: a sentence without "then" holds its one step in every slot.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def slot_of_steps(num_steps: int, slots: int) -> list[int]:
    """(K,) the step each of ``slots`` stretches holds when ``num_steps`` steps share the clip evenly."""
    return [k * num_steps // slots for k in range(slots)]


class SlotTextHead(nn.Module):
    """Sentence features of a text → (B, D): a global head over the whole text and one shared head per slot.

    Input (B, F + K·F): the whole text's feature, then per slot the feature of what the text says there
    (:class:`encoders.text.SlotText`). Each slot's head also reads the whole text, which names what a
    later step leaves out ("then moves away": who does).
    """

    def __init__(self, features: int, embed_dim: int, slots: int, slot_dim: int, hidden: int) -> None:
        super().__init__()
        self.features, self.slots = features, slots
        self.global_head = nn.Sequential(nn.Linear(features, features), nn.GELU(),
                                         nn.Linear(features, embed_dim - slots * slot_dim))
        self.slot_head = nn.Sequential(nn.Linear(2 * features, hidden), nn.GELU(), nn.Linear(hidden, slot_dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, F + K·F) → (B, D)."""
        f, k = self.features, self.slots
        whole = x[:, :f]  # (B, F)
        steps = x[:, f:].reshape(len(x), k, f)  # (B, K, F)
        per_slot = torch.cat([whole[:, None].expand(-1, k, -1), steps], dim=-1)  # (B, K, 2F)
        return torch.cat([self.global_head(whole), self.slot_head(per_slot).flatten(1)], dim=-1)  # (B, D)


class SlotReadout(nn.Module):
    """A temporal stream's clip vector and frame tokens → (B, D): global part and K time slots.

    Slot k attends over the frames with logits ``w_k · token_t − (u_t − c_k)² / (2 σ_k²)``, where
    u_t ∈ [0, 1] is the frame's place in the clip; the centres start evenly from the first frame to the
    last (c_k = k / (K − 1)) and σ_k at half a stretch's length, both learnable, so a slot can follow where
    a step really is. The ends, not the middles of the stretches: a caption's first step holds at the
    clip's first frame and its last step at the last frame whatever the steps' durations, where the
    middle of the first stretch may already show the second step (a step of one frame). With the rules'
    own per-frame tags for the video slots, a caption beats its reversed steps on more of the demo's
    test pairs with centres at the ends than at the middles of the stretches; trained, the change is
    within one seed's spread (``docs/research/action-context-heads.md``).
    """

    def __init__(self, width: int, embed_dim: int, slots: int, slot_dim: int) -> None:
        super().__init__()
        self.slots = slots
        self.global_head = nn.Linear(width, embed_dim - slots * slot_dim)
        self.score = nn.Linear(width, slots)
        self.centre = nn.Parameter(torch.linspace(0.0, 1.0, slots) if slots > 1 else torch.full((1,), 0.5))
        self.log_sigma = nn.Parameter(torch.full((slots,), math.log(0.5 / slots)))
        self.slot_head = nn.Linear(width, slot_dim)

    def attention(self, tokens: torch.Tensor) -> torch.Tensor:
        """tokens: (B, T, W) → (B, K, T) each slot's weights over the frames."""
        t = tokens.shape[1]
        u = torch.linspace(0.0, 1.0, t, device=tokens.device, dtype=tokens.dtype) if t > 1 else tokens.new_zeros(1)
        prior = -((u[None, :] - self.centre[:, None]) ** 2) / (2 * self.log_sigma.exp()[:, None] ** 2)  # (K, T)
        return F.softmax(self.score(tokens).transpose(1, 2) + prior, dim=-1)  # (B, K, T)

    def forward(self, clip: torch.Tensor, tokens: torch.Tensor) -> torch.Tensor:
        """clip: (B, W); tokens: (B, T, W) → (B, D)."""
        pooled = self.attention(tokens) @ tokens  # (B, K, W)
        return torch.cat([self.global_head(clip), self.slot_head(pooled).flatten(1)], dim=-1)  # (B, D)


def clip_head(width: int, embed_dim: int, time_slots: int, slot_dim: int) -> nn.Module:
    """A temporal stream's clip vector (and frame tokens) → (B, D): a linear map, or with ``time_slots``
    K > 0 :class:`SlotReadout` (global part + K time slots)."""
    if time_slots:
        return SlotReadout(width, embed_dim, time_slots, slot_dim)
    return nn.Linear(width, embed_dim)


def read_clip(head: nn.Module, clip: torch.Tensor, tokens: torch.Tensor) -> torch.Tensor:
    """clip: (B, W); tokens: (B, T, W) → (B, D) through a :func:`clip_head`."""
    return head(clip, tokens) if isinstance(head, SlotReadout) else head(clip)
