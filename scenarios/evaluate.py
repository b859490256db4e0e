"""Running a program on one log's features: every node becomes a selection over objects × frames.

A :class:`Selection` holds (K, F) scores (0 where an object is not selected at a frame) and (K, F)
related flags (the objects the selected ones relate to). Nodes combine them with array operations
only; relations look at subject × other × frame blocks, restricted to the objects their two sides
select anywhere in the log (so "vehicle with a bicycle to its right" compares vehicles with bicycles,
not every pair), in chunks of bounded size. Durations are seconds on the log's own timestamps, so a
program means the same at 10 Hz and at 2 Hz.

A predicate or relation that needs what a log lacks (a map; recorded lighting or weather) selects
nothing there and adds a note saying so (:attr:`Evaluation.notes`): "no answer" is never reported as
"false" silently.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from scenarios import program as p
from scenarios.answer import LogAnswer
from scenarios.features import LogFeatures
from scenarios.kinds import KIND_NAMES, kind_mask
from scenarios.predicates import PREDICATES, Mask, ProgramError, unanswerable
from scenarios.relations import RELATIONS, candidate_pairs, group_any, group_count, in_direction, pair_geometry
from scenarios.timing import (
    chained,
    followed_within,
    onsets,
    preceded_within,
    reached_in_order,
    runs_holding,
    runs_lasting,
)
from scenes.categories import AV2_TO_CATEGORY, EGO_VEHICLE_LABEL

#: Subject × other × frame cells a relation compares at once.
_CHUNK_CELLS = 2_000_000


@dataclass(frozen=True)
class Selection:
    """Objects × frames selected by a node.

    Attributes:
        scores: (K, F) float32, > 0 where selected.
        related: (K, F) bool, objects related to selected ones.
    """

    scores: NDArray[np.float32]
    related: Mask

    @property
    def mask(self) -> Mask:
        return np.asarray(self.scores > 0)


@dataclass
class Evaluation:
    """A program's selection on one log, and what it could not answer there.

    Attributes:
        selection: the objects × frames the program selects.
        notes: what the log could not answer.
        events: (K, F) for a sequence (``then``, also under filters), the frames where it happens: its
            last step begins after the steps before it ("drives off": where it moves); None otherwise,
            and unless asked for.
    """

    selection: Selection
    notes: list[str] = field(default_factory=list)
    events: Mask | None = None


def _any(mask: Mask, axis: int) -> Mask:
    return np.asarray(mask.any(axis=axis), dtype=bool)


def _empty(x: LogFeatures) -> Selection:
    shape = (x.num_objects, x.num_frames)
    return Selection(np.zeros(shape, np.float32), np.zeros(shape, bool))


def _keep(sel: Selection, mask: Mask) -> Selection:
    """``sel`` where ``mask`` holds; related objects only at frames where something stays selected."""
    scores = np.where(mask, sel.scores, 0.0).astype(np.float32)
    return Selection(scores, sel.related & _any(scores > 0, 0)[None, :])


class _Run:
    """One evaluation: the log's features and the notes gathered on the way."""

    def __init__(self, x: LogFeatures) -> None:
        self.x = x
        self.notes: list[str] = []
        self._selections: dict[p.Node, Selection] = {}

    def note(self, name: str, reason: str) -> None:
        note = f"{self.x.log_id}: '{name}' {reason}: no answer there (not 'false')"
        if note not in self.notes:
            self.notes.append(note)

    def eval(self, node: p.Node) -> Selection:
        """``node``'s selection, each distinct node evaluated once per run: a sequence's steps are read
        again where it begins (:meth:`starts`), and a program may name one subtree twice ("stopped(car)",
        then "moving(car)"). No step writes into a selection it was given, so they can be shared."""
        done = self._selections.get(node)
        if done is None:
            done = self._selections[node] = self._evaluate(node)
        return done

    def _evaluate(self, node: p.Node) -> Selection:
        x = self.x
        match node:
            case p.Objects(kind):
                if kind not in KIND_NAMES:
                    raise ProgramError(f"unknown kind {kind!r} (known: {', '.join(KIND_NAMES)})")
                mask = kind_mask(kind, x.labels, x.categories)[:, None] & x.valid
                return Selection(mask.astype(np.float32), np.zeros_like(mask))
            case p.Is(subject, predicate, params, negate):
                spec = PREDICATES.get(predicate)
                if spec is None:
                    raise ProgramError(f"unknown predicate {predicate!r} (known: {', '.join(sorted(PREDICATES))})")
                resolved = spec.resolve(dict(params))
                sel = self.eval(subject)
                reason = unanswerable(spec, x, resolved)
                if reason is not None:
                    self.note(predicate, reason)
                    return _empty(x)
                holds = spec.fn(x, resolved)
                return _keep(sel, ~holds & x.valid if negate else holds)
            case p.Has():
                return self.relation(node)
            case p.Between(subject, left, right, lateral_m):
                return self.between(self.eval(subject), self.eval(left), self.eval(right), lateral_m)
            case p.AllOf(children):
                parts = [self.eval(c) for c in children]
                scores = np.minimum.reduce([part.scores for part in parts])
                related = np.logical_or.reduce([part.related for part in parts]) & _any(scores > 0, 0)[None]
                return Selection(scores, related)
            case p.AnyOf(children):
                parts = [self.eval(c) for c in children]
                return Selection(np.maximum.reduce([part.scores for part in parts]),
                                 np.logical_or.reduce([part.related for part in parts]))
            case p.Excluding(base, excluded):
                return _keep(self.eval(base), ~self.eval(excluded).mask)
            case p.Together(child, min_count):
                sel = self.eval(child)
                return _keep(sel, np.broadcast_to((sel.mask.sum(axis=0) >= min_count)[None], sel.scores.shape))
            case p.ForAtLeast(child, seconds):
                sel = self.eval(child)
                return _keep(sel, runs_lasting(sel.mask, x.time_s, seconds))
            case p.Then():
                steps, gaps_s = p.chain_steps(node)
                parts = [self.eval(step) for step in steps]
                keep = chained([part.mask for part in parts], gaps_s, x.time_s)
                scores = np.maximum.reduce([part.scores for part in parts])
                related = np.logical_or.reduce([part.related for part in parts])
                return Selection(np.where(keep, scores, 0.0).astype(np.float32), related & _any(keep, 0)[None])
            case p.While(child, condition):
                sel, cond = self.eval(child), self.eval(condition)
                when = _any(cond.mask, 0)[None, :]
                kept = _keep(sel, np.broadcast_to(when, sel.scores.shape))
                return Selection(kept.scores, kept.related | (cond.mask & _any(kept.mask, 0)[None]))
            case p.Sequenced(child, event, within_s, after):
                return self.sequenced(child, event, within_s, after)
        raise ProgramError(f"not a program node: {node!r}")

    def starts(self, node: p.Node, sel: Selection) -> Mask:
        """(K, F) the frames where what ``node`` selects begins: the first frame of each run seen to begin
        (the frame before it observed: a state held since an object came into view has no beginning), and
        for a sequence (``then``, also under filters such as ``while``) where its last step begins after the
        steps before it ("drives off": where it moves)."""
        begins = onsets(sel.mask) & np.pad(self.x.valid, ((0, 0), (1, 0)))[:, :-1]
        chain = p.chain_under(node)
        if chain is None:
            return begins
        steps, gaps_s = chain
        masks = [self.eval(step).mask for step in steps]
        moves = onsets(masks[-1]) & reached_in_order(masks, gaps_s, self.x.time_s)[-1] & sel.mask
        return moves | (begins & ~runs_holding(sel.mask, moves))

    def sequenced(self, child: p.Node, event: p.Node, within_s: float, after: bool) -> Selection:
        """``child``'s runs that begin at most ``within_s`` before (``after``: after) some object's ``event``
        begins, not at the same frame; the event's runs that begin so are related. Beginnings, not every
        frame: "a car stops, then a pedestrian crosses" is not a pedestrian crossing all along."""
        x = self.x
        sel, ev = self.eval(child), self.eval(event)
        sel_starts, ev_starts = self.starts(child, sel), self.starts(event, ev)
        toward_event, toward_child = (preceded_within, followed_within) if after else (followed_within, preceded_within)
        kept_starts = toward_event(sel_starts, _any(ev_starts, 0), x.time_s, within_s)
        kept = _keep(sel, runs_holding(sel.mask, kept_starts))
        related = runs_holding(ev.mask, toward_child(ev_starts, _any(kept_starts, 0), x.time_s, within_s))
        return Selection(kept.scores, kept.related | related)

    def relation(self, node: p.Has) -> Selection:
        x = self.x
        spec = RELATIONS.get(node.relation)
        if spec is None:
            raise ProgramError(f"unknown relation {node.relation!r} (known: {', '.join(sorted(RELATIONS))})")
        resolved = spec.resolve(dict(node.params))
        if node.min_count < 1 or (node.max_count is not None and node.max_count < node.min_count):
            raise ProgramError(f"{node.relation}: min_count must be ≥ 1 and max_count ≥ min_count")
        if node.nearest is not None and not 1 <= node.min_count <= node.nearest:
            raise ProgramError(f"{node.relation}: nearest must be ≥ 1 and ≥ min_count")
        sel, other = self.eval(node.subject), self.eval(node.other)
        if spec.needs_map and not x.has_map:
            self.note(node.relation, "needs a map, and the log has none")
            return _empty(x)
        subjects = np.flatnonzero(sel.mask.any(axis=1))
        others = np.flatnonzero(other.mask.any(axis=1))
        k, f = x.num_objects, x.num_frames
        count = np.zeros((k, f), np.int64)  # of the subjects: how many others relate at each frame
        holds_parts, s_parts, o_parts, gap_parts = [], [], [], []
        if subjects.size and others.size:
            s_idx, o_idx = candidate_pairs(x, subjects, others, spec.reach_m(resolved))
            step = max(1, _CHUNK_CELLS // max(1, f))
            for start in range(0, s_idx.size, step):
                si, oi = s_idx[start:start + step], o_idx[start:start + step]
                geometry = pair_geometry(x, si, oi)
                holds = spec.fn(geometry, resolved) & other.mask[oi] & sel.mask[si]  # (P, F)
                count += group_count(holds, si, k)
                holds_parts.append(holds)
                s_parts.append(si)
                o_parts.append(oi)
                if node.nearest is not None:
                    gap_parts.append(geometry.gap_m)
        if node.nearest is not None and holds_parts:
            # A subject's pairs may straddle chunks: the nearest are ranked over all of them at once.
            holds_parts = [nearest_only(np.concatenate(holds_parts), np.concatenate(gap_parts),
                                        np.concatenate(s_parts), node.nearest)]
            s_parts, o_parts = [np.concatenate(s_parts)], [np.concatenate(o_parts)]
            count = group_count(holds_parts[0], s_parts[0], k)
        if node.negate:
            ok_subject = (count == 0) & sel.mask
        else:
            ok_subject = count >= node.min_count
            if node.max_count is not None:
                ok_subject &= count <= node.max_count
        related = np.zeros((k, f), bool)  # of the others, where they relate to a kept subject
        reverse_related = np.zeros((k, f), bool)  # of the subjects, where they relate to a kept other
        if not node.negate and holds_parts:
            holds, si, oi = np.concatenate(holds_parts), np.concatenate(s_parts), np.concatenate(o_parts)
            kept = holds & ok_subject[si]
            related = group_any(kept, oi, k)
            reverse_related = group_any(kept, si, k)
        if node.reverse:
            if node.negate:
                raise ProgramError(f"{node.relation}: reverse() of a negated relation names no object")
            return Selection(np.where(related, other.scores, 0.0).astype(np.float32), reverse_related)
        kept_sel = _keep(sel, ok_subject)
        return Selection(kept_sel.scores, kept_sel.related | (related & ~kept_sel.mask))

    def between(self, sel: Selection, left: Selection, right: Selection, lateral_m: float) -> Selection:
        x = self.x
        subjects = np.flatnonzero(sel.mask.any(axis=1))
        both = np.zeros((x.num_objects, x.num_frames), bool)
        related = np.zeros_like(both)
        for first, second in ((left, right), (right, left)):  # either kind may be on either side
            lo, hi = np.flatnonzero(first.mask.any(axis=1)), np.flatnonzero(second.mask.any(axis=1))
            if not (subjects.size and lo.size and hi.size):
                continue
            reach = 50.0 + lateral_m
            s_lo, o_lo = candidate_pairs(x, subjects, lo, reach)
            s_hi, o_hi = candidate_pairs(x, subjects, hi, reach)
            on_left = in_direction(pair_geometry(x, s_lo, o_lo), "left", 50.0, lateral_m) & first.mask[o_lo]
            on_right = in_direction(pair_geometry(x, s_hi, o_hi), "right", 50.0, lateral_m) & second.mask[o_hi]
            ok = group_any(on_left, s_lo, x.num_objects) & group_any(on_right, s_hi, x.num_objects)  # (K, F)
            both |= ok
            related |= group_any(on_left & ok[s_lo], o_lo, x.num_objects)
            related |= group_any(on_right & ok[s_hi], o_hi, x.num_objects)
        kept = _keep(sel, both)
        return Selection(kept.scores, kept.related | (related & ~kept.mask))


def nearest_only(holds: Mask, gap_m: NDArray[np.float32], subjects: NDArray[np.int64], n: int) -> Mask:
    """(P, F) ``holds`` kept, at each frame, for only the ``n`` pairs of each subject with the smallest
    ``gap_m`` (ties: the earlier pair).

    Args:
        holds: (P, F) where pair p relates at frame f.
        gap_m: (P, F) the distance between the pair's boxes.
        subjects: (P,) each pair's subject.
        n: how many others each subject keeps per frame.
    """
    pair, frame = np.nonzero(holds)
    order = np.lexsort((pair, gap_m[pair, frame], frame, subjects[pair]))  # by subject, frame, gap, pair
    pair, frame = pair[order], frame[order]
    group = np.concatenate([[True], (subjects[pair][1:] != subjects[pair][:-1]) | (frame[1:] != frame[:-1])])
    starts = np.flatnonzero(group)
    rank = np.arange(pair.size) - np.repeat(starts, np.diff(np.append(starts, pair.size)))
    kept = np.zeros_like(holds)
    kept[pair[rank < n], frame[rank < n]] = True
    return kept


def evaluate(node: p.Node, features: LogFeatures, events: bool = False) -> Evaluation:
    """Run ``node`` on one log (see the module docstring); with ``events``, also where a sequence
    happens (:attr:`Evaluation.events`: the search's moments of a sequence are those that show it).

    Raises:
        ProgramError: the program names an unknown kind, predicate or relation, or a bad parameter.
    """
    run = _Run(features)
    selection = run.eval(node)
    happens = run.starts(node, selection) if events and p.chain_under(node) is not None else None
    return Evaluation(selection, run.notes, happens)


def answer(node: p.Node, features: LogFeatures, description: str | None = None) -> tuple[LogAnswer, list[str]]:
    """The program's answer on one log (referred and related objects per frame) and its notes."""
    result = evaluate(node, features)
    x, sel = features, result.selection
    referred = np.where(x.valid, sel.scores, 0.0).astype(np.float32)
    ego_xyz = np.concatenate([x.xy_m[x.ego_index], x.z_m[x.ego_index][:, None]], axis=1).astype(np.float64)
    xyz = np.concatenate([x.xy_m, x.z_m[..., None]], axis=-1).astype(np.float64)
    velocity = np.concatenate([x.velocity_mps, np.zeros_like(x.z_m)[..., None]], axis=-1).astype(np.float64)
    size = np.broadcast_to(x.size_lwh_m[:, None, :], xyz.shape).astype(np.float64)
    return LogAnswer(
        log_id=x.log_id, description=description if description is not None else p.to_text(node),
        timestamps_ns=x.timestamps_ns, track_ids=x.track_ids, valid=x.valid,
        categories=np.where(np.isin(x.labels, [*AV2_TO_CATEGORY, EGO_VEHICLE_LABEL]), x.labels, x.categories),
        referred=referred, related=sel.related & x.valid & (referred == 0), center_city_xyz_m=xyz,
        size_lwh_m=size, yaw_city_rad=x.yaw_rad.astype(np.float64), velocity_city_mps=velocity,
        ego_city_xyz_m=ego_xyz,
    ), result.notes


def grouped_notes(said: Iterable[tuple[str, str]], shown: int = 3) -> tuple[str, ...]:
    """Notes of many logs, given as (log id, note) pairs, once per distinct reason: each names the first
    ``shown`` logs it is about and counts the rest (a note per log would bury the answer under the same
    sentence repeated). A note's ``"<log id>: "`` prefix, as :meth:`_Run.note` writes it, is left out."""
    by_reason: dict[str, list[str]] = {}
    for log_id, note in said:
        logs = by_reason.setdefault(note.removeprefix(f"{log_id}: "), [])
        if log_id not in logs:
            logs.append(log_id)
    out = []
    for reason, logs in by_reason.items():
        named = ", ".join(logs if len(logs) <= shown + 1 else logs[:shown])
        if len(logs) > shown + 1:
            named += f" and {len(logs) - shown} more logs"
        out.append(f"{named}: {reason}")
    return tuple(out)
