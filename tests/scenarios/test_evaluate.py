"""Programs on hand-built features: each family of predicate, relation and composition selects what it says."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scenarios import program as p
from scenarios.compiler import compile_description
from scenarios.evaluate import answer, evaluate
from scenarios.predicates import ProgramError
from scenarios.relations import RELATIONS, candidate_pairs, pair_geometry
from tests.scenarios.synthetic import car, cyclist, make_features, pedestrian

Y = 50.0  # the scene lies away from the ego at the origin


def selected(node: p.Node, features: object) -> np.ndarray:
    """(K,) which objects the node selects anywhere."""
    return evaluate(node, features).selection.mask.any(axis=1)  # type: ignore[arg-type]


def test_kinds_match_labels_and_fall_back_on_categories() -> None:
    x = make_features([car((0, Y)), {"label": "BUS", "category": "bus", "xy": (10, Y)},
                       {"label": "Car", "category": "car", "xy": (20, Y)}, cyclist((30, Y))])
    assert selected(p.Objects("vehicle"), x).tolist() == [True, True, True, False, False]
    assert selected(p.Objects("car"), x).tolist() == [True, False, True, False, False]
    assert selected(p.Objects("any"), x).tolist() == [True, True, True, True, False]
    assert selected(p.Objects("ego"), x).tolist() == [False] * 4 + [True]
    with pytest.raises(ProgramError, match="unknown kind 'unicorn'"):
        evaluate(p.Objects("unicorn"), x)


def test_predicates_read_flags_and_speeds() -> None:
    turning = np.zeros(20, bool)
    turning[5:9] = True
    x = make_features([car((0, Y), flags={"left_turn": turning}), car((10, Y), speed=0.0, flags=("parked",)),
                       car((20, Y), speed=0.1)])
    mask = evaluate(p.Is(p.Objects("car"), "turning", (("direction", "left"),)), x).selection.mask
    assert mask[0].tolist() == turning.tolist() and not mask[1:].any()
    assert selected(p.Is(p.Objects("car"), "parked"), x).tolist() == [False, True, False, False]
    # parked is not stopped
    assert selected(p.Is(p.Objects("car"), "stopped"), x).tolist() == [False, False, True, False]
    assert selected(p.Is(p.Objects("car"), "moving"), x).tolist() == [True, False, False, False]
    assert selected(p.Is(p.Objects("car"), "moving", negate=True), x).tolist() == [False, True, True, False]
    with pytest.raises(ProgramError, match=r"turning: direction='up' is not one of left, right, any"):
        evaluate(p.Is(p.Objects("car"), "turning", (("direction", "up"),)), x)


def test_reversing_is_a_metre_backwards_over_a_second_by_the_heading_at_both_ends() -> None:
    frames = 30
    t = np.arange(frames) / 10.0
    backing = np.stack([20.0 - 1.5 * t, np.full(frames, Y)], axis=-1)  # 1.5 m/s towards −x, facing +x
    forward = np.stack([1.5 * t, np.full(frames, Y + 10)], axis=-1)
    jitter = np.stack([-30 + 0.6 * (np.arange(frames) % 2), np.full(frames, Y + 20)], axis=-1)  # 6 m/s flicker
    flip = np.zeros(frames)
    flip[15] = np.pi  # the forward car's heading flips for one frame
    x = make_features([car(backing), car(forward, yaw=flip), car(jitter, speed=0.0)], frames=frames)
    mask = evaluate(p.Is(p.Objects("car"), "reversing"), x).selection.mask
    # Every frame whose 1-s window lies inside the log for 0.8 s or more: frames 3 to 26.
    assert np.flatnonzero(mask[0]).tolist() == list(range(3, 27))
    assert not mask[1:].any()
    # At 2 Hz the same motion over the same second (three frames) answers the same.
    slow = make_features([car(backing[::5])], frames=6)
    slow = dataclasses.replace(slow, timestamps_ns=slow.timestamps_ns[0] + np.arange(6, dtype=np.int64) * 500_000_000)
    slow_mask = evaluate(p.Is(p.Objects("car"), "reversing"), slow).selection.mask
    assert np.flatnonzero(slow_mask[0]).tolist() == [1, 2, 3, 4]
    assert not evaluate(p.Is(p.Objects("car"), "reversing", (("min_m", 2.0),)), x).selection.mask.any()


def test_about_to_cross_and_approaching_a_crosswalk_look_ahead_in_seconds() -> None:
    frames = 50
    on_lane = np.arange(frames) >= 40  # a walking pedestrian steps onto the lane at 4 s
    on_crosswalk = np.arange(frames) >= 45
    x = make_features([pedestrian((0, Y), flags={"on_lane": on_lane, "on_crosswalk": on_crosswalk})], frames=frames)
    about = evaluate(p.Is(p.Objects("pedestrian"), "about_to_cross"), x).selection.mask[0]
    assert np.flatnonzero(about).tolist() == list(range(10, 40))  # from 3 s before, until it crosses
    soon = evaluate(p.Is(p.Objects("pedestrian"), "approaching_crosswalk", (("within_s", 1.0),)), x).selection.mask[0]
    assert np.flatnonzero(soon).tolist() == list(range(35, 45))


def test_fast_and_slow_are_for_the_objects_kind() -> None:
    x = make_features([pedestrian((0, Y), speed=3.0), car((10, Y), speed=3.0), car((20, Y), speed=14.0),
                       cyclist((30, Y), speed=1.0), pedestrian((40, Y), speed=1.2)])
    assert selected(p.Is(p.Objects("any"), "fast"), x).tolist() == [True, False, True, False, False, False]
    assert selected(p.Is(p.Objects("any"), "slow"), x).tolist() == [False, False, False, True, False, False]


def test_map_predicates_on_a_log_without_a_map_say_so() -> None:
    x = make_features([car((0, Y), flags=("at_intersection",))], has_map=False)
    result = evaluate(p.Is(p.Objects("car"), "at_intersection"), x)
    assert not result.selection.mask.any()
    assert result.notes == ["synthetic: 'at_intersection' needs a map, and the log has none: no answer there "
                            "(not 'false')"]


def test_direction_with_distance_and_lateral_band() -> None:
    # The car heads +x: its right is −y. A cyclist 3 m to its right, another 3 m to its left, one 30 m right.
    x = make_features([car((0, Y)), cyclist((0, Y - 3)), cyclist((0, Y + 3)), cyclist((0, Y - 30))])
    right = p.Has(p.Objects("car"), "direction", p.Objects("cyclist"), (("side", "right"), ("within_m", 5.0)))
    result = evaluate(right, x).selection
    assert result.mask.any(axis=1).tolist() == [True, False, False, False, False]
    assert result.related.any(axis=1).tolist() == [False, True, False, False, False]
    wide = p.Has(p.Objects("car"), "direction", p.Objects("cyclist"), (("side", "right"),))
    assert evaluate(p.Has(p.Objects("car"), "direction", p.Objects("cyclist"), (("side", "right"),), min_count=2),
                    x).selection.mask.any()
    assert selected(wide, x)[0]
    reverse = p.Has(p.Objects("car"), "direction", p.Objects("cyclist"), (("side", "right"), ("within_m", 5.0)),
                  reverse=True)
    assert selected(reverse, x).tolist() == [False, True, False, False, False]
    assert not selected(p.Has(p.Objects("car"), "direction", p.Objects("cyclist"), (("side", "front"),)), x).any()


def test_counts_and_negation() -> None:
    x = make_features([car((0, Y)), pedestrian((2, Y + 3)), pedestrian((-2, Y + 3)), car((100, Y))])
    two = p.Has(p.Objects("car"), "near", p.Objects("pedestrian"), (("within_m", 5.0),), min_count=2)
    three = p.Has(p.Objects("car"), "near", p.Objects("pedestrian"), (("within_m", 5.0),), min_count=3)
    lonely = p.Has(p.Objects("car"), "near", p.Objects("pedestrian"), (("within_m", 5.0),), negate=True)
    assert selected(two, x).tolist() == [True, False, False, False, False]
    assert not selected(three, x).any()
    assert selected(lonely, x).tolist() == [False, False, False, True, False]
    assert selected(p.Together(p.Objects("pedestrian"), 2), x).tolist() == [False, True, True, False, False]
    assert not selected(p.Together(p.Objects("pedestrian"), 3), x).any()


def test_nearest_keeps_each_subjects_closest_others_at_each_frame() -> None:
    # Ahead of the ego in its lane: a car 10 m out, a braking one 20 m out, a third 30 m out that
    # overtakes the first two from frame 10 on (it moves to 5 m ahead).
    far = np.array([[30.0, 0.0]] * 10 + [[5.0, 0.0]] * 10)
    x = make_features([car((10, 0)), car((20, 0), flags={"braking"}), car(far)])
    ahead = (("side", "front"), ("lateral_m", 1.5))
    lead = p.Has(p.Objects("ego"), "direction", p.Objects("car"), ahead, reverse=True, nearest=1)
    mask = evaluate(lead, x).selection.mask
    assert mask[0, :10].all() and not mask[0, 10:].any()  # the nearest until the third comes closer
    assert mask[2, 10:].all() and not mask[2, :10].any()
    assert not mask[1].any()
    # Among the objects the other side selects: the nearest braking car is the second.
    braking = p.Has(p.Objects("ego"), "direction", p.Is(p.Objects("car"), "braking"), ahead, reverse=True, nearest=1)
    assert selected(braking, x).tolist() == [False, True, False, False]
    # Two nearest: the third car is never among them while it is the farthest.
    two = dataclasses.replace(lead, nearest=2)
    assert evaluate(two, x).selection.mask[:3].sum(axis=1).tolist() == [20, 10, 10]
    # The subject side counts only its nearest: at least two of them is at most what ``nearest`` keeps.
    with pytest.raises(ProgramError, match="nearest must be"):
        evaluate(dataclasses.replace(lead, reverse=False, min_count=2), x)


def test_crossing_and_passing_happen_around_their_moment() -> None:
    frames = 40  # 4 s; each event happens at 2 s and counts for 1 s either side
    across = np.stack([np.full(frames, 6.0), Y + np.linspace(4, -4, frames)], axis=1)  # 6 m ahead, left to right
    overtaking = np.stack([np.linspace(-10, 10, frames), np.full(frames, Y + 3.0)], axis=1)  # passes on the left
    x = make_features([car((0, Y)), pedestrian(across), car(overtaking, speed=10.0)], frames=frames)
    crossed = evaluate(p.Has(p.Objects("car"), "crossed_by", p.Objects("pedestrian")), x).selection.mask[0]
    assert crossed[19] and crossed[20] and not crossed[0] and not crossed[-1]
    left = p.Has(p.Objects("car"), "passed_by", p.Objects("car"), (("side", "left"),))
    passed = evaluate(left, x).selection.mask[0]
    assert passed[20] and not passed[0]
    right = p.Has(p.Objects("car"), "passed_by", p.Objects("car"), (("side", "right"),))
    assert not evaluate(right, x).selection.mask[0].any()
    # An oncoming car going by on the left: not overtaking, but passing either way.
    oncoming = make_features([car((0, Y)), car(overtaking[::-1], yaw=np.pi, speed=10.0)], frames=frames)
    assert not evaluate(left, oncoming).selection.mask[0].any()
    either = p.Has(p.Objects("car"), "passed_by", p.Objects("car"), (("side", "left"), ("way", "either")))
    assert evaluate(either, oncoming).selection.mask[0].tolist() == passed.tolist()
    # Yielding: crossed while slow. The car above moves at 5 m/s; one waiting at 1 m/s yields.
    yields = p.Has(p.Objects("car"), "yielding_to", p.Objects("pedestrian"))
    assert not evaluate(yields, x).selection.mask.any()
    waiting = make_features([car((0, Y), speed=1.0), pedestrian(across)], frames=frames)
    assert evaluate(yields, waiting).selection.mask[0].tolist() == crossed.tolist()


def test_between_following_same_lane_and_heading() -> None:
    x = make_features([pedestrian((0, Y)), car((0, Y + 3), lane=1), car((0, Y - 3), lane=1), car((15, Y + 3), lane=1),
                       car((-40, Y + 3), yaw=np.pi, lane=2)])
    assert selected(p.Between(p.Objects("pedestrian"), p.Objects("car"), p.Objects("car")), x)[0]
    assert not selected(p.Between(p.Objects("pedestrian"), p.Objects("car"), p.Objects("bus")), x).any()
    follows = selected(p.Has(p.Objects("car"), "following", p.Objects("car")), x)
    assert follows.tolist() == [False, True, False, False, False, False]  # the car 15 m behind the first
    shares = selected(p.Has(p.Objects("car"), "same_lane", p.Objects("car")), x)
    assert shares.tolist() == [False, True, True, True, False, False]
    opposite = selected(p.Has(p.Objects("car"), "heading", p.Objects("car"), (("way", "opposite"),)), x)
    assert opposite.tolist() == [False, True, True, False, True, False]  # within 50 m of the oncoming car


def test_heading_toward_and_away_from_another_object() -> None:
    """A pedestrian walking east with a bus 10 m behind it heads away from the bus; one walking west toward
    it heads toward it; a standing one does neither."""
    bus = {"label": "BUS", "category": "bus", "xy": (0, Y), "speed": 0.0, "size": (12.0, 2.5, 3.0)}
    x = make_features([bus, pedestrian((16, Y)), pedestrian((16, Y + 1), yaw=np.pi),
                       pedestrian((16, Y - 1), speed=0.0)])
    away = selected(p.Has(p.Objects("pedestrian"), "heading_away_from", p.Objects("bus")), x)
    toward = selected(p.Has(p.Objects("pedestrian"), "heading_toward", p.Objects("bus")), x)
    assert away.tolist() == [False, True, False, False, False]
    assert toward.tolist() == [False, False, True, False, False]
    left_behind = selected(p.Has(p.Objects("pedestrian"), "heading_away_from", p.Objects("bus"), reverse=True), x)
    assert left_behind.tolist() == [True, False, False, False, False]


def test_and_or_excluding() -> None:
    x = make_features([car((0, Y), flags=("braking",)), car((10, Y), flags=("parked",), speed=0.0), cyclist((20, Y))])
    braking, parked = p.Is(p.Objects("car"), "braking"), p.Is(p.Objects("car"), "parked")
    assert selected(p.AnyOf((braking, parked)), x).tolist() == [True, True, False, False]
    assert not selected(p.AllOf((braking, parked)), x).any()
    assert selected(p.Excluding(p.Objects("vehicle"), parked), x).tolist() == [True, False, False, False]


def test_a_least_distance_keeps_the_farther_objects() -> None:
    # Cars straight ahead, their rears 2.3, 7.3 and 70.3 m beyond the front of the ego's box (centred at 0).
    x = make_features([car((7.0, 0.0)), car((12.0, 0.0)), car((75.0, 0.0))])
    for description, expected in (("a car more than 5 m away", [False, True, True]),
                                  ("a car between 5 and 10 m from us", [False, True, False]),
                                  ("a car more than 60 m ahead of us", [False, False, True]),
                                  ("a car 5 to 10 m in front of the ego", [False, True, False])):
        assert selected(compile_description(description).program, x).tolist()[:3] == expected, description
    # Per pair: a bus with one car 3 m behind it and another 8 m behind has a car 5 to 10 m behind it; a
    # bus with one 3 m behind has not. (Buses 12 m long, cars 4.5 m.)
    bus = {"label": "BUS", "category": "bus", "speed": 5.0, "size": (12.0, 2.5, 3.0)}
    x = make_features([{**bus, "xy": (0.0, Y)}, car((-11.25, Y)), car((-16.25, Y)),
                       {**bus, "xy": (40.0, Y)}, car((28.75, Y))])
    behind = p.Has(p.Objects("bus"), "direction", p.Objects("car"),
                   (("side", "behind"), ("within_m", 10.0), ("beyond_m", 5.0)))
    result = evaluate(behind, x).selection
    assert result.mask.any(axis=1).tolist() == [True, False, False, False, False, False]
    assert result.related.any(axis=1).tolist() == [False, False, True, False, False, False]
    with pytest.raises(ProgramError, match="beyond_m=10 must be less than within_m=10"):
        evaluate(dataclasses.replace(behind, params=(("within_m", 10.0), ("beyond_m", 10.0))), x)


def test_then_while_and_for_at_least_on_features() -> None:
    frames = 30
    stopped = np.zeros(frames, bool)
    stopped[:10] = True
    waiting = np.zeros(frames, bool)
    waiting[20:] = True
    x = make_features([car((0, Y), flags={"stopped": stopped}, speed=np.where(stopped, 0.0, 5.0)),
                       cyclist((5, Y), speed=np.where(waiting, 0.0, 4.0))], frames=frames)
    drive_off = p.Then(p.Is(p.Objects("car"), "stopped"), p.Is(p.Objects("car"), "moving"), 0.5)
    mask = evaluate(drive_off, x).selection.mask[0]
    assert mask[9] and mask[10] and not mask[0] and not mask[-1]
    assert evaluate(p.ForAtLeast(p.Is(p.Objects("car"), "stopped"), 1.0), x).selection.mask[0].sum() == 10
    assert not evaluate(p.ForAtLeast(p.Is(p.Objects("car"), "stopped"), 1.5), x).selection.mask.any()
    while_waiting = evaluate(p.While(p.Objects("car"), p.Is(p.Objects("cyclist"), "stopped")), x).selection
    assert while_waiting.mask[0].tolist() == waiting.tolist()
    assert while_waiting.related[1].tolist() == waiting.tolist()


def test_one_objects_moment_before_or_after_another_objects_event() -> None:
    # At 10 Hz: the car drives, stops over frames 5–14 (from 0.5 s) and drives off at 1.5 s; the cyclist
    # waits from frame 25 (2.5 s) on; a pedestrian walks all along.
    frames = 40
    stopped = (np.arange(frames) >= 5) & (np.arange(frames) < 15)
    waiting = np.arange(frames) >= 25
    x = make_features([car((0, Y), flags={"stopped": stopped}, speed=np.where(stopped, 0.0, 5.0)),
                       cyclist((5, Y), speed=np.where(waiting, 0.0, 4.0)), pedestrian((9, Y))], frames=frames)
    car_stops, cyclist_waits = p.Is(p.Objects("car"), "stopped"), p.Is(p.Objects("cyclist"), "stopped")
    # What counts is when each begins: the car's stop at 0.5 s, the cyclist's wait at 2.5 s.
    before = evaluate(p.Sequenced(car_stops, cyclist_waits, 2.5), x).selection
    assert np.flatnonzero(before.mask[0]).tolist() == list(range(5, 15))  # the car's whole stop
    assert np.flatnonzero(before.related[1]).tolist() == list(range(25, 40))  # the cyclist's whole wait
    assert not before.mask[1].any()  # related, not referred
    assert not evaluate(p.Sequenced(car_stops, cyclist_waits, 1.5), x).selection.mask.any()
    after = evaluate(p.Sequenced(cyclist_waits, car_stops, 2.5, after=True), x).selection
    assert np.flatnonzero(after.mask[1]).tolist() == list(range(25, 40))
    assert np.flatnonzero(after.related[0]).tolist() == list(range(5, 15))
    assert not evaluate(p.Sequenced(car_stops, cyclist_waits, 2.5, after=True), x).selection.mask.any()
    # A state held since the object came into view has no beginning: it follows and precedes nothing.
    walks = p.Is(p.Objects("pedestrian"), "moving")
    for after_ in (False, True):
        assert not evaluate(p.Sequenced(cyclist_waits, walks, 5.0, after_), x).selection.mask.any()
    # A sequence begins where its second step does: the car drives off at 1.5 s, 1 s before the wait;
    # so does a sequence under a filter.
    drive_off = p.Then(car_stops, p.Is(p.Objects("car"), "moving"), 4.0)
    assert evaluate(p.Sequenced(drive_off, cyclist_waits, 1.5), x).selection.mask[0].any()
    assert not evaluate(p.Sequenced(drive_off, cyclist_waits, 0.5), x).selection.mask.any()
    assert not evaluate(p.Sequenced(drive_off, cyclist_waits, 5.0, after=True), x).selection.mask.any()
    assert evaluate(p.Sequenced(p.ForAtLeast(drive_off, 1.0), cyclist_waits, 1.5), x).selection.mask[0].any()
    assert not evaluate(p.Sequenced(p.ForAtLeast(drive_off, 1.0), cyclist_waits, 0.5), x).selection.mask.any()


def test_answer_marks_referred_and_related_apart() -> None:
    x = make_features([car((0, Y)), cyclist((0, Y - 3))])
    result, notes = answer(p.Has(p.Objects("car"), "direction", p.Objects("cyclist"), (("side", "right"),)), x, "d")
    assert notes == [] and result.description == "d"
    assert result.referred_mask.any(axis=1).tolist() == [True, False, False]
    assert result.related.any(axis=1).tolist() == [False, True, False]
    assert not (result.related & result.referred_mask).any()
    assert result.categories.tolist() == ["REGULAR_VEHICLE", "BICYCLIST", "EGO_VEHICLE"]
    assert result.center_city_xyz_m.shape == (3, 20, 3) and result.ego_city_xyz_m.shape == (20, 3)


def test_a_negated_relation_with_no_other_object_keeps_every_subject() -> None:
    """"car without a pedestrian near it" where the log has no pedestrian: every car."""
    x = make_features([car((0, Y)), car((100, Y))])
    lonely = p.Has(p.Objects("car"), "near", p.Objects("pedestrian"), (("within_m", 5.0),), negate=True)
    assert selected(lonely, x).tolist() == [True, True, False]


@pytest.mark.parametrize("relation", sorted(RELATIONS))
def test_pairs_left_out_as_too_far_apart_never_hold(relation: str) -> None:
    """The coarse test of candidate_pairs is conservative: on random scenes, a relation holds on no pair
    it leaves out (the relation computed on every pair is the reference)."""
    rng = np.random.default_rng(7)
    spec = RELATIONS[relation]
    params = spec.resolve({})
    for _ in range(5):
        frames = 30
        start = rng.uniform(-80, 80, (12, 2))
        step = rng.uniform(-2, 2, (12, 2))
        objects = [car(start[i] + np.arange(frames)[:, None] * step[i], yaw=float(rng.uniform(-np.pi, np.pi)),
                       lane=int(rng.integers(0, 3))) for i in range(12)]
        x = make_features(objects, frames=frames)
        every = np.arange(x.num_objects)
        s_all, o_all = np.repeat(every, every.size), np.tile(every, every.size)
        holds = spec.fn(pair_geometry(x, s_all, o_all), params).any(axis=1)
        s_kept, o_kept = candidate_pairs(x, every, every, spec.reach_m(params))
        kept = set(zip(s_kept.tolist(), o_kept.tolist()))
        assert {(s, o) for s, o, h in zip(s_all.tolist(), o_all.tolist(), holds) if h} <= kept


def test_notes_of_many_logs_are_said_once_per_reason() -> None:
    from scenarios.evaluate import grouped_notes

    said = [(f"log{i}", f"log{i}: 'on_crosswalk' needs a map") for i in range(6)] + [("log2", "log2: no weather")]
    assert grouped_notes(said) == ("log0, log1, log2 and 3 more logs: 'on_crosswalk' needs a map", "log2: no weather")
    assert grouped_notes(said[:4]) == ("log0, log1, log2, log3: 'on_crosswalk' needs a map",)


def test_crossing_from_left_to_right_in_front_of_us_tells_the_two_ways_apart() -> None:
    from scenarios.compiler import compile_description

    across = np.linspace(6.0, -6.0, 40)  # 4 s at 10 Hz, 10 m ahead: from our left to our right
    left_to_right = np.stack([np.full(40, 10.0), across], axis=1)
    right_to_left = np.stack([np.full(40, 14.0), across[::-1]], axis=1)
    x = make_features([pedestrian(left_to_right, flags=("on_lane",), yaw=-np.pi / 2, speed=3.0),
                       pedestrian(right_to_left, flags=("on_lane",), yaw=np.pi / 2, speed=3.0),
                       pedestrian(np.stack([np.full(40, 30.0), np.full(40, 4.0)], axis=1), flags=("on_lane",))],
                      frames=40)
    ways = {text: selected(compile_description(text).program, x).tolist()
            for text in ("a pedestrian crossing from left to right in front of us",
                         "pedestrians crossing from the right to the left")}
    assert ways == {"a pedestrian crossing from left to right in front of us": [True, False, False, False],
                    "pedestrians crossing from the right to the left": [False, True, False, False]}
