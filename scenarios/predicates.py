"""Predicates on one object per frame: its own motion, its place on the map, and its place relative to the ego.

Each predicate maps a log's features to a (K, F) mask of the frames where it holds, vectorised over
every object and frame. Thresholds are the predicate's parameters, with defaults; speeds in m/s,
accelerations in m/s², durations in seconds. A predicate that reads the map (:attr:`Predicate.needs_map`)
has no answer on a log without one: the evaluation says so instead of answering "false".

- ``moving``: speed above ``min_mps`` (0.5); ``standing``: at most that.
- ``stationary``: the object moves less than ``max_travel_m`` (2 m) over its whole track.
- ``parked``, ``stopped``: the captioning rules' (:mod:`captioning.behavior`); ``stopped`` also holds
  for any standing object the rules do not call parked.
- ``accelerating`` / ``braking``: speed rising at ``min_mps2`` (0.65) or more / falling at ``min_mps2``
  (1.0) or more, or the rules' braking.
- ``turning``, ``changing_lanes``: the rules' turns and lane changes, ``direction`` left, right or any.
- ``reversing``: the centre moves at least ``min_m`` (1 m) backwards along the object's heading over
  the ``window_s`` (1 s) centred on the frame, by the heading at the window's start, middle and end
  (a box jittering in place, or a heading that flips for a frame, does not).
- ``blocked``, ``braking_for_leader``: the rules' slow follower held up by, or braking for, a vehicle ahead.
- ``speed``: speed within [``min_mps``, ``max_mps``]; ``fast`` / ``slow``: fast or slow for the object's
  kind (:data:`FAST_MPS`, :data:`SLOW_MPS`: a pedestrian is fast from 2.5 m/s, a car from 13).
- ``crossing_road``: a pedestrian, cyclist or other small road user moving on a lane, a crosswalk or
  in a junction; ``approaching_crosswalk``: not on a crosswalk yet, on one within ``within_s`` (3 s);
  ``about_to_cross``: not crossing the road yet, crossing it within ``within_s`` (3 s).
- ``near_intersection``: at most ``within_m`` (5 m) along its lane from the junction it enters, or in it.
- ``at_intersection``, ``on_crosswalk``, ``at_crosswalk`` (on one or within 1 m: where pedestrians
  wait), ``on_road`` (on a lane or in a junction), ``in_bike_lane``, ``in_bus_lane``, ``in_vehicle_lane``
  (on a lane that is neither): map context.
- ``jaywalking``: a moving pedestrian on a lane, off crosswalks and intersections (needs the map).
- ``appearance`` (``time_of_day``, ``weather``): the log's recorded lighting and weather; a log that
  records neither has no answer (a note says so).
- ``ego_lane`` (``lane``: host, left, right, adjacent, oncoming, lateral): the object's lane relative to
  the ego's (:mod:`scenarios.features`: the map's lanes where there is a map, else the captioning's tags).
- ``approaching_ego`` / ``moving_away_from_ego``: moving (above ``min_mps``), and the distance between
  the centres of the object and the ego shrinks / grows by at least :data:`GAP_RATE_MPS` (1 m/s).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import KW_ONLY, dataclass, field

import numpy as np
from numpy.typing import NDArray

from captioning.tags import LANES, Lane
from scenarios.features import LogFeatures
from scenarios.timing import followed_within

Mask = NDArray[np.bool_]
Params = Mapping[str, float | str]


class ProgramError(ValueError):
    """A program that cannot be built or run: an unknown name, a parameter of the wrong kind or value."""


@dataclass(frozen=True)
class Criterion:
    """What predicates and relations share: a name, parameters with defaults, and whether the map is read.

    Attributes:
        name: the name programs use.
        defaults: parameter name → default value (a float, or a str among ``choices``).
        choices: for str parameters, the values allowed.
        needs_map: whether it reads the log's map.
    """

    name: str
    _: KW_ONLY
    defaults: Mapping[str, float | str] = field(default_factory=dict)
    choices: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    needs_map: bool = False

    def resolve(self, given: Params) -> dict[str, float | str]:
        """``given`` checked against the parameters, with the defaults filled in.

        Raises:
            ProgramError: an unknown parameter, a number where a word is expected (or the reverse), or a
                word outside the choices; the message starts with the name.
        """
        unknown = sorted(set(given) - set(self.defaults))
        if unknown:
            raise ProgramError(f"{self.name}: unknown parameter {unknown[0]!r} "
                               f"(known: {', '.join(self.defaults) or 'none'})")
        out = dict(self.defaults)
        for key, value in given.items():
            if key in self.choices:
                if str(value) not in self.choices[key]:
                    raise ProgramError(f"{self.name}: {key}={value!r} is not one of {', '.join(self.choices[key])}")
                out[key] = str(value)
            else:
                try:
                    number = float(value)
                except (TypeError, ValueError):
                    raise ProgramError(f"{self.name}: {key}={value!r} is not a number") from None
                if not np.isfinite(number) or number < 0:
                    raise ProgramError(f"{self.name}: {key}={value!r} must be a finite number ≥ 0")
                out[key] = number
        return out


@dataclass(frozen=True)
class Predicate(Criterion):
    """A named test of one object at each frame (with the parameters of :class:`Criterion`).

    Attributes:
        phrase: how a reader says it ("turning {direction}").
        fn: ``(features, params) -> (K, F) mask``.
        says: how a reader says it with given parameters, where the template cannot ("faster than 10 m/s"
            rather than "moving at 10–1000 m/s"); None: ``phrase`` filled in.
    """

    phrase: str
    fn: Callable[[LogFeatures, Params], Mask]
    says: Callable[[Params], str] | None = None

    def words(self, params: Params) -> str:
        """The phrase for ``params`` (every parameter given)."""
        return self.says(params) if self.says is not None else self.phrase.format(**params)


PREDICATES: dict[str, Predicate] = {}
DIRECTIONS = ("left", "right", "any")


def _define(name: str, phrase: str, defaults: Mapping[str, float | str] | None = None,
            choices: Mapping[str, tuple[str, ...]] | None = None, needs_map: bool = False,
            says: Callable[[Params], str] | None = None
            ) -> Callable[[Callable[[LogFeatures, Params], Mask]], Callable[[LogFeatures, Params], Mask]]:
    def register(fn: Callable[[LogFeatures, Params], Mask]) -> Callable[[LogFeatures, Params], Mask]:
        PREDICATES[name] = Predicate(name, phrase, fn, says, defaults=dict(defaults or {}),
                                     choices=dict(choices or {}), needs_map=needs_map)
        return fn
    return register


def _f(params: Params, key: str) -> float:
    return float(params[key])


@_define("moving", "moving", {"min_mps": 0.5})
def _moving(x: LogFeatures, p: Params) -> Mask:
    return x.valid & (x.speed_mps > _f(p, "min_mps"))


@_define("standing", "standing", {"max_mps": 0.5})
def _standing(x: LogFeatures, p: Params) -> Mask:
    return x.valid & (x.speed_mps <= _f(p, "max_mps"))


@_define("stationary", "never moving", {"max_travel_m": 2.0})
def _stationary(x: LogFeatures, p: Params) -> Mask:
    xy = np.where(x.valid[..., None], x.xy_m, np.nan)
    with warnings.catch_warnings():  # tracks never observed give all-NaN rows: no travel known
        warnings.simplefilter("ignore", RuntimeWarning)
        extent = np.nanmax(xy, axis=1) - np.nanmin(xy, axis=1)  # (K, 2)
    travel = np.nan_to_num(np.hypot(extent[:, 0], extent[:, 1]), nan=np.inf)
    return x.valid & (travel <= _f(p, "max_travel_m"))[:, None]


@_define("parked", "parked")
def _parked(x: LogFeatures, p: Params) -> Mask:
    return x.flag("parked")


@_define("stopped", "stopped", {"max_mps": 0.5})
def _stopped(x: LogFeatures, p: Params) -> Mask:
    return (x.flag("stopped") | (x.valid & (x.speed_mps <= _f(p, "max_mps")))) & ~x.flag("parked")


@_define("accelerating", "accelerating", {"min_mps2": 0.65})
def _accelerating(x: LogFeatures, p: Params) -> Mask:
    return (x.valid & (x.accel_mps2 >= _f(p, "min_mps2")) & (x.speed_mps > 0.5)) | x.flag("accelerating_host")


@_define("braking", "braking", {"min_mps2": 1.0})
def _braking(x: LogFeatures, p: Params) -> Mask:
    return x.flag("braking") | (x.valid & (x.accel_mps2 <= -_f(p, "min_mps2")) & (x.speed_mps > 0.5))


def _sided(x: LogFeatures, left: str, right: str, direction: str) -> Mask:
    if direction == "left":
        return x.flag(left)
    if direction == "right":
        return x.flag(right)
    return x.flag(left) | x.flag(right)


@_define("turning", "turning {direction}", {"direction": "any"}, {"direction": DIRECTIONS})
def _turning(x: LogFeatures, p: Params) -> Mask:
    return _sided(x, "left_turn", "right_turn", str(p["direction"]))


@_define("changing_lanes", "changing lanes {direction}", {"direction": "any"}, {"direction": DIRECTIONS},
         needs_map=True)
def _changing_lanes(x: LogFeatures, p: Params) -> Mask:
    return _sided(x, "left_lane_change", "right_lane_change", str(p["direction"]))


@_define("jaywalking", "jaywalking (on a lane, off crosswalks)", needs_map=True)
def _jaywalking(x: LogFeatures, p: Params) -> Mask:
    return x.flag("on_lane") & ~x.flag("on_crosswalk") & ~x.flag("at_intersection") & (x.speed_mps > 0.5) \
        & np.isin(x.categories, ["pedestrian"])[:, None]


@_define("appearance", "in logs recorded: {time_of_day} {weather}",
         {"time_of_day": "any", "weather": "any"},
         {"time_of_day": ("any", "day", "dusk", "night"), "weather": ("any", "clear", "rain", "fog", "snow")})
def _appearance(x: LogFeatures, p: Params) -> Mask:
    ok = all(str(p[key]) in ("any", getattr(x, key)) for key in ("time_of_day", "weather"))
    return x.valid & ok


@_define("crossing_road", "crossing the road", needs_map=True)
def _crossing_road(x: LogFeatures, p: Params) -> Mask:
    on = x.flag("on_crosswalk") | x.flag("on_lane") | x.flag("at_intersection")
    walkers = np.isin(x.categories, ["pedestrian", "cyclist", "other"])[:, None]
    return on & walkers & (x.speed_mps > 0.5)


def _soon(x: LogFeatures, holds: Mask, within_s: float) -> Mask:
    """(K, F) frames where ``holds`` does not hold yet and will within ``within_s``."""
    return followed_within(x.valid & ~holds, holds, x.time_s, within_s)


@_define("approaching_crosswalk", "reaching a crosswalk within {within_s} s", {"within_s": 3.0}, needs_map=True)
def _approaching_crosswalk(x: LogFeatures, p: Params) -> Mask:
    return _soon(x, x.flag("on_crosswalk"), _f(p, "within_s"))


@_define("about_to_cross", "about to cross the road (within {within_s} s)", {"within_s": 3.0}, needs_map=True)
def _about_to_cross(x: LogFeatures, p: Params) -> Mask:
    return _soon(x, _crossing_road(x, p), _f(p, "within_s"))


@_define("near_intersection", "within {within_m} m of an intersection", {"within_m": 5.0}, needs_map=True)
def _near_intersection(x: LogFeatures, p: Params) -> Mask:
    return x.valid & (x.to_junction_m <= _f(p, "within_m"))


@_define("blocked", "blocked by a vehicle ahead")
def _blocked(x: LogFeatures, p: Params) -> Mask:
    return x.flag("blocked_by")


@_define("reversing", "moving backwards", {"min_m": 1.0, "window_s": 1.0})
def _reversing(x: LogFeatures, p: Params) -> Mask:
    # Displacement over a window of the log's own timestamps (the same at 10 Hz and 2 Hz), not the
    # per-frame velocity: on real boxes the centres of parked and stopping vehicles jitter by 1 m/s.
    half_s, t = _f(p, "window_s") / 2.0, x.time_s
    lo = np.searchsorted(t, t - half_s - 1e-6)  # (F,) the window's first and last frames
    hi = np.searchsorted(t, t + half_s + 1e-6, side="right") - 1
    moved = x.xy_m[:, hi].astype(np.float64) - x.xy_m[:, lo]  # (K, F, 2)
    # Backwards along the heading at the window's start, middle and end alike: a heading that flips for
    # a frame does not turn forward motion into reverse.
    yaw = x.yaw_rad.astype(np.float64)
    along_m = np.max([moved[..., 0] * np.cos(yaw[:, at]) + moved[..., 1] * np.sin(yaw[:, at])
                      for at in (lo, np.arange(t.size), hi)], axis=0)
    # Both ends observed, and at least 0.8 of the window inside the log.
    spans = (t[hi] - t[lo]) >= 0.8 * 2.0 * half_s
    with np.errstate(invalid="ignore"):
        return x.valid & x.valid[:, lo] & x.valid[:, hi] & spans[None, :] & (along_m <= -_f(p, "min_m"))


@_define("braking_for_leader", "braking for a vehicle ahead")
def _braking_for(x: LogFeatures, p: Params) -> Mask:
    return x.flag("braking_for")


#: The ``speed`` predicate's default ceiling: no bound at all.
_MAX_SPEED_MPS = 1000.0


def _speed_words(p: Params) -> str:
    """A floor or a ceiling alone reads as one ("faster than 10 m/s"), both as a band."""
    low, high = _f(p, "min_mps"), _f(p, "max_mps")
    if high >= _MAX_SPEED_MPS:
        return f"faster than {low:g} m/s"
    if low <= 0.0:
        return f"slower than {high:g} m/s"
    return f"at {low:g}–{high:g} m/s"


@_define("speed", "moving at {min_mps}–{max_mps} m/s", {"min_mps": 0.0, "max_mps": _MAX_SPEED_MPS},
         says=_speed_words)
def _speed(x: LogFeatures, p: Params) -> Mask:
    return x.valid & (x.speed_mps >= _f(p, "min_mps")) & (x.speed_mps <= _f(p, "max_mps"))


#: Speeds at and above which an object of a public category is fast; vehicles' (and the ego's) otherwise.
FAST_MPS = {"pedestrian": 2.5, "cyclist": 6.0, "other": 2.5, "vehicle": 13.0}
#: Speed ranges in which an object of a public category moves slowly; vehicles' otherwise.
SLOW_MPS = {"pedestrian": (0.1, 0.7), "cyclist": (0.1, 1.5), "other": (0.1, 0.7), "vehicle": (0.1, 2.0)}


@_define("fast", "at a fast pace for their kind")
def _fast(x: LogFeatures, p: Params) -> Mask:
    floor = np.array([FAST_MPS.get(str(c), FAST_MPS["vehicle"]) for c in x.categories], np.float32)
    return x.valid & (x.speed_mps >= floor[:, None])


@_define("slow", "at a slow pace for their kind")
def _slow(x: LogFeatures, p: Params) -> Mask:
    low, high = np.array([SLOW_MPS.get(str(c), SLOW_MPS["vehicle"]) for c in x.categories], np.float32).T
    return x.valid & (x.speed_mps >= low[:, None]) & (x.speed_mps <= high[:, None])


def _map_flag(flag: str) -> Callable[[LogFeatures, Params], Mask]:
    def holds(x: LogFeatures, p: Params) -> Mask:
        return x.flag(flag)
    return holds


@_define("in_vehicle_lane", "in a vehicle lane", needs_map=True)
def _in_vehicle_lane(x: LogFeatures, p: Params) -> Mask:
    return x.flag("on_lane") & ~x.flag("in_bike_lane") & ~x.flag("in_bus_lane")


for _name, _flag, _phrase in (("at_intersection", "at_intersection", "at an intersection"),
                              ("on_crosswalk", "on_crosswalk", "on a crosswalk"),
                              ("at_crosswalk", "at_crosswalk", "at a crosswalk"),
                              ("in_bike_lane", "in_bike_lane", "in a bike lane"),
                              ("in_bus_lane", "in_bus_lane", "in a bus lane"),
                              ("on_road", "on_lane", "on the road")):
    _define(_name, _phrase, needs_map=True)(_map_flag(_flag))

_LANE_GROUPS: dict[str, tuple[Lane, ...]] = {
    "host": (Lane.HOST,), "left": (Lane.LEFT,), "right": (Lane.RIGHT,), "adjacent": (Lane.LEFT, Lane.RIGHT),
    "oncoming": (Lane.ONCOMING,),
    "lateral": (Lane.LEFT_LATERAL, Lane.RIGHT_LATERAL, Lane.HOST_LATERAL),
}


@_define("ego_lane", "in the {lane} lane of the ego", {"lane": "host"}, {"lane": tuple(_LANE_GROUPS)})
def _ego_lane(x: LogFeatures, p: Params) -> Mask:
    codes = [LANES.index(lane) for lane in _LANE_GROUPS[str(p["lane"])]]
    return x.valid & np.isin(x.ego_lane, codes)


#: The gap to the ego changes by at least this much for an object to approach it or move away.
GAP_RATE_MPS = 1.0


def _gap_rate(x: LogFeatures) -> NDArray[np.float64]:
    """(K, F) rate of change of each object's centre distance to the ego, m/s (NaN where unobserved)."""
    offset = x.xy_m.astype(np.float64) - x.xy_m[-1:].astype(np.float64)  # (K, F, 2)
    closing = x.velocity_mps.astype(np.float64) - x.velocity_mps[-1:].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (offset * closing).sum(axis=-1) / np.linalg.norm(offset, axis=-1)


@_define("approaching_ego", "coming closer to the ego", {"min_mps": 0.5})
def _approaching(x: LogFeatures, p: Params) -> Mask:
    with np.errstate(invalid="ignore"):
        return _moving(x, p) & (_gap_rate(x) <= -GAP_RATE_MPS)


@_define("moving_away_from_ego", "moving away from the ego", {"min_mps": 0.5})
def _away(x: LogFeatures, p: Params) -> Mask:
    with np.errstate(invalid="ignore"):
        return _moving(x, p) & (_gap_rate(x) >= GAP_RATE_MPS)


def unanswerable(spec: Predicate, x: LogFeatures, params: Params) -> str | None:
    """Why ``spec`` has no answer on this log (no map; no recorded lighting or weather), or None."""
    if spec.needs_map and not x.has_map:
        return "needs a map, and the log has none"
    if spec.name == "appearance":
        missing = [key for key in ("time_of_day", "weather") if params[key] != "any" and getattr(x, key) == "unknown"]
        if missing:
            return f"needs the log's {' and '.join(missing).replace('_', ' ')}, which the log does not record"
    return None
