"""Reference answers of scenario programs: plain per-object, per-frame Python loops over true boxes,
the simulator's behaviour labels and the map.

This is the ground truth of the mining benchmark and its speed baseline. It shares no code with
:mod:`scenarios`' vectorised evaluation or features (it reads only the program tree and writes a
:class:`scenarios.answer.LogAnswer`), so a disagreement between the two shows that one of them is
wrong. Every test is written again from its definition, one object and one frame at a time:

- **Kinds**: RefAV's groups of AV2 labels (:data:`KIND_LABELS`); ``any`` is every object but the ego.
- **Own behaviour** comes from ``behavior_labels.feather`` (the simulator's state, not the boxes):
  ``parked``, ``stopped`` (not parked), ``braking``, ``turning`` (left / right turn labels),
  ``changing_lanes``, ``blocked``, ``braking_for_leader``; ``moving``: labelled speed above
  ``min_mps``; ``accelerating``: the labelled speed rises by at least ``min_mps2`` over the second
  centred on the frame (clipped to the track), while above 0.5 m/s. An object without label rows
  (street furniture) has no behaviour flags and its speed from its box centres.
- **Map context and lanes relative to the ego**: read with the log
  (:mod:`benchmarks.mining_reference_log`). ``approaching_ego``: moving, and the centre distance to the
  ego shrinks by at least 1 m/s (central difference).
- **Relations** (:mod:`scenarios.relations`' definitions): geometry in the subject's frame
  (:class:`~benchmarks.mining_reference_log.ReferenceLog`'s); the gap
  is the exact distance between the two rectangles (0 when they overlap). ``direction``: the other's
  centre beyond the subject's box on that side, within ``lateral_m`` of the box's sides and
  ``within_m`` of the box; ``near``; ``following`` (in front within ``within_m`` and ``lateral_m``,
  headings within 45°, the subject moving); ``same_lane``; these four also take ``beyond_m`` (the
  gap more than that); ``crossed_by`` (the other's centre
  changes side of the subject's heading line between two frames, both inside the zone up to
  ``forward_m`` past the front and ``lateral_m`` aside; the pair's frames within ``window_s``
  count; a centre within :data:`ON_LINE_M` of the line is on neither side, so an object that walks
  along the line does not cross it at every rounding of its offset).
- **Composition and time** as :mod:`scenarios.program` states (the tests over time in
  :mod:`benchmarks.mining_reference_time`): ``Has`` with counts, negation,
  ``reverse`` and ``nearest`` (by the exact gap); ``Between`` (either kind on either side, boxes
  within 50 m); and / or / but not; ``Together``; ``ForAtLeast`` (a run lasts from its first
  frame to its last plus one frame interval); ``Then`` (the same object, the second starting after
  a frame of the first, within ``within_s``; in a chain, each step after the one before); ``While``
  (the condition holds for any object at that frame); ``Sequenced`` (runs that begin within
  ``within_s`` before, or after, any object's event begins; a ``then`` begins where its last step
  does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmarks.mining_reference_log import FLAGS, Grid, ReferenceLog, central_rate, wrap
from benchmarks.mining_reference_time import FrameClock
from scenarios import program as p
from scenarios.answer import LogAnswer
from scenes.categories import AV2_TO_CATEGORY, EGO_VEHICLE_LABEL

Params = dict[str, float | str]

#: A centre this close to the subject's heading line is on it, on neither side (it has not crossed).
ON_LINE_M = 0.001
_VEHICLES = {"REGULAR_VEHICLE", "LARGE_VEHICLE", "BUS", "BOX_TRUCK", "TRUCK", "VEHICULAR_TRAILER", "TRUCK_CAB",
             "SCHOOL_BUS", "ARTICULATED_BUS", "MESSAGE_BOARD_TRAILER", "RAILED_VEHICLE"}
_VRU = {"PEDESTRIAN", "OFFICIAL_SIGNALER", "BICYCLIST", "BICYCLE", "WHEELED_RIDER", "MOTORCYCLIST", "MOTORCYCLE",
        "WHEELCHAIR", "STROLLER", "WHEELED_DEVICE"}
#: Kind → the AV2 labels it covers (``any``: all but the ego).
KIND_LABELS: dict[str, set[str]] = {
    "vehicle": _VEHICLES, "car": {"REGULAR_VEHICLE"},
    "truck": {"BOX_TRUCK", "TRUCK", "TRUCK_CAB", "LARGE_VEHICLE"}, "box_truck": {"BOX_TRUCK"},
    "bus": {"BUS", "ARTICULATED_BUS", "SCHOOL_BUS"}, "pedestrian": {"PEDESTRIAN", "OFFICIAL_SIGNALER"},
    "cyclist": {"BICYCLIST", "BICYCLE", "WHEELED_RIDER"}, "motorcycle": {"MOTORCYCLIST", "MOTORCYCLE"},
    "vulnerable_road_user": _VRU, "any": set(AV2_TO_CATEGORY), "ego": {EGO_VEHICLE_LABEL},
}
_PREDICATE_DEFAULTS: dict[str, Params] = {
    "moving": {"min_mps": 0.5}, "stopped": {}, "parked": {}, "braking": {}, "accelerating": {"min_mps2": 0.65},
    "turning": {"direction": "any"}, "changing_lanes": {"direction": "any"}, "blocked": {},
    "braking_for_leader": {}, "at_intersection": {}, "near_intersection": {"within_m": 5.0}, "on_crosswalk": {},
    "at_crosswalk": {},
    "ego_lane": {"lane": "host"}, "approaching_ego": {},
}
_RELATION_DEFAULTS: dict[str, Params] = {
    "direction": {"side": "front", "within_m": 50.0, "lateral_m": 1000.0, "beyond_m": 0.0},
    "near": {"within_m": 10.0, "beyond_m": 0.0}, "following": {"within_m": 25.0, "lateral_m": 1.5, "beyond_m": 0.0},
    "same_lane": {"within_m": 50.0, "beyond_m": 0.0},
    "crossed_by": {"forward_m": 10.0, "lateral_m": 5.0, "window_s": 1.0},
}


class ReferenceError(ValueError):
    """A program the reference does not answer (a predicate or relation it does not define)."""


# ---------------------------------------------------------------------------------- evaluating a program


@dataclass
class _Sel:
    """Selected objects × frames, and the objects related to them."""

    sel: Grid
    related: Grid


def _params(defaults: dict[str, Params], name: str, given: tuple[tuple[str, float | str], ...]) -> Params:
    if name not in defaults:
        raise ReferenceError(f"the reference does not define {name!r} (it defines {', '.join(sorted(defaults))})")
    out = dict(defaults[name])
    for key, value in given:
        if key not in out:
            raise ReferenceError(f"{name}: unknown parameter {key!r}")
        out[key] = value if isinstance(out[key], str) else float(value)
    return out


class _Reference:
    """One program on one :class:`ReferenceLog`, node by node, with plain loops."""

    def __init__(self, log: ReferenceLog) -> None:
        self.log = log
        self.k, self.f = log.num_objects, log.num_frames
        self.clock = FrameClock(list(log.time_s), log.num_objects)

    def grid(self, value: bool = False) -> Grid:
        return self.clock.grid(value)

    def any_at(self, grid: Grid) -> list[bool]:
        return [any(grid[o][f] for o in range(self.k)) for f in range(self.f)]

    def eval(self, node: p.Node) -> _Sel:
        log, k, nf = self.log, self.k, self.f
        match node:
            case p.Objects(kind):
                if kind not in KIND_LABELS:
                    raise ReferenceError(f"the reference does not define the kind {kind!r}")
                covered = KIND_LABELS[kind]
                sel = self.grid()
                for o in range(k):
                    if log.labels[o] in covered and not (kind == "any" and log.labels[o] == EGO_VEHICLE_LABEL):
                        for f in range(nf):
                            sel[o][f] = log.valid[o][f]
                return _Sel(sel, self.grid())
            case p.Is(subject, predicate, params, negate):
                resolved = _params(_PREDICATE_DEFAULTS, predicate, params)
                child = self.eval(subject)
                holds = self.predicate(predicate, resolved)
                keep = self.grid()
                for o in range(k):
                    for f in range(nf):
                        keep[o][f] = log.valid[o][f] and (holds[o][f] != negate)
                return self.keep(child, keep)
            case p.Has():
                return self.relation(node)
            case p.Between(subject, left, right, lateral_m):
                return self.between(self.eval(subject), self.eval(left), self.eval(right), float(lateral_m))
            case p.AllOf(children):
                parts = [self.eval(c) for c in children]
                sel = self.grid()
                for o in range(k):
                    for f in range(nf):
                        sel[o][f] = all(part.sel[o][f] for part in parts)
                on = self.any_at(sel)
                related = self.grid()
                for o in range(k):
                    for f in range(nf):
                        related[o][f] = on[f] and any(part.related[o][f] for part in parts)
                return _Sel(sel, related)
            case p.AnyOf(children):
                parts = [self.eval(c) for c in children]
                sel, related = self.grid(), self.grid()
                for o in range(k):
                    for f in range(nf):
                        sel[o][f] = any(part.sel[o][f] for part in parts)
                        related[o][f] = any(part.related[o][f] for part in parts)
                return _Sel(sel, related)
            case p.Excluding(base, excluded):
                kept, out = self.eval(base), self.eval(excluded)
                return self.keep(kept, [[not out.sel[o][f] for f in range(nf)] for o in range(k)])
            case p.Together(child, min_count):
                part = self.eval(child)
                counts = [sum(part.sel[o][f] for o in range(k)) for f in range(nf)]
                return self.keep(part, [[counts[f] >= min_count for f in range(nf)] for _ in range(k)])
            case p.ForAtLeast(child, seconds):
                part = self.eval(child)
                return self.keep(part, self.clock.runs_lasting(part.sel, float(seconds)))
            case p.Then():
                steps, gaps_s = p.chain_steps(node)
                parts = [self.eval(step) for step in steps]
                keep = self.clock.chained([part.sel for part in parts], gaps_s)
                on = self.any_at(keep)
                related = [[on[f] and any(part.related[o][f] for part in parts) for f in range(nf)]
                           for o in range(k)]
                return _Sel(keep, related)
            case p.While(child, condition):
                part, cond = self.eval(child), self.eval(condition)
                when = self.any_at(cond.sel)
                kept = self.keep(part, [list(when) for _ in range(k)])
                on = self.any_at(kept.sel)
                related = [[kept.related[o][f] or (cond.sel[o][f] and on[f]) for f in range(nf)] for o in range(k)]
                return _Sel(kept.sel, related)
            case p.Sequenced(child, event, within_s, after):
                part, ev = self.eval(child), self.eval(event)
                part_starts, ev_starts = self.starts(child, part.sel), self.starts(event, ev.sel)
                step = -1 if after else 1  # where the event's beginning is looked for: before or after
                ev_begins = self.any_at(ev_starts)
                kept_starts = [[part_starts[o][f] and self.clock.in_reach(ev_begins, f, step, float(within_s))
                                for f in range(nf)] for o in range(k)]
                kept = self.keep(part, self.clock.runs_holding(part.sel, kept_starts))
                begins = self.any_at(kept_starts)
                related_starts = [[ev_starts[o][f] and self.clock.in_reach(begins, f, -step, float(within_s))
                                   for f in range(nf)] for o in range(k)]
                related_runs = self.clock.runs_holding(ev.sel, related_starts)
                return _Sel(kept.sel, [[kept.related[o][f] or related_runs[o][f] for f in range(nf)]
                                       for o in range(k)])
        raise ReferenceError(f"not a program node: {node!r}")

    def keep(self, part: _Sel, mask: Grid) -> _Sel:
        """``part`` where ``mask`` holds; its related objects only at frames where something stays selected."""
        sel = [[part.sel[o][f] and mask[o][f] for f in range(self.f)] for o in range(self.k)]
        on = self.any_at(sel)
        return _Sel(sel, [[part.related[o][f] and on[f] for f in range(self.f)] for o in range(self.k)])

    # -- own state -------------------------------------------------------------------------------------
    def predicate(self, name: str, p: Params) -> Grid:
        log, k, nf = self.log, self.k, self.f
        out = self.grid()
        if name == "accelerating":
            for o in range(k):
                rate = central_rate(log.speed[o], log.valid[o], log.time_s, 0.5)
                for f in range(nf):
                    out[o][f] = rate[f] >= float(p["min_mps2"]) and log.speed[o][f] > 0.5
            return out
        if name == "approaching_ego":
            e = k - 1
            for o in range(k - 1):
                distance = [math.hypot(log.x[o][f] - log.x[e][f], log.y[o][f] - log.y[e][f]) if log.valid[o][f]
                            else 0.0 for f in range(nf)]
                rate = central_rate(distance, log.valid[o], log.time_s, 0.1)
                for f in range(nf):
                    out[o][f] = log.valid[o][f] and log.speed[o][f] > 0.5 and rate[f] <= -1.0
            return out
        for o in range(k):
            for f in range(nf):
                if not log.valid[o][f]:
                    continue
                flag = {n: log.flags[n][o][f] for n in FLAGS}
                if name == "moving":
                    out[o][f] = log.speed[o][f] > float(p["min_mps"])
                elif name == "stopped":
                    out[o][f] = flag["stopped"] and not flag["parked"]
                elif name in ("parked", "braking"):
                    out[o][f] = flag[name]
                elif name == "blocked":
                    out[o][f] = flag["blocked_by"]
                elif name == "braking_for_leader":
                    out[o][f] = flag["braking_for"]
                elif name in ("turning", "changing_lanes"):
                    left, right = ("left_turn", "right_turn") if name == "turning" else \
                        ("left_lane_change", "right_lane_change")
                    way = p["direction"]
                    out[o][f] = (way in ("left", "any") and flag[left]) or (way in ("right", "any") and flag[right])
                elif name == "at_intersection":
                    out[o][f] = log.in_junction[o][f]
                elif name == "near_intersection":
                    out[o][f] = log.junction_m[o][f] <= float(p["within_m"])
                elif name == "on_crosswalk":
                    out[o][f] = log.crosswalk_m[o][f] == 0.0
                elif name == "at_crosswalk":
                    out[o][f] = log.crosswalk_m[o][f] <= 1.0
                elif name == "ego_lane":
                    lane = str(p["lane"])
                    here = log.ego_lane[o][f]
                    out[o][f] = here == lane or (lane == "adjacent" and here in ("left", "right"))
        return out

    # -- relations -------------------------------------------------------------------------------------
    def pair_frames(self, name: str, p: Params, s: int, o: int) -> list[bool]:
        """(F) the frames where ``o`` stands in relation ``name`` to ``s`` (both observed)."""
        log, nf = self.log, self.f
        both = [log.valid[s][f] and log.valid[o][f] for f in range(nf)]
        out = [False] * nf
        if name == "crossed_by":
            zone = [False] * nf
            lateral = [0.0] * nf
            for f in range(nf):
                if both[f]:
                    fwd, left = self.log.local(s, o, f)
                    lateral[f] = left
                    zone[f] = 0 < fwd <= log.length[s][f] / 2 + float(p["forward_m"]) \
                        and abs(left) <= log.width[s][f] / 2 + float(p["lateral_m"])
            side = [(v > ON_LINE_M) - (v < -ON_LINE_M) for v in lateral]  # 0: on the line, no side
            events = [f for f in range(1, nf) if zone[f] and zone[f - 1] and side[f] * side[f - 1] < 0]
            for f in range(nf):
                if both[f]:
                    out[f] = any(abs(log.time_s[f] - log.time_s[g]) <= float(p["window_s"]) for g in events)
            return out
        for f in range(nf):
            if not both[f]:
                continue
            if name == "direction":
                out[f] = self.log.in_direction(s, o, f, str(p["side"]), float(p["within_m"]), float(p["lateral_m"]))
            elif name == "near":
                out[f] = self.log.gap(s, o, f) <= float(p["within_m"])
            elif name == "following":
                rel = abs(wrap(log.yaw[o][f] - log.yaw[s][f]))
                out[f] = log.speed[s][f] > 0.5 and rel <= math.pi / 4 \
                    and self.log.in_direction(s, o, f, "front", float(p["within_m"]), float(p["lateral_m"]))
            elif name == "same_lane":
                out[f] = log.lane[s][f] >= 0 and log.lane[s][f] == log.lane[o][f] \
                    and self.log.gap(s, o, f) <= float(p["within_m"])
            if float(p["beyond_m"]) > 0:  # a least distance
                out[f] = out[f] and self.log.gap(s, o, f) > float(p["beyond_m"])
        return out

    def relation(self, node: p.Has) -> _Sel:
        k, nf = self.k, self.f
        resolved = _params(_RELATION_DEFAULTS, node.relation, node.params)
        subject, other = self.eval(node.subject), self.eval(node.other)
        subjects = [s for s in range(k) if any(subject.sel[s])]
        others = [o for o in range(k) if any(other.sel[o])]
        holds: dict[tuple[int, int], list[bool]] = {}
        for s in subjects:
            for o in others:
                if s != o:
                    frames = self.pair_frames(node.relation, resolved, s, o)
                    holds[(s, o)] = [frames[f] and subject.sel[s][f] and other.sel[o][f] for f in range(nf)]
        if node.nearest is not None:  # each subject keeps, at each frame, only its nearest others that hold
            for s in subjects:
                for f in range(nf):
                    near_first = sorted((self.log.gap(s, o, f), o) for o in others if s != o and holds[(s, o)][f])
                    for _, o in near_first[node.nearest:]:
                        holds[(s, o)][f] = False
        ok = self.grid()
        related_others, related_subjects = self.grid(), self.grid()
        for s in subjects:
            for f in range(nf):
                count = sum(1 for o in others if s != o and holds[(s, o)][f])
                if node.negate:
                    ok[s][f] = count == 0 and subject.sel[s][f]
                else:
                    ok[s][f] = count >= node.min_count and (node.max_count is None or count <= node.max_count)
                if ok[s][f] and not node.negate:
                    for o in others:
                        if s != o and holds[(s, o)][f]:
                            related_others[o][f] = True
                            related_subjects[s][f] = True
        if node.reverse:
            if node.negate:
                raise ReferenceError(f"{node.relation}: reverse() of a negated relation names no object")
            return _Sel(related_others, related_subjects)
        kept = self.keep(subject, ok)
        related = [[kept.related[o][f] or (related_others[o][f] and not kept.sel[o][f]) for f in range(nf)]
                   for o in range(k)]
        return _Sel(kept.sel, related)

    def between(self, subject: _Sel, left: _Sel, right: _Sel, lateral_m: float) -> _Sel:
        k, nf = self.k, self.f
        ok, related = self.grid(), self.grid()
        subjects = [s for s in range(k) if any(subject.sel[s])]
        for s in subjects:
            for f in range(nf):
                if not subject.sel[s][f]:
                    continue
                for first, second in ((left, right), (right, left)):
                    on_left = [o for o in range(k) if o != s and first.sel[o][f]
                               and self.log.in_direction(s, o, f, "left", 50.0, lateral_m)]
                    on_right = [o for o in range(k) if o != s and second.sel[o][f]
                                and self.log.in_direction(s, o, f, "right", 50.0, lateral_m)]
                    if on_left and on_right:
                        ok[s][f] = True
                        for o in on_left + on_right:
                            related[o][f] = True
        kept = self.keep(subject, ok)
        return _Sel(kept.sel, [[kept.related[o][f] or (related[o][f] and not kept.sel[o][f]) for f in range(nf)]
                               for o in range(k)])

    # -- time ------------------------------------------------------------------------------------------
    def starts(self, node: p.Node, sel: Grid) -> Grid:
        """Where what ``node`` selects begins: the first frame of each run whose frame before is observed,
        and for ``then`` (also under ``is``, ``for_at_least``, ``while``, ``together``, ``before`` /
        ``after``) the frames where its last step begins with the steps before it reached in order; a run
        with none of those begins where it begins."""
        log, k, nf = self.log, self.k, self.f
        begins = [[sel[o][f] and f > 0 and not sel[o][f - 1] and log.valid[o][f - 1] for f in range(nf)]
                  for o in range(k)]
        chain = p.chain_under(node)
        if chain is None:
            return begins
        steps, gaps_s = chain
        grids = [self.eval(step).sel for step in steps]
        last, reached = grids[-1], self.clock.reached(grids, gaps_s)[-1]
        moves = [[sel[o][f] and reached[o][f] and not (f > 0 and last[o][f - 1]) for f in range(nf)]
                 for o in range(k)]
        moving_runs = self.clock.runs_holding(sel, moves)
        return [[moves[o][f] or (begins[o][f] and not moving_runs[o][f]) for f in range(nf)] for o in range(k)]


def reference_selection(program: p.Node, log: ReferenceLog) -> tuple[Grid, Grid]:
    """The (referred, related) objects × frames of ``program`` on ``log``, by the reference's loops.

    Raises:
        ReferenceError: the program uses a predicate, relation or kind the reference does not define.
    """
    result = _Reference(log).eval(program)
    return result.sel, result.related


def reference_answer(program: p.Node, log: ReferenceLog, description: str) -> LogAnswer:
    """The reference's answer as a :class:`LogAnswer` (referred objects score 1)."""
    referred, related = reference_selection(program, log)
    k, nf = log.num_objects, log.num_frames
    valid = np.asarray(log.valid, dtype=bool).reshape(k, nf)
    xyz = np.stack([np.asarray(log.x), np.asarray(log.y), np.asarray(log.z)], axis=-1).reshape(k, nf, 3)
    velocity = np.zeros((k, nf, 3))
    for o in range(k):
        velocity[o, :, 0] = central_rate(log.x[o], log.valid[o], log.time_s, 0.1)
        velocity[o, :, 1] = central_rate(log.y[o], log.valid[o], log.time_s, 0.1)
    size = np.stack([np.asarray(log.length), np.asarray(log.width), np.asarray(log.height)], axis=-1)
    referred_array = np.asarray(referred, dtype=bool).reshape(k, nf) & valid
    return LogAnswer(
        log_id=log.log_id, description=description, timestamps_ns=np.asarray(log.timestamps_ns, dtype=np.int64),
        track_ids=np.asarray(log.track_ids, dtype=np.str_), categories=np.asarray(log.labels, dtype=np.str_),
        valid=valid, referred=referred_array.astype(np.float32),
        related=np.asarray(related, dtype=bool).reshape(k, nf) & valid & ~referred_array,
        center_city_xyz_m=np.where(valid[..., None], xyz, np.nan), size_lwh_m=np.nan_to_num(size.reshape(k, nf, 3)),
        yaw_city_rad=np.nan_to_num(np.asarray(log.yaw, dtype=np.float64).reshape(k, nf)),
        velocity_city_mps=velocity, ego_city_xyz_m=xyz[-1],
    )



__all__ = ["KIND_LABELS", "ReferenceError", "reference_answer", "reference_selection"]
