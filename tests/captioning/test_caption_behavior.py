"""Own behaviour and map context from tracks and a hand-built map, with and without the map."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from captioning.behavior import NO_MAP_NOTE, SKIP_SHORT, BehaviorTags
from captioning.config import CaptioningConfig
from captioning.map_context import JUNCTION_KINDS, junction_kind_codes, lookup, rasterize_map
from captioning.pipeline import LogCaptions, caption_arrays
from captioning.unify import collapse
from scenes.behavior import BehaviorLabel, JunctionKind
from scenes.map import LaneSegment, PedestrianCrossing, VectorMap

from .conftest import Scene

T = 120  # 12 s at 10 Hz
DT = 0.1
W = 3.5  # lane width


def lane(lane_id: int, start: tuple[float, float], end: tuple[float, float], width: float = W,
         intersection: bool = False, **links: object) -> LaneSegment:
    """A straight lane from ``start`` to ``end`` (its boundaries ``width / 2`` either side)."""
    a, b = np.array(start, float), np.array(end, float)
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]]) * width / 2
    left = np.array([[*(a + n), 0.0], [*(b + n), 0.0]])
    right = np.array([[*(a - n), 0.0], [*(b - n), 0.0]])
    return LaneSegment(lane_id, intersection, "VEHICLE", left, right, **links)  # type: ignore[arg-type]


def city_map(arms: int = 4) -> VectorMap:
    """Two eastbound lanes (1 right, 2 left) into a 20 m × 20 m junction at x 0..20, roads leaving east
    (3), north (4) and, for four arms, coming from the south (5); a crosswalk across both lanes."""
    lanes = {
        1: lane(1, (-120, 0), (0, 0), left_neighbor_id=2, successors=(10,)),
        2: lane(2, (-120, W), (0, W), right_neighbor_id=1, successors=(10,)),
        3: lane(3, (20, 0), (120, 0), predecessors=(10,)),
        4: lane(4, (10, 10), (10, 120), predecessors=(10,)),
    }
    if arms == 4:
        lanes[5] = lane(5, (10, -120), (10, -10), successors=(10,))
    entering = (1, 2, 5) if arms == 4 else (1, 2)
    lanes[10] = lane(10, (0, 0), (20, 0), width=20.0, intersection=True, predecessors=entering, successors=(3, 4))
    crossing = PedestrianCrossing(1, np.array([[-6.0, -2.0, 0.0], [-6.0, 6.0, 0.0]]),
                                  np.array([[-2.0, -2.0, 0.0], [-2.0, 6.0, 0.0]]))
    return VectorMap(lanes, {1: crossing})


def _track(x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
    xy = np.stack([x, y], axis=1)
    v = np.gradient(xy, axis=0)
    yaw = np.arctan2(v[:, 1], v[:, 0])
    moving = np.hypot(v[:, 0], v[:, 1]) > 1e-6
    yaw = np.where(moving, yaw, np.nan)
    first = yaw[np.isfinite(yaw)][0] if np.isfinite(yaw).any() else 0.0
    # Headings of standing frames: the last heading while moving (a box keeps its orientation).
    filled = np.array([first, *yaw[1:]])
    for i in range(1, len(filled)):
        if not np.isfinite(filled[i]):
            filled[i] = filled[i - 1]
    return xy, filled


def braking_profile(x0: float, v0: float, start_s: float, decel: float) -> NDArray:
    """Positions of a vehicle driving at ``v0`` that brakes at ``decel`` from ``start_s`` to a stop."""
    t = np.arange(T) * DT
    tb = np.clip(t - start_s, 0.0, v0 / decel)
    return x0 + v0 * np.minimum(t, start_s) + v0 * tb - 0.5 * decel * tb**2


def scene() -> tuple[Scene, NDArray]:
    """Tracks named after what they do; returns the scene and (K, T) box lengths."""
    t = np.arange(T) * DT
    s = Scene(ego_xy_m=np.tile([-100.0, -60.0], (T, 1)), ego_yaw_rad=np.zeros(T))
    still = np.ones(T)
    s.add("parked", "car", np.stack([-60 * still, -4.5 * still], 1), 0.0)
    s.add("queued", "car", np.stack([-30 * still, 0 * still], 1), 0.0)
    s.add("blocked", "car", np.stack([-36.5 * still, 0 * still], 1), 0.0)
    # Lane change to the left between 3 s and 6 s, at 8 m/s.
    y = np.clip((t - 3.0) / 3.0, 0, 1) * W
    xy, yaw = _track(-110 + 8 * t, y)
    s.add("changer", "car", xy, yaw)
    # Left turn: east along the left lane, a quarter circle inside the junction, then north.
    r = 6.5
    path_s = 8 * t
    straight = 40.0
    arc = np.pi / 2 * r
    phi = np.clip((path_s - straight) / r, 0, np.pi / 2)
    x = np.where(path_s < straight, -40 + path_s, r * np.sin(phi))
    y = np.where(path_s < straight, W, W + r * (1 - np.cos(phi)))
    after = np.maximum(path_s - straight - arc, 0)
    x, y = np.where(after > 0, r, x), np.where(after > 0, W + r + after, y)
    xy, yaw = _track(x, y)
    s.add("turner", "car", xy, yaw)
    xy, yaw = _track(braking_profile(-100, 12.0, 2.0, 4.0), 0 * t)
    s.add("braker", "car", xy, yaw)
    s.add("walker", "pedestrian", np.stack([-4 * still, 2 * still], 1), 0.0)
    lengths = np.array([0.5 if c == "pedestrian" else 4.5 for _, c, *_ in s.objects])[:, None] * np.ones(T)
    return s, lengths


def caption(vector_map: VectorMap | None, config: CaptioningConfig | None = None) -> LogCaptions:
    s, lengths = scene()
    return caption_arrays(config=config or CaptioningConfig(), vector_map=vector_map, length_m=lengths,
                          **s.arrays())  # type: ignore[arg-type]


def flags(result: LogCaptions, track: str, label: BehaviorLabel) -> NDArray[np.bool_]:
    beh = result.behavior
    assert isinstance(beh, BehaviorTags)
    k = list(result.track_ids).index(track)
    return beh.flag(label)[k]


def share(values: NDArray[np.bool_]) -> float:
    return float(np.mean(values))


@pytest.fixture(scope="module")
def with_map() -> LogCaptions:
    return caption(city_map())


def test_parked_off_the_lanes_stopped_in_a_lane(with_map: LogCaptions) -> None:
    assert share(flags(with_map, "parked", BehaviorLabel.PARKED)) == 1.0
    assert not flags(with_map, "parked", BehaviorLabel.STOPPED).any()
    for track in ("queued", "blocked"):
        assert share(flags(with_map, track, BehaviorLabel.STOPPED)) == 1.0
        assert not flags(with_map, track, BehaviorLabel.PARKED).any()
    # A pedestrian can stand, never park.
    assert share(flags(with_map, "walker", BehaviorLabel.STOPPED)) == 1.0
    assert not flags(with_map, "walker", BehaviorLabel.PARKED).any()


def test_braking_then_stopped(with_map: LogCaptions) -> None:
    braking = flags(with_map, "braker", BehaviorLabel.BRAKING)
    # Brakes from 2.0 s to 5.0 s; smoothing blurs the ends by a few frames.
    assert braking[25:45].all() and not braking[:15].any() and not braking[60:].any()
    assert flags(with_map, "braker", BehaviorLabel.STOPPED)[60:].all()
    # Braking for the blocked car ahead (slower, within 3 s of headway) early in its braking: at 2.2 s
    # it is 33 m behind at 11 m/s; at 3 s, 25 m behind at 8 m/s (beyond 3 s × 8 m/s).
    braking_for = flags(with_map, "braker", BehaviorLabel.BRAKING_FOR)
    assert braking_for[21:26].all() and not braking_for[32:].any()


def test_blocked_by_the_vehicle_ahead_in_the_lane(with_map: LogCaptions) -> None:
    assert share(flags(with_map, "blocked", BehaviorLabel.BLOCKED_BY)) == 1.0
    assert not flags(with_map, "queued", BehaviorLabel.BLOCKED_BY).any()  # nothing ahead of it
    assert not flags(with_map, "parked", BehaviorLabel.BLOCKED_BY).any()


def test_lane_change_and_keeping_the_lane(with_map: LogCaptions) -> None:
    left = flags(with_map, "changer", BehaviorLabel.LEFT_LANE_CHANGE)
    assert left[35:55].all() and not left[:25].any() and not left[70:].any()
    assert not flags(with_map, "changer", BehaviorLabel.RIGHT_LANE_CHANGE).any()
    keeping = flags(with_map, "changer", BehaviorLabel.KEEPING_LANE)
    assert keeping[5:25].all() and keeping[75:110].all() and not (keeping & left).any()


def test_left_turn_inside_the_junction_only(with_map: LogCaptions) -> None:
    turn = flags(with_map, "turner", BehaviorLabel.LEFT_TURN)
    beh = with_map.behavior
    assert beh is not None
    k = list(with_map.track_ids).index("turner")
    inside = beh.at_intersection[k]
    assert inside.sum() >= 10
    assert (turn == inside).all()
    assert not flags(with_map, "turner", BehaviorLabel.RIGHT_TURN).any()
    assert not flags(with_map, "turner", BehaviorLabel.KEEPING_LANE)[inside].any()
    assert {JUNCTION_KINDS[c].value for c in beh.junction_kind[k][inside]} == {"four_way"}


def test_context_columns_and_caption_attributes(with_map: LogCaptions) -> None:
    frames = with_map.frame_tags_table()
    rows = [r for r in frames.to_pylist() if r["track_id"] == "walker"]
    assert all(r["on_crosswalk"] and r["stopped"] and r["parked"] is False for r in rows)
    ego = [r for r in frames.to_pylist() if r["track_id"] == "ego"]
    assert all(r["parked"] is None and r["speed_mps"] is None for r in ego)
    by_track = {c.track_id: c for c in with_map.captions}
    # Stationary objects are captioned too, as parked or stopped.
    assert by_track["parked"].attributes is not None and by_track["parked"].attributes["parked"] is True
    assert "is parked" in by_track["parked"].canonical_caption
    assert any(t.endswith(":stopped:on_crosswalk") for t in by_track["walker"].tags)
    assert by_track["turner"].attributes is not None and by_track["turner"].attributes["left_turn"] is True
    assert by_track["turner"].attributes["junction_kind"] == "four_way"
    table = with_map.captions_table()
    assert {"braking", "parked", "junction_kind", "at_intersection"} <= set(table.column_names)


def test_frame_action_and_context_collapse_into_each_caption(with_map: LogCaptions) -> None:
    """frame_tags.parquet's action and context are what each frame's unified tag carries: a caption's
    tags are its frames' lane:motion[:action][:context] collapsed, so a dense head can learn when a step
    that differs in its action alone ("moves away, then moves away braking") holds."""
    rows = with_map.frame_tags_table().to_pylist()
    assert all(r["action"] is None and r["context"] is None for r in rows if r["track_id"] == "ego")
    assert all((r["action"] is None) == (r["lane"] is None) for r in rows if r["track_id"] != "ego")
    checked = 0
    for cap in with_map.captions:
        if cap.track_id == "ego":
            continue
        frames = [r for r in rows if r["track_id"] == cap.track_id and r["lane"] is not None
                  and cap.start_ns <= r["timestamp_ns"] <= cap.end_ns]
        steps = [":".join([r["lane"], r["motion"], *(x for x in (r["action"], r["context"]) if x != "none")])
                 for r in frames]
        assert collapse(steps) == list(cap.tags), cap.track_id
        checked += 1
    assert checked >= 4
    actions = {r["action"] for r in rows} - {None}
    assert {"none", "braking", "stopped"} <= actions and "on_crosswalk" in {r["context"] for r in rows}


def test_filters_read_the_new_columns(with_map: LogCaptions) -> None:
    from indexes.filters import compile_mask

    table = with_map.captions_table()
    braking = compile_mask(table, "braking == true")
    assert set(np.asarray(table.column("track_id"))[braking]) == {"braker"}
    tag = next(c.tags[0] for c in with_map.captions if c.track_id == "parked")
    assert tag.endswith(":parked")
    parked = compile_mask(table, f"tags contains '{tag}' and parked == true")
    assert set(np.asarray(table.column("track_id"))[parked]) == {"parked"}


def test_junction_kinds_from_the_map() -> None:
    for arms, kind in ((4, JunctionKind.FOUR_WAY), (3, JunctionKind.THREE_WAY)):
        points = np.array([[-100.0, 0.0], [60.0, 60.0]])
        raster = rasterize_map(city_map(arms), points, CaptioningConfig().map)
        assert raster is not None
        found = lookup(raster, np.array([[10.0, 0.0], [-15.0, 0.0], [-50.0, 0.0], [60.0, 0.0]]))
        codes = junction_kind_codes(raster, found, approach_m=20.0)
        # Inside; 15 m before on a lane entering it; 50 m before; on a lane leaving it.
        assert [JUNCTION_KINDS[c] if c >= 0 else None for c in codes] == [kind, kind, None, None]
        assert found.lane[2] == 0 and abs(found.lateral_m[2]) < 1e-9  # on lane 1's centre line


def test_without_a_map_lane_tags_are_null_and_said_once() -> None:
    result = caption(None)
    assert result.notes == [NO_MAP_NOTE]
    frames = result.frame_tags_table().to_pylist()
    objects = [r for r in frames if r["track_id"] != "ego"]
    assert all(r["keeping_lane"] is None and r["left_lane_change"] is None for r in objects)
    assert all(r["at_intersection"] is None and r["junction_kind"] is None for r in objects)
    assert all(r["stopped"] is not None and r["braking"] is not None for r in objects)
    # Geometry still tells braking, and a vehicle standing over its whole (long) track is parked.
    assert flags(result, "braker", BehaviorLabel.BRAKING)[25:45].all()
    assert share(flags(result, "parked", BehaviorLabel.PARKED)) == 1.0
    # The turn comes from the yaw rate.
    assert flags(result, "turner", BehaviorLabel.LEFT_TURN).sum() >= 5


def test_tracks_too_short_for_a_derivative_are_reported() -> None:
    s, lengths = scene()
    valid = np.zeros(T, bool)
    valid[10:13] = True  # three frames: differentiable, too short for own behaviour
    s.add("glimpse", "car", np.tile([-20.0, 0.0], (T, 1)), 0.0, valid)
    lengths = np.vstack([lengths, np.full((1, T), 4.5)])
    result = caption_arrays(config=CaptioningConfig(), vector_map=city_map(), length_m=lengths,
                            **s.arrays())  # type: ignore[arg-type]
    assert result.skipped_tracks == {"glimpse": SKIP_SHORT.format(seconds=0.5, frames=5, rate="10 Hz")}
    assert result.skipped_tracks["glimpse"] == ("no run of 0.5 s (5 frames at 10 Hz) of observed frames for "
                                                "own-behaviour tags (behavior.min_run_s)")
    assert not flags(result, "glimpse", BehaviorLabel.STOPPED).any()
    rows = [r for r in result.frame_tags_table().to_pylist() if r["track_id"] == "glimpse"]
    assert len(rows) == 3 and all(r["stopped"] is None for r in rows)


def test_many_polylines_resample_as_one_at_a_time() -> None:
    from captioning.map_context import _resample_many
    from scenes.map import resample_polyline

    rng = np.random.default_rng(3)
    lines = [np.cumsum(rng.normal(0, 2, (n, 3)), axis=0) for n in (1, 2, 5, 9)] + [np.zeros((3, 3))]
    wanted = np.array([4, 2, 7, 3, 5])
    got = _resample_many(np.concatenate(lines), np.array([len(p) for p in lines]), wanted)
    expected = np.concatenate([resample_polyline(p, n) for p, n in zip(lines, wanted)])
    np.testing.assert_allclose(got, expected, atol=1e-9)
