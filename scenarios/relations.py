"""Relations between two objects per frame, vectorised over pairs of objects × frames.

Geometry is taken in the subject's own frame: ``dx_m`` forward along its heading, ``dy_m`` to its left.
``gap_m`` is the distance between the two boxes, approximated by the centre distance less each box's
extent towards the other (exact for boxes facing each other, within centimetres otherwise). Each
relation maps a :class:`PairGeometry` to a (P, F) mask of the frames where the other object of a pair stands
in that relation to its subject; pairs whose boxes never come within the relation's reach are left out
beforehand (:func:`candidate_pairs`):

- ``direction`` (``front``, ``behind``, ``left``, ``right``, ``beside``: left or right, and the corners
  ``front_left`` … ``back_right``): the other is beyond the subject's box on that side (both ways for
  a corner), within ``lateral_m`` of the box's sides and ``within_m`` of the box.
- ``near``: the boxes are within ``within_m``.
- ``following``: the subject moves behind the other, in the same direction (within 45°), at most
  ``within_m`` back and ``lateral_m`` aside.
- ``same_lane``: both are on the same lane segment, within ``within_m``.
- ``crossed_by``: the other's centre crosses the line ahead of the subject (up to ``forward_m`` past its
  front, within ``lateral_m`` of it); the frames within ``window_s`` of the crossing count.
- ``yielding_to``: crossed by the other within ``forward_m`` (15 m) while at most ``max_mps`` (3 m/s):
  the subject waits or creeps while the other crosses its path.
- ``passed_by`` (``side`` left, right or any): the other moves from behind to ahead of the subject on
  that side, within ``lateral_m`` (``way`` ``overtaking``), or either way (``either``: also an oncoming
  object going by); the frames within ``window_s`` of it count.
- ``heading`` (``same``, ``opposite``, ``perpendicular``): the headings differ by at most 45°, at least
  135°, or between.
- ``facing``: the other lies within ``angle_deg`` of the subject's heading, within ``within_m``.
- ``heading_toward``: the subject moves (``min_mps``) towards the other, within ``angle_deg``.
- ``heading_away_from``: the subject moves (``min_mps``) away from the other: the other lies within
  ``angle_deg`` of straight behind it, within ``within_m``.

Every relation bounded by ``within_m`` also takes ``beyond_m`` (default 0): the boxes are more than that
apart, a least distance ("more than 20 m ahead", "5 to 10 m behind it").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scenarios.features import LogFeatures
from scenarios.predicates import Criterion, Mask, Params, ProgramError

Array = NDArray[np.float32]


@dataclass(frozen=True)
class PairGeometry:
    """Pairs (subject, other) × frames, both observed (arrays (P, F) unless said).

    Attributes:
        ok: both observed, and not the same object.
        dx_m, dy_m: the other's centre in the subject's frame.
        gap_m: distance between the boxes.
        rel_yaw_rad: the other's heading less the subject's, wrapped to (−π, π].
        half_length_m, half_width_m: (P, 1) the subject's half extents.
        subject_speed_mps, other_speed_mps: speeds.
        same_lane: on the same lane segment.
        time_s: (F,) seconds since the log's first frame.
    """

    ok: Mask
    dx_m: Array
    dy_m: Array
    gap_m: Array
    rel_yaw_rad: Array
    half_length_m: Array
    half_width_m: Array
    subject_speed_mps: Array
    other_speed_mps: Array
    same_lane: Mask
    time_s: NDArray[np.float64]


def pair_geometry(x: LogFeatures, subjects: NDArray[np.int64], others: NDArray[np.int64]) -> PairGeometry:
    """The geometry of each pair (``subjects[p]``, ``others[p]``) (P,) at every frame."""
    s_xy, o_xy = x.xy_m[subjects], x.xy_m[others]  # (P, F, 2)
    s_yaw, o_yaw = x.yaw_rad[subjects], x.yaw_rad[others]  # (P, F)
    d = o_xy - s_xy  # (P, F, 2)
    c, s = np.cos(s_yaw), np.sin(s_yaw)
    dx = c * d[..., 0] + s * d[..., 1]
    dy = -s * d[..., 0] + c * d[..., 1]
    rel = (o_yaw - s_yaw + np.pi) % (2 * np.pi) - np.pi
    dist = np.hypot(dx, dy)
    s_half = (x.size_lwh_m[subjects, :2][:, None] / 2).astype(np.float32)  # (P, 1, 2)
    o_half = (x.size_lwh_m[others, :2][:, None] / 2).astype(np.float32)  # (P, 1, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux, uy = np.abs(dx / dist), np.abs(dy / dist)  # the direction to the other, in the subject's frame
        # ... and in the other's frame (rotated by the relative heading).
        cr, sr = np.cos(rel), np.sin(rel)
        vx, vy = np.abs(cr * dx + sr * dy) / dist, np.abs(-sr * dx + cr * dy) / dist
    extent = np.nan_to_num(ux * s_half[..., 0] + uy * s_half[..., 1] + vx * o_half[..., 0] + vy * o_half[..., 1])
    ok = x.valid[subjects] & x.valid[others] & (subjects != others)[:, None]
    s_lane, o_lane = x.lane[subjects], x.lane[others]
    return PairGeometry(
        ok=ok, dx_m=dx, dy_m=dy, gap_m=np.maximum(dist - extent, 0.0), rel_yaw_rad=rel,
        half_length_m=s_half[..., 0], half_width_m=s_half[..., 1],
        subject_speed_mps=x.speed_mps[subjects], other_speed_mps=x.speed_mps[others],
        same_lane=(s_lane == o_lane) & (s_lane >= 0), time_s=x.time_s,
    )


#: Frames per block of :func:`candidate_pairs`' coarse test (1 s at 10 Hz).
PAIR_BLOCK_FRAMES = 10


def candidate_pairs(x: LogFeatures, subjects: NDArray[np.int64], others: NDArray[np.int64], reach_m: float | None
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The pairs (subject, other), as two (P,) arrays sorted by subject, that may relate: two different
    objects observed in a same block of :data:`PAIR_BLOCK_FRAMES` frames with their centres' boxes over
    that block within ``reach_m`` plus both boxes' half diagonals (every pair when ``reach_m`` is None).

    The test is conservative (a pair left out never comes that close), so the relations' answers do not
    change; it spares the geometry of objects far apart, most pairs of a busy log.
    """
    f = x.num_frames
    nb = -(-f // PAIR_BLOCK_FRAMES)
    pad = nb * PAIR_BLOCK_FRAMES - f

    def block_boxes(idx: NDArray[np.int64]) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_]]:
        valid = np.pad(x.valid[idx], ((0, 0), (0, pad))).reshape(len(idx), nb, PAIR_BLOCK_FRAMES)
        xy = np.pad(x.xy_m[idx], ((0, 0), (0, pad), (0, 0))).reshape(len(idx), nb, PAIR_BLOCK_FRAMES, 2)
        lo = np.where(valid[..., None], xy, np.inf).min(axis=2)  # (N, B, 2)
        hi = np.where(valid[..., None], xy, -np.inf).max(axis=2)
        return lo, hi, np.asarray(valid.any(axis=2))

    s_lo, s_hi, s_on = block_boxes(subjects)
    o_lo, o_hi, o_on = block_boxes(others)
    near = s_on[:, None] & o_on[None]  # (S, O, B)
    if reach_m is not None:
        half_diag = np.hypot(x.size_lwh_m[:, 0], x.size_lwh_m[:, 1]) / 2
        margin = (reach_m + half_diag[subjects][:, None] + half_diag[others][None])[..., None]  # (S, O, 1)
        for axis in (0, 1):
            near &= (s_lo[:, None, :, axis] - margin <= o_hi[None, :, :, axis]) \
                & (o_lo[None, :, :, axis] <= s_hi[:, None, :, axis] + margin)
    pair = near.any(axis=2) & (subjects[:, None] != others[None, :])
    si, oi = np.nonzero(pair)
    return subjects[si], others[oi]


