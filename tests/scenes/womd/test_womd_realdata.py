"""The WOMD development scenario in ../shared/realdata: what the importer parses equals the decoded
CSV/JSON of the same scenario, the imported log puts every box back where WOMD had it, and it
validates, captions and cuts into clips like any log."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from retrieval.cli import main as cli_main
from scenes.geometry import quat_to_yaw, wrap_angle_rad
from scenes.log import Log
from scenes.womd import (
    EGO_BOX_CENTER_AHEAD_M,
    ScenarioTracks,
    import_womd_files,
    parse_scenario,
    read_records,
    scenario_tracks,
    womd_map_from_features,
)
from scenes.womd.proto import MAP_FEATURE_KINDS, ObjectType
from scenes.womd.roadmap import MAX_HALF_WIDTH_M
from tests.realdata import REALDATA

WOMD = REALDATA / "womd"
DEV_FILE = WOMD / "womd_scenario_input.tfrecord"
DEV_ID = "ee519cf571686d19"
DECODED_TRACKS = WOMD / "decoded" / f"{DEV_ID}_tracks.csv"
DECODED_MAP = WOMD / "decoded" / f"{DEV_ID}_map.json"


def _require() -> None:
    for path in (DEV_FILE, DECODED_TRACKS, DECODED_MAP):
        if not path.is_file():
            pytest.skip(f"WOMD development data not found at {path} (the shared realdata folder is absent)")


@pytest.fixture(scope="module")
def scenario() -> Any:
    _require()
    (record,) = list(read_records(DEV_FILE))
    return parse_scenario(record.data)


@pytest.fixture(scope="module")
def tracks(scenario: Any) -> ScenarioTracks:
    return scenario_tracks(scenario, DEV_FILE, 0)


@pytest.fixture(scope="module")
def decoded() -> dict[str, np.ndarray]:
    """The decoded CSV as (K, T) arrays in track-index, step order."""
    _require()
    with DECODED_TRACKS.open() as f:
        rows = list(csv.DictReader(f))
    k = max(int(r["track_index"]) for r in rows) + 1
    t = max(int(r["step"]) for r in rows) + 1
    out: dict[str, np.ndarray] = {}
    for name in ("track_id", "is_sdc", "t_s", "center_x", "center_y", "center_z", "length", "width", "height",
                 "heading", "velocity_x", "velocity_y", "valid"):
        grid = np.full((k, t), np.nan)
        for r in rows:
            grid[int(r["track_index"]), int(r["step"])] = float(r[name])
        out[name] = grid
    types = np.empty(k, dtype=object)
    for r in rows:
        types[int(r["track_index"])] = r["object_type"]
    out["object_type"] = types
    return out


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    _require()
    out = tmp_path_factory.mktemp("womd_logs")
    batch = import_womd_files([DEV_FILE], out)
    assert batch.skipped == [], batch.skipped
    (report,) = batch.imported
    return report.log_dir


def test_parsed_tracks_equal_the_decoded_csv(tracks: ScenarioTracks, decoded: dict[str, np.ndarray]) -> None:
    assert tracks.scenario_id == DEV_ID
    assert tracks.valid.shape == decoded["valid"].shape == (257, 91)
    np.testing.assert_array_equal(tracks.track_ids, decoded["track_id"][:, 0])
    assert [ObjectType(int(t)).name for t in tracks.object_types] == list(decoded["object_type"])
    assert decoded["is_sdc"][tracks.sdc_index].all() and decoded["is_sdc"].sum() == 91
    np.testing.assert_array_equal(tracks.valid, decoded["valid"] > 0.5)
    np.testing.assert_allclose(tracks.timestamps_ns * 1e-9, decoded["t_s"][0], atol=6e-4)
    for k, name in enumerate(("center_x", "center_y", "center_z")):
        np.testing.assert_allclose(tracks.center_xyz_m[..., k], decoded[name], atol=6e-5)
    for k, name in enumerate(("length", "width", "height")):
        np.testing.assert_allclose(tracks.size_lwh_m[..., k], decoded[name], atol=6e-5)
    np.testing.assert_allclose(tracks.heading_rad, decoded["heading"], atol=6e-5)
    np.testing.assert_allclose(tracks.velocity_xy_mps[..., 0], decoded["velocity_x"], atol=6e-5)
    np.testing.assert_allclose(tracks.velocity_xy_mps[..., 1], decoded["velocity_y"], atol=6e-5)
    assert tracks.current_time_index == 10


def test_parsed_map_equals_the_decoded_json(scenario: Any) -> None:
    expected = json.loads(DECODED_MAP.read_text())
    assert scenario.sdc_track_index == expected["sdc_track_index"]
    by_id = {f["id"]: f for f in expected["map_features"]}
    assert len(by_id) == len(scenario.map_features) == 215
    for feature in scenario.map_features:
        kind = feature.WhichOneof("feature_data")
        assert kind in MAP_FEATURE_KINDS
        want = by_id[feature.id]
        assert want["kind"] == kind
        body = getattr(feature, kind)
        if kind == "stop_sign":
            points = [body.position]
        else:
            points = body.polygon if kind in ("crosswalk", "speed_bump", "driveway") else body.polyline
        np.testing.assert_allclose([(p.x, p.y, p.z) for p in points], want["points"], atol=6e-4)
        if "type" in want:
            assert body.type == want["type"]
        if kind == "lane":
            assert body.speed_limit_mph == pytest.approx(want["speed_limit_mph"])
    womd = womd_map_from_features(scenario.map_features)
    assert (len(womd.lanes), len(womd.road_edges), len(womd.road_lines), len(womd.crosswalks)) == (114, 75, 12, 4)
    assert womd.other_counts == {"speed_bump": 6, "stop_sign": 4}


def test_imported_log_holds_valid_states_where_womd_had_them(
    imported: Path, tracks: ScenarioTracks, decoded: dict[str, np.ndarray]
) -> None:
    log = Log.open(imported)
    sdc = tracks.sdc_index
    # Ego: the SDC's box centre, moved back to the rear axle, at every step the SDC is valid.
    assert len(log.ego) == int(decoded["valid"][sdc].sum()) == 91
    heading = decoded["heading"][sdc]
    centre = log.ego.translation_m[:, :2] + EGO_BOX_CENTER_AHEAD_M * np.stack([np.cos(heading), np.sin(heading)], 1)
    np.testing.assert_allclose(centre, np.stack([decoded["center_x"][sdc], decoded["center_y"][sdc]], 1), atol=1e-4)
    np.testing.assert_allclose(wrap_angle_rad(log.ego.yaw_rad - heading), 0.0, atol=1e-4)
    # Boxes: one row per valid state of every other track.
    others = np.ones(257, bool)
    others[sdc] = False
    assert len(log.annotations) == int(decoded["valid"][others].sum()) == 8477
    tracks_by_id = log.tracks()
    assert len(tracks_by_id) == 256
    index_of = {int(i): k for k, i in enumerate(tracks.track_ids)}
    for track_id, track in tracks_by_id.items():
        k = index_of[int(track_id)]
        steps = np.searchsorted(tracks.timestamps_ns, track.timestamps_ns)
        np.testing.assert_array_equal(decoded["valid"][k, steps], 1.0)
        np.testing.assert_allclose(track.center_city_xyz_m[:, 0], decoded["center_x"][k, steps], atol=1e-3)
        np.testing.assert_allclose(track.center_city_xyz_m[:, 1], decoded["center_y"][k, steps], atol=1e-3)
        np.testing.assert_allclose(np.cos(track.yaw_city_rad - decoded["heading"][k, steps]), 1.0, atol=1e-6)
    categories = {str(c) for c in log.annotations.category}
    assert categories == {"REGULAR_VEHICLE", "PEDESTRIAN"}
    assert log.metadata.extra["object_type_counts"] == {"PEDESTRIAN": 2023, "VEHICLE": 6454}
    assert np.all(np.abs(quat_to_yaw(log.annotations.quat_wxyz)) <= np.pi + 1e-9)


def test_imported_map_follows_the_lane_centres(imported: Path, scenario: Any) -> None:
    log = Log.open(imported)
    vector_map = log.map
    assert vector_map is not None
    womd = womd_map_from_features(scenario.map_features)
    assert set(vector_map.lane_segments) == set(womd.lanes)
    assert len(vector_map.pedestrian_crossings) == 4
    assert len(vector_map.drivable_areas) >= 1
    widths = []
    for lane_id, lane in vector_map.lane_segments.items():
        centre = womd.lanes[lane_id].centerline
        np.testing.assert_allclose(0.5 * (lane.left_lane_boundary + lane.right_lane_boundary)[:, :2],
                                   centre[:, :2], atol=0.6)  # equal offsets unless one side meets a kerb
        widths.append(np.linalg.norm(lane.left_lane_boundary - lane.right_lane_boundary, axis=1))
    width = np.concatenate(widths)
    assert width.min() >= 1.0 and width.max() <= 2 * MAX_HALF_WIDTH_M + 1e-6 and 3.0 <= np.median(width) <= 4.5
    assert 0 < sum(lane.is_intersection for lane in vector_map.lane_segments.values()) < 114


def test_imported_log_validates_captions_and_cuts_clips(
    imported: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli_main(["validate", str(imported)]) == 0
    assert cli_main(["caption", str(imported), "--out", str(tmp_path / "captions")]) == 0
    out = capsys.readouterr().out
    assert f"womd_{DEV_ID}: 91 frames" in out
    import pyarrow.parquet as pq

    captions = pq.read_table(tmp_path / "captions" / "captions.parquet").to_pydict()
    assert len(captions["caption"]) > 10
    assert any("pedestrian" in c for c in captions["caption"])
    assert cli_main(["clips", str(imported), "--captions", str(tmp_path / "captions"), "--out",
                     str(tmp_path / "clips"), "--bev-source", "boxes"]) == 0
    assert "clips from 1 log" in capsys.readouterr().out
