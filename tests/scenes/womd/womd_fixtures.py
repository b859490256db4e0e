"""Tiny synthetic WOMD scenarios for the tests: built with the importer's own schema, so every value
is known."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scenes.womd.proto import message_class
from scenes.womd.tfrecord import encode_record


@dataclass
class TrackSpec:
    """One track: (T, 2) xy, heading per step, size, validity."""

    track_id: int
    object_type: int
    xy: np.ndarray
    heading: np.ndarray
    size_lwh: tuple[float, float, float] = (4.5, 2.0, 1.6)
    z: float = 0.8
    valid: np.ndarray | None = None


@dataclass
class ScenarioSpec:
    scenario_id: str = "abc123"
    times_s: np.ndarray = field(default_factory=lambda: np.arange(5) * 0.1)
    tracks: list[TrackSpec] = field(default_factory=list)
    sdc_index: int | None = 0
    map_features: list[dict[str, Any]] = field(default_factory=list)


def default_spec() -> ScenarioSpec:
    """An ego driving +x at 10 m/s, a car 10 m ahead and 3.5 m left going the same way, a pedestrian
    invalid at step 2, and a map: one straight lane with a road line on its left and a road edge on
    its right, one crosswalk and one road edge."""
    t = np.arange(5) * 0.1
    ego_xy = np.stack([100.0 + 10.0 * t, np.full(5, 50.0)], axis=1)
    car_xy = ego_xy + np.array([10.0 + 1.4, 3.5])
    ped_xy = np.stack([np.full(5, 120.0), 45.0 + 1.2 * t], axis=1)
    ped_valid = np.array([True, True, False, True, True])
    lane = [(x, 50.0, 0.0) for x in np.arange(80.0, 141.0, 5.0)]
    line = [(x, 51.7, 0.0) for x in np.arange(80.0, 141.0, 5.0)]
    edge = [(x, 47.0, 0.0) for x in np.arange(60.0, 161.0, 5.0)]  # longer than the lane: a kerb to wrap around
    n = len(lane)
    return ScenarioSpec(
        times_s=t,
        tracks=[
            TrackSpec(7, 1, ego_xy, np.zeros(5), (5.0, 2.2, 1.8), z=0.9),
            TrackSpec(8, 1, car_xy, np.zeros(5)),
            TrackSpec(9, 2, ped_xy, np.full(5, np.pi / 2), (0.6, 0.6, 1.7), valid=ped_valid),
        ],
        map_features=[
            {"id": 1, "lane": {"polyline": lane, "type": 2,
                               "left_boundaries": [(0, n - 1, 2, 6)], "right_boundaries": [(0, n - 1, 3, 0)]}},
            {"id": 2, "road_line": {"type": 6, "polyline": line}},
            {"id": 3, "road_edge": {"type": 1, "polyline": edge}},
            {"id": 4, "crosswalk": {"polygon": [(118, 46, 0), (118, 54, 0), (122, 54, 0), (122, 46, 0)]}},
            {"id": 5, "stop_sign": {"position": (117, 46, 0)}},
        ],
    )


def _set_points(container: Any, points: list[tuple[float, float, float]]) -> None:
    for x, y, z in points:
        p = container.add()
        p.x, p.y, p.z = float(x), float(y), float(z)


def build_scenario(spec: ScenarioSpec) -> Any:
    scenario = message_class("Scenario")()
    if spec.scenario_id:
        scenario.scenario_id = spec.scenario_id
    scenario.timestamps_seconds.extend(float(v) for v in spec.times_s)
    scenario.current_time_index = 1
    if spec.sdc_index is not None:
        scenario.sdc_track_index = spec.sdc_index
    for track in spec.tracks:
        msg = scenario.tracks.add()
        msg.id = track.track_id
        msg.object_type = track.object_type
        valid = np.ones(len(track.xy), bool) if track.valid is None else track.valid
        for (x, y), heading, ok in zip(track.xy, track.heading, valid):
            state = msg.states.add()
            state.center_x, state.center_y, state.center_z = float(x), float(y), track.z
            state.length, state.width, state.height = track.size_lwh
            state.heading = float(heading)
            state.valid = bool(ok)
    for feature in spec.map_features:
        msg = scenario.map_features.add()
        msg.id = feature["id"]
        if "lane" in feature:
            lane = feature["lane"]
            msg.lane.type = lane.get("type", 2)
            _set_points(msg.lane.polyline, lane["polyline"])
            msg.lane.entry_lanes.extend(lane.get("entry", []))
            msg.lane.exit_lanes.extend(lane.get("exit", []))
            for side in ("left_boundaries", "right_boundaries"):
                for start, end, fid, btype in lane.get(side, []):
                    b = getattr(msg.lane, side).add()
                    b.lane_start_index, b.lane_end_index = start, end
                    b.boundary_feature_id, b.boundary_type = fid, btype
        for kind in ("road_line", "road_edge"):
            if kind in feature:
                getattr(msg, kind).type = feature[kind]["type"]
                _set_points(getattr(msg, kind).polyline, feature[kind]["polyline"])
        if "crosswalk" in feature:
            _set_points(msg.crosswalk.polygon, feature["crosswalk"]["polygon"])
        if "driveway" in feature:
            _set_points(msg.driveway.polygon, feature["driveway"]["polygon"])
        if "stop_sign" in feature:
            x, y, z = feature["stop_sign"]["position"]
            msg.stop_sign.position.x, msg.stop_sign.position.y, msg.stop_sign.position.z = x, y, z
    return scenario


def write_tfrecord(path: Path, scenarios: list[Any] | list[bytes]) -> Path:
    """Frame each scenario (a message or raw bytes) as one record of ``path``."""
    payloads = [s if isinstance(s, bytes) else s.SerializeToString() for s in scenarios]
    path.write_bytes(b"".join(encode_record(p) for p in payloads))
    return path