def _grouped(mask: Mask, keys: NDArray[np.int64], n: int, reduce: np.ufunc, dtype: type) -> NDArray[Any]:
    """(n, F): row k reduces (``reduce.reduceat``) the rows of ``mask`` (P, F) whose key is k."""
    out: NDArray[Any] = np.zeros((n, mask.shape[1]), dtype=dtype)
    if keys.size:
        order = np.argsort(keys, kind="stable")
        k = keys[order]
        starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        out[k[starts]] = reduce.reduceat(mask[order].astype(dtype), starts, axis=0)
    return out


def group_any(mask: Mask, keys: NDArray[np.int64], n: int) -> Mask:
    """(n, F): row k is the or of the rows of ``mask`` (P, F) whose key is k."""
    return _grouped(mask, keys, n, np.logical_or, bool)


def group_count(mask: Mask, keys: NDArray[np.int64], n: int) -> NDArray[np.int64]:
    """(n, F): row k counts the rows of ``mask`` (P, F) whose key is k that hold at each frame."""
    return _grouped(mask, keys, n, np.add, np.int64)


@dataclass(frozen=True)
class Relation(Criterion):
    """A named relation of another object to a subject (see the module docstring), with the parameters of
    :class:`~scenarios.predicates.Criterion`.

    ``phrase`` says it after the subjects' name ("with {other} …"), ``reverse_phrase`` after the other
    objects' ("… {subject}"), for programs that answer those.
    """

    phrase: str
    reverse_phrase: str
    fn: Callable[[PairGeometry, Params], Mask]
    #: The farthest the boxes can be apart where it holds, given its parameters (None: no bound).
    reach_m: Callable[[Params], float | None] = lambda p: None

    def resolve(self, given: Params) -> dict[str, float | str]:
        """As :meth:`Criterion.resolve`; a least distance must be below the reach.

        Raises:
            ProgramError: also ``beyond_m`` at or above ``within_m``, which nothing could meet.
        """
        out = super().resolve(given)
        if "beyond_m" in given and float(out["beyond_m"]) >= float(out["within_m"]):
            raise ProgramError(f"{self.name}: beyond_m={float(out['beyond_m']):g} must be less than "
                               f"within_m={float(out['within_m']):g}")
        return out


