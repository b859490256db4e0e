"""Clip → clip figures: how alike in action a clip's nearest neighbours are, and how alike in look.

Pure functions on (N, D) L2-normalised clip embeddings and each clip's action (its unified tag
sequence as one string), appearance key (time of day, weather), log and time window, beside the analytic figures
of random neighbours and the ceiling a perfect ranking reaches. :mod:`retrieval.evaluation` reports them
for the model, its shuffled frames and the clips' own rule captions.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from encoders.metrics import ROWS_AT_ONCE


def clip_to_clip_figures(x: np.ndarray, actions: Sequence[str], appearance: Sequence[str],
                         k: int = 5, logs: Sequence[str] | None = None,
                         windows_ns: Sequence[tuple[int, int]] | None = None) -> dict[str, float | None]:
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

    Several objects are in view at once, and at one moment they share the log, its place, the ego's
    motion and the look. With ``windows_ns`` beside ``logs``, ``same_moment_share_neighbours`` /
    ``_chance`` say how often neighbours that differ in action are clips of the query's own moment (its
    log, windows that share an instant with its own), and the figures ending in ``_other_moments`` are those of each
    clip's k nearest neighbours outside its moment, against chance and the ceiling among those clips:
    what a search for *other* moments like this one (``SceneSearch.search_clip(..., other_moments=True)``)
    returns.

    Args:
        x: (N, D) L2-normalised clip embeddings.
        actions: (N,) each clip's unified tag sequence as one string.
        appearance: (N,) each clip's appearance key.
        logs: (N,) each clip's log id.
        windows_ns: (N,) each clip's first and last timestamps, ns; needs ``logs``.

    Raises:
        ValueError: fewer than 2 clips, or ``windows_ns`` without ``logs``.
    """
    x = np.asarray(x, dtype=np.float32)
    n = len(x)
    if n < 2:
        raise ValueError(f"clip → clip needs at least 2 clips, got {n}")
    act, app = _keys(actions), _keys(appearance)
    k = min(k, n - 1)
    sim = x @ x.T
    np.fill_diagonal(sim, -np.inf)
    # Equal scores (clips with the same caption, under rule captions) are ranked in a seeded random
    # order: table order would favour whichever log comes first.
    tiebreak = np.random.default_rng(0).random(n)
    nn = _nearest(sim, tiebreak, k)
    figures = _neighbour_figures(nn, act, app, k)
    figures[f"action_precision@{k}_ceiling"] = action_precision_ceiling(act, k)
    for name, same in _groups(logs, windows_ns).items():
        figures[f"same_{name}_share_neighbours"] = _pair_share(nn, act, same)
        figures[f"same_{name}_share_chance"] = _pair_chance(act, same)
        figures.update(_figures_among(sim, tiebreak, act, app, ~same, k, f"_other_{name}s"))
        if name == "moment":
            figures[f"action_precision@{k}_ceiling_other_moments"] = action_precision_ceiling(act, k, among=~same)
    return figures


def action_precision_ceiling(actions: Sequence[str] | np.ndarray, k: int = 5, among: np.ndarray | None = None) -> float:
    """The action precision@k of a perfect ranking: a clip whose action n − 1 other clips share finds at
    most min(k, n − 1) of them among its k neighbours, so where many actions occur once, even a perfect
    embedding stays far below 1 (the figure to read ``action_precision@k`` against). ``among`` (N, N)
    bool: the clips each clip may take as neighbours (default all others); a clip with fewer than k
    of them has fewer neighbours, pooled as the precision pools them."""
    act = _keys(actions)
    n = len(act)
    if min(k, n - 1) <= 0:
        return 0.0
    among = (np.ones((n, n), dtype=bool) if among is None else among) & ~np.eye(n, dtype=bool)
    candidates = np.minimum(k, among.sum(axis=1))  # (N,) neighbours each clip has
    peers = np.minimum(candidates, ((act[:, None] == act[None, :]) & among).sum(axis=1))  # (N,)
    return float(peers.sum() / candidates.sum()) if candidates.sum() else 0.0


