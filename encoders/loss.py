"""Symmetric InfoNCE with multiple positives.

Rule captions repeat: two clips with the same canonical caption are positives for each other, not
negatives. With ``P`` (B, B) the positives (``P_ii`` true) and ``s_i = scale · v_i · T^T`` the logits
of clip i against all captions of the batch:

    loss_v2t = mean_i −log Σ_{j ∈ P_i} softmax(s_i)_j

The loss puts the softmax mass on the set of positives (it does not force equal mass on each, which is
right for identical captions). It is the mean of the clip→text and text→clip terms.

Hard negatives (``negatives`` (M, D), e.g. captions of a clip's steps reversed: :mod:`encoders.negatives`)
join the clip→text side as M more columns of every row; the text→clip side and the targets over the
batch stay as they are. A negative whose key equals clip i's (``negative_positives[i, j]``) is a
positive of clip i there.

:func:`order_loss` asks for the order itself, pair by pair: each clip closer to its caption than to
its caption's steps reversed, as the temporal-order evaluation tests.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import torch
import torch.nn.functional as F


def positives_matrix(keys: Sequence[Hashable], device: torch.device | None = None) -> torch.Tensor:
    """keys: B hashable (canonical captions) → (B, B) bool, true where keys are equal."""
    index: dict[Hashable, int] = {}
    ids = torch.tensor([index.setdefault(k, len(index)) for k in keys], device=device)  # (B,)
    return ids[:, None] == ids[None, :]


def row_losses(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The loss of each row of ``logits`` (R, C) against its bool positives ``target`` (R, C): −log of
    the softmax mass on them → (R,)."""
    # −log Σ_{j∈P_i} softmax(s_i)_j = logsumexp(s_i) − logsumexp(s_i over P_i)
    return torch.logsumexp(logits, dim=1) - torch.logsumexp(logits.masked_fill(~target, float("-inf")), dim=1)