RELATIONS: dict[str, Relation] = {}


def _within_reach(p: Params) -> float | None:
    return float(p["within_m"])


def _define(name: str, phrase: str, reverse_phrase: str, defaults: Mapping[str, float | str] | None = None,
            choices: Mapping[str, tuple[str, ...]] | None = None, needs_map: bool = False,
            reach_m: Callable[[Params], float | None] = _within_reach,
            ) -> Callable[[Callable[[PairGeometry, Params], Mask]], Callable[[PairGeometry, Params], Mask]]:
    def register(fn: Callable[[PairGeometry, Params], Mask]) -> Callable[[PairGeometry, Params], Mask]:
        known = dict(defaults or {})
        if "within_m" in known:
            known["beyond_m"] = 0.0
        RELATIONS[name] = Relation(name, phrase, reverse_phrase, _beyond(fn) if "within_m" in known else fn,
                                   reach_m, defaults=known, choices=dict(choices or {}), needs_map=needs_map)
        return fn
    return register


def _beyond(fn: Callable[[PairGeometry, Params], Mask]) -> Callable[[PairGeometry, Params], Mask]:
    """``fn`` where the boxes are also more than ``beyond_m`` apart."""
    def holds(g: PairGeometry, p: Params) -> Mask:
        beyond_m = _f(p, "beyond_m")
        return fn(g, p) & (g.gap_m > beyond_m) if beyond_m > 0 else fn(g, p)
    return holds