def perfect_ranking_figures(actions: Sequence[str], egos: Sequence[str], appearance: Sequence[str], k: int = 5,
                            logs: Sequence[str] | None = None,
                            windows_ns: Sequence[tuple[int, int]] | None = None) -> dict[str, float | None]:
    """The appearance biases of a perfect ranking by what the captions say, keys ending in
    ``_perfect_ranking``: each clip's neighbours are the clips of its action (the object's unified tags)
    and the ego's motion (``egos``, the ego's unified tags as one string), then of its action, then of
    the ego's motion, then the rest, ties in a seeded random order. A caption opens with the ego's motion,
    so a model that reads it well ranks so; where the ego's motion is the log's, the bias of this ranking
    is what the captions' content alone gives, the figure to read ``appearance_bias`` against."""
    act, ego = _keys(actions), _keys(egos)
    one_hot = [np.unique(key, return_inverse=True)[1] for key in (act, ego)]
    # Same action and ego: 1; same action: 0.8; same ego: 0.2; neither: 0 (cosines of the rows below).
    x = np.hstack([np.eye(one_hot[0].max() + 1)[one_hot[0]], 0.5 * np.eye(one_hot[1].max() + 1)[one_hot[1]]])
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    figures = clip_to_clip_figures(x, act.tolist(), appearance, k, logs, windows_ns)
    return {f"{key}_perfect_ranking": value for key, value in figures.items() if key.startswith("appearance_bias")}


def same_moment(logs: Sequence[str], windows_ns: Sequence[tuple[int, int]]) -> np.ndarray:
    """(N, N) bool: clips of the same log whose windows share an instant (a window runs from its first
    timestamp to its last, both included, as ``start_ns`` and ``end_ns`` of a clip do), the diagonal True."""
    log = _keys(logs)
    window = np.asarray(list(windows_ns), dtype=np.int64).reshape(len(log), 2)  # (N, 2)
    start, end = window[:, 0], window[:, 1]
    overlap = (start[:, None] <= end[None, :]) & (start[None, :] <= end[:, None])
    return (log[:, None] == log[None, :]) & (overlap | np.eye(len(log), dtype=bool))


def _groups(logs: Sequence[str] | None, windows_ns: Sequence[tuple[int, int]] | None) -> dict[str, np.ndarray]:
    """The (N, N) bool "same" matrices the figures are split by: ``log`` with ``logs``, ``moment`` with
    ``windows_ns`` too."""
    if logs is None:
        if windows_ns is not None:
            raise ValueError("clip → clip: windows_ns needs logs (a moment is a time window in one log)")
        return {}
    groups = {"log": _same_key(_keys(logs))}
    if windows_ns is not None:
        groups["moment"] = same_moment(logs, windows_ns)
    return groups


def _figures_among(sim: np.ndarray, tiebreak: np.ndarray, act: np.ndarray, app: np.ndarray,
                   among: np.ndarray, k: int, suffix: str) -> dict[str, float | None]:
    """:func:`_neighbour_figures` of each clip's k nearest neighbours within its row of ``among``, against
    chance among the same pairs; keys end in ``suffix``.

    Args:
        sim: (N, N) clip × clip scores, the diagonal −inf.
        tiebreak: (N,) secondary sort key for equal scores.
        among: (N, N) bool, the clips each clip may take as neighbours.
    """
    among = among & ~np.eye(len(among), dtype=bool)
    nn = _nearest(sim, tiebreak, k, among)  # (N, k)
    valid = np.take_along_axis(among, nn, axis=1)  # False where a clip has fewer than k candidates
    figures = _neighbour_figures(nn, act, app, k, valid=valid, among=among)
    return {f"{key}{suffix}": value for key, value in figures.items()}


def _nearest(sim: np.ndarray, tiebreak: np.ndarray, k: int, among: np.ndarray | None = None) -> np.ndarray:
    """(N, k) each clip's k best columns of ``sim`` (N, N), by score, then by ``tiebreak`` (N,) for
    equal scores; with ``among`` (N, N) bool, the columns outside it rank last. Sorted by
    :data:`encoders.metrics.ROWS_AT_ONCE` rows at a time, since a whole sort's (N, N) indices and copies
    would not fit in memory for a large split (docs/research/eval-memory.md)."""
    nn = np.empty((len(sim), k), dtype=np.int64)
    for start in range(0, len(sim), ROWS_AT_ONCE):
        rows = sim[start:start + ROWS_AT_ONCE]
        if among is not None:
            rows = np.where(among[start:start + ROWS_AT_ONCE], rows, -np.inf)
        nn[start:start + ROWS_AT_ONCE] = np.lexsort((np.broadcast_to(tiebreak, rows.shape), -rows), axis=1)[:, :k]
    return nn