def contrastive_loss(
    video: torch.Tensor,
    text: torch.Tensor,
    scale: torch.Tensor,
    positives: torch.Tensor,
    negatives: torch.Tensor | None = None,
    negative_positives: torch.Tensor | None = None,
    rows: slice | torch.Tensor | None = None,
) -> torch.Tensor:
    """video: (B, D), text: (B, D) normalised; scale: () ; positives: (B, B) bool → scalar loss.

    ``negatives`` (M, D) normalised are extra captions for the clip→text side; ``negative_positives``
    (B, M) bool marks the ones equal to a clip's own caption (default: none). ``rows`` (default all; a
    slice or an index tensor): the mean is over these clips' and captions' terms only, each still against
    every column; with the batch gathered from several processes (:mod:`encoders.distributed`) each
    takes its own rows, and the mean of their losses is the loss of the whole batch.
    """
    mine = slice(None) if rows is None else rows
    clips = video if rows is None else video[rows]  # (B or b, D)
    logits = scale * clips.float() @ text.float().T  # (B or b, B) clip i vs caption j
    target = positives.to(logits.device)  # (B, B), symmetric: the same targets serve both directions

    def side(s: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return row_losses(s, t).mean()
    v2t_logits, v2t_target = logits, target[mine]
    if negatives is not None and len(negatives):
        own = (torch.zeros(len(video), len(negatives), dtype=torch.bool) if negative_positives is None
               else negative_positives).to(logits.device)  # (B, M)
        v2t_logits = torch.cat([logits, scale * clips.float() @ negatives.float().T], dim=1)  # (B, B + M)
        v2t_target = torch.cat([target[mine], own[mine].to(target.dtype)], dim=1)
    v2t = side(v2t_logits, v2t_target)
    # Built after the clip → text side: the gradient sums in one fixed order.
    t2v_logits = logits.T if rows is None else scale * text[rows].float() @ video.float().T  # caption i vs clip j
    return 0.5 * (v2t + side(t2v_logits, target.T[mine]))


def view_loss(view: torch.Tensor, text: torch.Tensor, scale: torch.Tensor, positives: torch.Tensor,
              keep: torch.Tensor, rows: slice | None, processes: int, negatives: torch.Tensor | None = None,
              own: torch.Tensor | None = None, move_text: bool = True) -> torch.Tensor:
    """The contrastive loss of one view alone over the whole batch's clips where ``keep`` holds.

    view: (N, D) the whole batch's clip vectors of the view; text: (N, D) their captions; positives:
    (N, N); keep: (N,) bool; negatives: (M, D); own: (N, M). ``rows``: this process's
    rows of the whole batch (None on one process) out of ``processes``. Each process takes the mean
    over its own kept clips, rescaled by its share of them, so that the mean over processes is the
    loss of the whole batch, as for the fused view. 0 (with a graph) when fewer than 2 clips are kept.
    ``move_text`` False: the captions' side (text, negatives, scale) passes no gradient, so the view
    meets the captions where the other views put them (``TrainConfig.camera_apart``).
    """
    zero = view.sum() * 0.0  # every process's loss reaches every parameter of the view, as in one process
    if not move_text:
        text, scale = text.detach(), scale.detach()
        negatives = None if negatives is None else negatives.detach()
    index = torch.nonzero(keep).reshape(-1)  # (K,) kept rows of the whole batch
    if len(index) < 2:
        return zero
    mine: torch.Tensor | None = None
    share = 1.0
    if rows is not None:
        mine = torch.nonzero((index >= rows.start) & (index < rows.stop)).reshape(-1)  # my rows among the kept
        if len(mine) == 0:
            return zero
        share = len(mine) * processes / len(index)
    loss = contrastive_loss(view[index], text[index], scale, positives[index][:, index], negatives,
                            None if own is None else own[index], rows=mine)
    return share * loss + zero


def order_loss(
    video: torch.Tensor, text: torch.Tensor, negatives: torch.Tensor, reversed_of: Sequence[int] | torch.Tensor,
    scale: torch.Tensor, rows: slice | None = None,
) -> torch.Tensor:
    """Each clip against its caption's steps reversed: mean over pairs of softplus(−scale · (v·t − v·t_rev)).

    In the contrastive loss a clip's reversed caption is one column among the batch's, and its pull
    fades as soon as the softmax mass sits on the positives; on the demo the trained model then left
    some of its own training pairs out of order (``docs/research/order-loss.md``). This term keeps
    pushing each pair apart.

    video, text: (B, D) the whole batch's clips and captions, normalised; negatives: (M, D);
    reversed_of: (M,) the clip whose steps negative m reverses (−1: another edit; a reversal
    never renders as its clip's own caption, :func:`encoders.negatives.hard_negatives` drops those).
    ``rows``: this process's rows of the whole batch; its pairs' sum is divided by the whole batch's
    pair count, so that the processes' losses sum to the whole batch's. 0 (with a graph) without pairs.
    """
    owners = torch.as_tensor(reversed_of, dtype=torch.long, device=video.device)  # (M,)
    m = torch.nonzero(owners >= 0).reshape(-1)  # (P,) negatives that reverse a clip's steps
    clip = owners[m]
    total = len(m)
    if rows is not None:
        mine = (clip >= (rows.start or 0)) & (clip < rows.stop)
        m, clip = m[mine], clip[mine]
    if len(m) == 0:
        return video.sum() * 0.0
    v = video[clip].float()  # (P, D)
    margin = (v * text[clip].float()).sum(-1) - (v * negatives[m].float()).sum(-1)  # (P,)
    return F.softplus(-scale * margin).sum() / total


def partial_query_loss(video: torch.Tensor, partial: torch.Tensor, scale: torch.Tensor,
                       positives: torch.Tensor) -> torch.Tensor:
    """The batch's clips against the halves of their captions (:mod:`encoders.partial_queries`).

    video: (B, D) the whole batch's clips, normalised; partial: (M, D) the whole batch's halves,
    normalised; positives: (B, M) bool, clip i answers half m. Symmetric as :func:`contrastive_loss`:
    each half against the batch's clips (the retrieval a typed half asks for) and each clip against the
    halves, over the clips that answer one (ego clips have no half). Every process computes the whole
    batch's loss: gathered rows pass their gradients back summed over processes, which the gradients'
    average over processes undoes. 0 (with a graph) without halves.
    """
    if partial.shape[0] == 0:
        return video.sum() * 0.0
    logits = scale * video.float() @ partial.float().T  # (B, M) clip i vs half m
    pos = positives.to(device=logits.device, dtype=torch.bool)
    answered = pos.any(dim=1)  # (B,) clips that answer some half
    clip_side = row_losses(logits[answered], pos[answered]).mean()
    half_side = row_losses(logits.T, pos.T).mean()
    return 0.5 * (clip_side + half_side)