def _f(p: Params, key: str) -> float:
    return float(p[key])


def in_direction(g: PairGeometry, side: str, within_m: float, lateral_m: float) -> Mask:
    """Where the other lies beyond the subject's box on ``side``, within ``lateral_m`` of its sides."""
    hl, hw = g.half_length_m, g.half_width_m
    if side == "front":
        where = (g.dx_m > hl) & (np.abs(g.dy_m) <= hw + lateral_m)
    elif side == "behind":
        where = (g.dx_m < -hl) & (np.abs(g.dy_m) <= hw + lateral_m)
    elif side == "left":
        where = (g.dy_m > hw) & (np.abs(g.dx_m) <= hl + lateral_m)
    elif side == "right":
        where = (g.dy_m < -hw) & (np.abs(g.dx_m) <= hl + lateral_m)
    elif side == "beside":  # left or right
        where = (np.abs(g.dy_m) > hw) & (np.abs(g.dx_m) <= hl + lateral_m)
    else:  # a corner: beyond the box both ways
        ahead = g.dx_m > hl if side.startswith("front") else g.dx_m < -hl
        where = ahead & ((g.dy_m > hw) if side.endswith("left") else (g.dy_m < -hw))
    return g.ok & where & (g.gap_m <= within_m)


@_define("direction", "with {other} {side_of} them", "{side_of} {subject}",
         {"side": "front", "within_m": 50.0, "lateral_m": 1000.0},
         {"side": ("front", "behind", "left", "right", "beside", "front_left", "front_right", "back_left",
                   "back_right")})
def _direction(g: PairGeometry, p: Params) -> Mask:
    return in_direction(g, str(p["side"]), _f(p, "within_m"), _f(p, "lateral_m"))


@_define("near", "near {other}", "near {subject}", {"within_m": 10.0})
def _near(g: PairGeometry, p: Params) -> Mask:
    return g.ok & (g.gap_m <= _f(p, "within_m"))


@_define("following", "following {other}", "followed by {subject}", {"within_m": 25.0, "lateral_m": 1.5})
def _following(g: PairGeometry, p: Params) -> Mask:
    return in_direction(g, "front", _f(p, "within_m"), _f(p, "lateral_m")) & (np.abs(g.rel_yaw_rad) <= np.pi / 4) \
        & (g.subject_speed_mps > 0.5)


@_define("same_lane", "sharing a lane with {other}", "sharing a lane with {subject}",
         {"within_m": 50.0}, needs_map=True)
def _same_lane(g: PairGeometry, p: Params) -> Mask:
    return g.ok & g.same_lane & (g.gap_m <= _f(p, "within_m"))


def _around_events(events: Mask, time_s: NDArray[np.float64], window_s: float) -> Mask:
    """(P, F) frames within ``window_s`` of an event frame (on the same pair)."""
    if events.shape[-1] == 0:
        return events
    t = np.broadcast_to(time_s, events.shape)
    last = np.maximum.accumulate(np.where(events, t, -np.inf), axis=-1)
    nxt = np.flip(np.minimum.accumulate(np.flip(np.where(events, t, np.inf), axis=-1), axis=-1), axis=-1)
    return (t - last <= window_s) | (nxt - t <= window_s)


def _sign_change(values: Array, ok: Mask) -> Mask:
    """(P, F) frames where ``values`` changes sign since the frame before (both observed)."""
    out = np.zeros(values.shape, dtype=bool)
    out[..., 1:] = ok[..., 1:] & ok[..., :-1] & (np.sign(values[..., 1:]) != np.sign(values[..., :-1]))
    return out


@_define("crossed_by", "crossed by {other}", "crossing in front of {subject}",
         {"forward_m": 10.0, "lateral_m": 5.0, "window_s": 1.0},
         # The other's centre enters the zone ahead: within its length and width beyond the box.
         reach_m=lambda p: float(np.hypot(float(p["forward_m"]), float(p["lateral_m"]))))
