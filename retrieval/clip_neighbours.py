"""Clip → clip figures: how alike in action a clip's nearest neighbours are, and how alike in look.

Pure functions on (N, D) L2-normalised clip embeddings and each clip's action (its unified tag
sequence as one string), appearance key (time of day, weather) and log, beside the analytic figures
of random neighbours and the ceiling a perfect ranking reaches. :mod:`retrieval.evaluation` reports them
for the model, its shuffled frames and the clips' own rule captions.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

import numpy as np


def clip_to_clip_figures(x: np.ndarray, actions: Sequence[str], appearance: Sequence[str],
                         k: int = 5, logs: Sequence[str] | None = None) -> dict[str, float | None]:
    """Action precision@k of each clip's nearest neighbours, and how appearance biases them.

    ``appearance_bias`` is the rate at which neighbours that differ in action share the query's
    appearance (time of day, weather), divided by that rate among all clips that differ in action:
    1 means neighbours are no more alike in appearance than chance, lower is better. None when no
    clip differs from another in appearance. Appearance is drawn per log, so where a split's logs
    each have their own, sharing appearance is sharing the log, with its place, traffic and ego
    motion: ``same_log_share_neighbours`` / ``_chance`` (with ``logs``) say how often neighbours
    that differ in action come from the query's own log, against all such clips. The look apart from
    the log is measured among other logs' clips only: ``action_precision@k_other_logs`` and
    ``appearance_bias_other_logs`` are the same figures for each clip's k nearest neighbours from other
    logs, against chance among other logs' clips (None where no two logs share an appearance).

    Args:
        x: (N, D) L2-normalised clip embeddings.
        actions: (N,) each clip's unified tag sequence as one string.
        appearance: (N,) each clip's appearance key.
        logs: (N,) each clip's log id.
    """
    x = np.asarray(x, dtype=np.float32)
    n = len(x)
    if n < 2:
        raise ValueError(f"clip → clip needs at least 2 clips, got {n}")
    k = min(k, n - 1)
    sim = x @ x.T
    np.fill_diagonal(sim, -np.inf)
    # Equal scores (clips with the same caption, under rule captions) are ranked in a seeded random
    # order: table order would favour whichever log comes first.
    tiebreak = np.broadcast_to(np.random.default_rng(0).random(n), sim.shape)
    nn = np.lexsort((tiebreak, -sim), axis=1)[:, :k]
    figures = _neighbour_figures(nn, actions, appearance, k)
    figures[f"action_precision@{k}_ceiling"] = action_precision_ceiling(actions, k)
    if logs is not None:
        same_log = _neighbour_figures(nn, actions, logs, k)
        figures["same_log_share_neighbours"] = same_log["appearance_share_neighbours"]
        figures["same_log_share_chance"] = same_log["appearance_share_chance"]
        figures.update(_other_log_figures(sim, tiebreak, actions, appearance, logs, k))
    return figures


def action_precision_ceiling(actions: Sequence[str], k: int = 5) -> float:
    """The action precision@k of a perfect ranking: a clip whose action n − 1 other clips share finds at
    most min(k, n − 1) of them among its k neighbours, so where many actions occur once, even a perfect
    embedding stays far below 1 (the figure to read ``action_precision@k`` against)."""
    counts = Counter(actions)
    k = min(k, len(actions) - 1)
    return float(np.mean([min(k, counts[a] - 1) / k for a in actions])) if k > 0 else 0.0


def _other_log_figures(sim: np.ndarray, tiebreak: np.ndarray, actions: Sequence[str], appearance: Sequence[str],
                       logs: Sequence[str], k: int) -> dict[str, float | None]:
    """:func:`_neighbour_figures` of each clip's k nearest neighbours from other logs, against chance
    among other logs' clips; keys end in ``_other_logs``.

    Args:
        sim: (N, N) clip × clip scores, the diagonal −inf.
        tiebreak: (N, N) secondary sort key for equal scores.
    """
    log = np.asarray(list(logs), dtype=object)
    other = log[:, None] != log[None, :]  # (N, N)
    nn = np.lexsort((tiebreak, -np.where(other, sim, -np.inf)), axis=1)[:, :k]  # (N, k)
    valid = np.take_along_axis(other, nn, axis=1)  # False where a clip has fewer than k other-log clips
    figures = _neighbour_figures(nn, actions, appearance, k, valid=valid, among=other)
    return {f"{key}_other_logs": value for key, value in figures.items()}


def random_clip_to_clip(actions: Sequence[str], appearance: Sequence[str], k: int = 5,
                        logs: Sequence[str] | None = None) -> dict[str, float | None]:
    """Expected clip → clip figures of random neighbours (analytic); with ``logs``, also among other
    logs' clips."""
    act = np.asarray(list(actions), dtype=object)
    app = np.asarray(list(appearance), dtype=object)
    n = len(act)
    same_action = act[:, None] == act[None, :]
    precision = _random_precision(same_action, ~np.eye(n, dtype=bool))
    has_variety = len(set(app.tolist())) > 1
    chance = _chance_appearance_rate(act, app)
    figures: dict[str, float | None] = {
        f"action_precision@{k}": precision, "appearance_bias": 1.0 if has_variety else None,
        "appearance_share_neighbours": chance, "appearance_share_chance": chance}
    if logs is not None:
        log = np.asarray(list(logs), dtype=object)
        other = log[:, None] != log[None, :]
        figures[f"action_precision@{k}_other_logs"] = _random_precision(same_action, other)
        chance_other = _chance_appearance_rate(act, app, among=other)
        figures["appearance_bias_other_logs"] = 1.0 if chance_other else None
    return figures


def _random_precision(same_action: np.ndarray, among: np.ndarray) -> float | None:
    """Mean over clips of the chance that a neighbour drawn at random from its row of ``among``
    (N, N) bool shares its action (``same_action``, (N, N) bool); None when no row has a candidate."""
    count = among.sum(axis=1)
    has = count > 0
    return float(np.mean((same_action & among).sum(axis=1)[has] / count[has])) if has.any() else None


def _neighbour_figures(nn: np.ndarray, actions: Sequence[str], appearance: Sequence[str], k: int,
                       valid: np.ndarray | None = None, among: np.ndarray | None = None) -> dict[str, float | None]:
    """Action precision and appearance bias of neighbours ``nn`` (N, k).

    ``valid`` (N, k) marks the neighbours that count (default all); ``among`` (N, N) the pairs chance
    is taken over (default all).
    """
    act = np.asarray(list(actions), dtype=object)
    app = np.asarray(list(appearance), dtype=object)
    valid = np.ones(nn.shape, dtype=bool) if valid is None else valid
    same_action = act[nn] == act[:, None]
    precision = float(np.mean(same_action[valid])) if valid.any() else None
    differ = valid & ~same_action
    share = float(np.mean((app[nn] == app[:, None])[differ])) if differ.any() else None
    chance = _chance_appearance_rate(act, app, among)
    bias = None
    if share is not None and chance is not None and chance > 0 and len(set(app.tolist())) > 1:
        bias = share / chance
    return {f"action_precision@{k}": precision, "appearance_bias": bias,
            "appearance_share_neighbours": share, "appearance_share_chance": chance}


def _chance_appearance_rate(act: np.ndarray, app: np.ndarray, among: np.ndarray | None = None) -> float | None:
    """Share of clip pairs that differ in action (within ``among``, (N, N) bool) sharing an appearance."""
    differ = act[:, None] != act[None, :]
    if among is not None:
        differ &= among
    if not differ.any():
        return None
    same_app = app[:, None] == app[None, :]
    return float(same_app[differ].mean())