def random_clip_to_clip(actions: Sequence[str], appearance: Sequence[str], k: int = 5,
                        logs: Sequence[str] | None = None,
                        windows_ns: Sequence[tuple[int, int]] | None = None) -> dict[str, float | None]:
    """Expected clip → clip figures of random neighbours (analytic); with ``logs``, also among other
    logs' clips, and with ``windows_ns`` too, among other moments' clips. A bias is None where the
    clips have one appearance, as the model's is."""
    act, app = _keys(actions), _keys(appearance)
    n = len(act)
    same_action = act[:, None] == act[None, :]
    same_look = _same_key(app)
    precision = _random_precision(same_action, ~np.eye(n, dtype=bool))
    has_variety = len(set(app.tolist())) > 1
    chance = _pair_chance(act, same_look)
    figures: dict[str, float | None] = {
        f"action_precision@{k}": precision, "appearance_bias": 1.0 if has_variety else None,
        "appearance_share_neighbours": chance, "appearance_share_chance": chance}
    for name, same in _groups(logs, windows_ns).items():
        figures[f"action_precision@{k}_other_{name}s"] = _random_precision(same_action, ~same)
        defined = has_variety and _pair_chance(act, same_look, ~same)
        figures[f"appearance_bias_other_{name}s"] = 1.0 if defined else None
    return figures


def _random_precision(same_action: np.ndarray, among: np.ndarray) -> float | None:
    """Mean over clips of the chance that a neighbour drawn at random from its row of ``among``
    (N, N) bool shares its action (``same_action``, (N, N) bool); None when no row has a candidate."""
    count = among.sum(axis=1)
    has = count > 0
    return float(np.mean((same_action & among).sum(axis=1)[has] / count[has])) if has.any() else None


def _neighbour_figures(nn: np.ndarray, act: np.ndarray, app: np.ndarray, k: int,
                       valid: np.ndarray | None = None, among: np.ndarray | None = None) -> dict[str, float | None]:
    """Action precision and appearance bias of neighbours ``nn`` (N, k) of clips whose actions and
    appearances are ``act`` and ``app`` ((N,) each).

    ``valid`` (N, k) marks the neighbours that count (default all); ``among`` (N, N) the pairs chance
    is taken over (default all).
    """
    valid = np.ones(nn.shape, dtype=bool) if valid is None else valid
    same_action = act[nn] == act[:, None]
    precision = float(np.mean(same_action[valid])) if valid.any() else None
    same_look = _same_key(app)
    share = _pair_share(nn, act, same_look, valid)
    chance = _pair_chance(act, same_look, among)
    bias = None
    if share is not None and chance and len(set(app.tolist())) > 1:
        bias = share / chance
    return {f"action_precision@{k}": precision, "appearance_bias": bias,
            "appearance_share_neighbours": share, "appearance_share_chance": chance}


def _keys(values: Sequence[str] | np.ndarray) -> np.ndarray:
    """(N,) object array of a sequence of keys, read once (the callers' sequences may be iterators)."""
    return np.asarray(list(values), dtype=object)


def _same_key(key: np.ndarray) -> np.ndarray:
    """(N, N) bool: the pairs of ``key`` (N,) that share a key."""
    return key[:, None] == key[None, :]


def _pair_share(nn: np.ndarray, act: np.ndarray, shared: np.ndarray,
                valid: np.ndarray | None = None) -> float | None:
    """Share of the neighbours ``nn`` (N, k) that differ from their query in action (``act``, (N,)) and
    are ``valid`` ((N, k) bool) to which ``shared`` (N, N) bool holds; None when no neighbour differs."""
    differ = act[nn] != act[:, None]
    if valid is not None:
        differ &= valid
    return float(np.mean(np.take_along_axis(shared, nn, axis=1)[differ])) if differ.any() else None


def _pair_chance(act: np.ndarray, shared: np.ndarray, among: np.ndarray | None = None) -> float | None:
    """Share of clip pairs that differ in action (``act``, (N,); within ``among``, (N, N) bool) to which
    ``shared`` (N, N) bool holds; None when no such pair."""
    differ = ~_same_key(act)
    if among is not None:
        differ &= among
    return float(shared[differ].mean()) if differ.any() else None