def _crossed_by(g: PairGeometry, p: Params) -> Mask:
    zone = g.ok & (g.dx_m > 0) & (g.dx_m <= g.half_length_m + _f(p, "forward_m")) \
        & (np.abs(g.dy_m) <= g.half_width_m + _f(p, "lateral_m"))
    events = _sign_change(g.dy_m, zone)
    return g.ok & _around_events(events, g.time_s, _f(p, "window_s"))


@_define("yielding_to", "yielding to {other}", "crossing in front of {subject}, which yields",
         {"forward_m": 15.0, "lateral_m": 5.0, "window_s": 1.0, "max_mps": 3.0},
         reach_m=lambda p: float(np.hypot(float(p["forward_m"]), float(p["lateral_m"]))))
def _yielding_to(g: PairGeometry, p: Params) -> Mask:
    return _crossed_by(g, p) & (g.subject_speed_mps <= _f(p, "max_mps"))


@_define("passed_by", "passed by {other} on the {side}{way_of}", "passing {subject} on the {side}{way_of}",
         {"side": "any", "way": "overtaking", "lateral_m": 5.0, "window_s": 1.0},
         {"side": ("left", "right", "any"), "way": ("overtaking", "either")},
         reach_m=lambda p: None)  # how far the other moves between two frames is unbounded
def _passed_by(g: PairGeometry, p: Params) -> Mask:
    side, lateral = str(p["side"]), _f(p, "lateral_m")
    beside = (np.abs(g.dy_m) > g.half_width_m) & (np.abs(g.dy_m) <= g.half_width_m + lateral)
    if side == "left":
        beside &= g.dy_m > 0
    elif side == "right":
        beside &= g.dy_m < 0
    events = _sign_change(g.dx_m, g.ok & beside)
    if str(p["way"]) == "overtaking":
        events[..., 1:] &= g.dx_m[..., 1:] >= 0  # from behind to ahead
    return g.ok & _around_events(events, g.time_s, _f(p, "window_s"))


@_define("heading", "heading the {way} way as {other}", "heading the {way} way as {subject}",
         {"way": "same", "within_m": 50.0},
         {"way": ("same", "opposite", "perpendicular")})
def _heading(g: PairGeometry, p: Params) -> Mask:
    a = np.abs(g.rel_yaw_rad)
    way = str(p["way"])
    match = a <= np.pi / 4 if way == "same" else a >= 3 * np.pi / 4 if way == "opposite" else \
        (a > np.pi / 4) & (a < 3 * np.pi / 4)
    return g.ok & match & (g.gap_m <= _f(p, "within_m"))


@_define("facing", "facing {other}", "faced by {subject}", {"angle_deg": 22.5, "within_m": 50.0})
def _facing(g: PairGeometry, p: Params) -> Mask:
    bearing = np.abs(np.arctan2(g.dy_m, g.dx_m))
    return g.ok & (bearing <= np.radians(_f(p, "angle_deg"))) & (g.gap_m <= _f(p, "within_m"))


@_define("heading_toward", "heading toward {other}", "approached by {subject}",
         {"angle_deg": 22.5, "min_mps": 0.5, "within_m": 50.0})
def _heading_toward(g: PairGeometry, p: Params) -> Mask:
    return _facing(g, p) & (g.subject_speed_mps >= _f(p, "min_mps"))


@_define("heading_away_from", "heading away from {other}", "left behind by {subject}",
         {"angle_deg": 22.5, "min_mps": 0.5, "within_m": 50.0})
def _heading_away_from(g: PairGeometry, p: Params) -> Mask:
    behind = np.pi - np.abs(np.arctan2(g.dy_m, g.dx_m))  # 0: straight behind the subject
    return g.ok & (behind <= np.radians(_f(p, "angle_deg"))) & (g.gap_m <= _f(p, "within_m")) \
        & (g.subject_speed_mps >= _f(p, "min_mps"))
