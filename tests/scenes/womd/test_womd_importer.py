"""WOMD import on tiny synthetic scenarios: frames, validity, categories, the map, the command, and
bad input (each skipped scenario named by file, record and reason; never a half log)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from retrieval.cli import main as cli_main
from scenes.av2_io import find_map_file, read_map
from scenes.categories import Category, category_from_label
from scenes.geometry import SE3
from scenes.log import Log
from scenes.validate import validate_log
from scenes.womd import (
    EGO_BOX_CENTER_AHEAD_M,
    WomdFormatError,
    convert_tracks,
    import_womd_files,
    parse_scenario,
    scenario_tracks,
)
from scenes.womd.proto import message_class
from tests.scenes.womd.womd_fixtures import ScenarioSpec, build_scenario, default_spec, write_tfrecord


def _tracks(spec: ScenarioSpec):  # type: ignore[no-untyped-def]
    return scenario_tracks(parse_scenario(build_scenario(spec).SerializeToString()), Path("s.tfrecord"), 0)


def test_ego_pose_is_the_rear_axle_of_the_sdc_box() -> None:
    converted = convert_tracks(_tracks(default_spec()), Path("s.tfrecord"), 0)
    ego = converted.ego
    assert len(ego) == 5
    np.testing.assert_array_equal(ego.timestamps_ns, np.arange(5) * 100_000_000)
    np.testing.assert_allclose(ego.translation_m[:, 0], 100.0 + np.arange(5) - EGO_BOX_CENTER_AHEAD_M)
    np.testing.assert_allclose(ego.translation_m[:, 1], 50.0)
    np.testing.assert_allclose(ego.translation_m[:, 2], 0.0, atol=1e-6)  # box centre minus half its height
    np.testing.assert_allclose(ego.yaw_rad, 0.0, atol=1e-12)


def test_boxes_in_the_ego_frame_valid_steps_only() -> None:
    converted = convert_tracks(_tracks(default_spec()), Path("s.tfrecord"), 0)
    ann = converted.annotations
    assert "7" not in set(ann.track_id.tolist())  # the ego is not a neighbour
    car = ann.track_id == "8"
    assert car.sum() == 5
    # 10 m ahead of the ego box centre, 1.4 m further from the rear axle; 3.5 m left.
    np.testing.assert_allclose(ann.center_xyz_m[car], [[10.0 + 2 * 1.4, 3.5, 0.8]] * 5, atol=1e-6)
    ped = ann.track_id == "9"
    np.testing.assert_array_equal(ann.timestamp_ns[ped], [0, 100_000_000, 300_000_000, 400_000_000])
    # The pedestrian walks +y in the city; the ego faces +x, so its yaw in the ego frame is +90°.
    ped_yaw = 2 * np.arctan2(ann.quat_wxyz[ped, 3], ann.quat_wxyz[ped, 0])
    np.testing.assert_allclose(ped_yaw, np.pi / 2, atol=1e-6)
    assert {category_from_label(c) for c in ann.category[car]} == {Category.CAR}
    assert {category_from_label(c) for c in ann.category[ped]} == {Category.PEDESTRIAN}
    assert converted.type_counts == {"VEHICLE": 5, "PEDESTRIAN": 4}


def test_city_positions_survive_the_round_trip() -> None:
    """Boxes put back into the city frame with the ego pose land where WOMD had them."""
    spec = default_spec()
    spec.tracks[0].heading = np.linspace(0.2, 0.6, 5)  # a turning ego
    converted = convert_tracks(_tracks(spec), Path("s.tfrecord"), 0)
    ann, ego = converted.annotations, converted.ego
    for i in range(len(ann)):
        step = int(ann.timestamp_ns[i] // 100_000_000)
        city = ego.city_SE3_ego(step).compose(SE3.from_quat(ann.quat_wxyz[i], ann.center_xyz_m[i]))
        track = {"8": spec.tracks[1], "9": spec.tracks[2]}[str(ann.track_id[i])]
        np.testing.assert_allclose(city.translation[:2], track.xy[step], atol=1e-9)
        np.testing.assert_allclose(np.cos(city.yaw_rad - track.heading[step]), 1.0, atol=1e-9)


def test_unusable_states_and_steps_without_ego_are_counted() -> None:
    spec = default_spec()
    spec.tracks[0].valid = np.array([True, True, True, False, True])  # the ego misses step 3
    spec.tracks[1].size_lwh = (0.0, 2.0, 1.6)  # the car's box is degenerate: every state unusable
    converted = convert_tracks(_tracks(spec), Path("s.tfrecord"), 0)
    assert len(converted.ego) == 4
    assert converted.dropped_unusable == 5
    assert converted.dropped_without_ego == 1  # the pedestrian at step 3
    assert set(converted.annotations.timestamp_ns.tolist()) == {0, 100_000_000, 400_000_000}


def test_unknown_object_type_is_other_and_counted() -> None:
    spec = default_spec()
    spec.tracks[1].object_type = 0
    converted = convert_tracks(_tracks(spec), Path("s.tfrecord"), 0)
    assert converted.unknown_types == {"UNSET": 5}
    assert category_from_label(converted.annotations.category[converted.annotations.track_id == "8"][0]) == (
        Category.OTHER)


@pytest.mark.parametrize(
    ("mutate", "field", "message"),
    [
        (lambda s: setattr(s, "sdc_index", None), "sdc_track_index", "sdc_track_index is unset"),
        (lambda s: setattr(s, "sdc_index", 3), "sdc_track_index", "names no track"),
        (lambda s: setattr(s.tracks[0], "valid", np.zeros(5, bool)), "tracks[0].states", "has no valid state"),
        (lambda s: setattr(s, "scenario_id", ""), "scenario_id", "no id"),
        (lambda s: setattr(s, "scenario_id", "../evil"), "scenario_id", "cannot name a log folder"),
        (lambda s: setattr(s, "times_s", np.array([0, 0.1, 0.1, 0.3, 0.4])), "timestamps_seconds",
         "not increasing at step 2"),
        (lambda s: setattr(s.tracks[2], "xy", s.tracks[2].xy[:4]), "tracks[2].states", "4 states for 5"),
        (lambda s: setattr(s.tracks[2], "track_id", 8), "tracks[2].id", "track id 8 is used by more"),
    ],
)
def test_bad_scenarios_name_file_record_and_field(mutate, field: str, message: str) -> None:  # type: ignore[no-untyped-def]
    spec = default_spec()
    mutate(spec)
    if spec.tracks[2].valid is not None and len(spec.tracks[2].xy) == 4:
        spec.tracks[2].valid = spec.tracks[2].valid[:4]
        spec.tracks[2].heading = spec.tracks[2].heading[:4]
    with pytest.raises(WomdFormatError) as err:
        convert_tracks(_tracks(spec), Path("s.tfrecord"), 0)
    assert err.value.field == field
    assert message in str(err.value)
    assert str(err.value).startswith(f"s.tfrecord, record 0, field '{field}'")


def test_unknown_fields_are_skipped() -> None:
    """Fields this schema does not declare (traffic lights, prediction targets) do not stop parsing."""
    data = build_scenario(default_spec()).SerializeToString()
    # field 11 (tracks_to_predict: a message) and field 7 (dynamic_map_states), as raw wire bytes
    extra = bytes([0x5A, 0x02, 0x08, 0x01]) + bytes([0x3A, 0x00])
    scenario = parse_scenario(data + extra)
    assert scenario.scenario_id == "abc123" and len(scenario.tracks) == 3


def test_import_writes_a_valid_log_and_map(tmp_path: Path) -> None:
    source = write_tfrecord(tmp_path / "a.tfrecord", [build_scenario(default_spec())])
    batch = import_womd_files([source], tmp_path / "logs")
    assert batch.skipped == []
    (report,) = batch.imported
    assert report.log_dir == tmp_path / "logs" / "womd_abc123"
    assert (report.rows, report.tracks, report.ego_poses, report.lanes, report.crossings) == (9, 2, 5, 1, 1)
    validation = validate_log(report.log_dir)
    assert validation.ok, validation.problems
    log = Log.open(report.log_dir)
    assert log.metadata.source == "womd"
    assert log.metadata.extra["scenario_id"] == "abc123"
    assert log.metadata.extra["map_features_not_converted"] == {"stop_sign": 1}
    vector_map = read_map(find_map_file(report.log_dir))  # type: ignore[arg-type]
    lane = vector_map.lane_segments[1]
    # Left: the solid yellow line 1.7 m away; right: the kerb 3 m away does not widen the lane past
    # the other side's half-width.
    np.testing.assert_allclose(lane.left_lane_boundary[:, 1], 51.7)
    np.testing.assert_allclose(lane.right_lane_boundary[:, 1], 48.3)
    assert (lane.left_lane_mark_type, lane.right_lane_mark_type) == ("SOLID_YELLOW", "NONE")
    assert not lane.is_intersection
    crossing = vector_map.pedestrian_crossings[4]
    np.testing.assert_allclose(crossing.edge1[:, :2], [[118, 46], [118, 54]])
    np.testing.assert_allclose(crossing.edge2[:, :2], [[122, 46], [122, 54]])
    # The road surface reaches the kerb at y = 47 (within a cell) and not beyond it.
    (area,) = vector_map.drivable_areas.values()
    assert area.area_boundary[:, 1].min() == pytest.approx(47.0, abs=0.6)
    assert area.area_boundary[:, 1].max() == pytest.approx(51.7 + 5.0, abs=0.6)
    assert not list((tmp_path / "logs").glob(".*"))  # no temporary folders left


def _error_cases(tmp_path: Path) -> list[Path]:
    good = build_scenario(default_spec())
    no_sdc = default_spec()
    no_sdc.scenario_id, no_sdc.sdc_index = "nosdc", None
    other = default_spec()
    other.scenario_id = "second"
    files = [write_tfrecord(tmp_path / "mixed.tfrecord",
                            [build_scenario(no_sdc), b"\x08\x96", good, build_scenario(other)])]
    flipped = write_tfrecord(tmp_path / "flipped.tfrecord", [good])
    raw = bytearray(flipped.read_bytes())
    raw[40] ^= 0x10
    flipped.write_bytes(bytes(raw))
    truncated = tmp_path / "truncated.tfrecord"
    truncated.write_bytes(write_tfrecord(tmp_path / "tmp.tfrecord", [good]).read_bytes()[:-10])
    empty = tmp_path / "empty.tfrecord"
    empty.write_bytes(b"")
    return [*files, flipped, truncated, empty, tmp_path / "missing.tfrecord"]


def test_batch_reports_every_skip_and_imports_the_rest(tmp_path: Path) -> None:
    out = tmp_path / "logs"
    batch = import_womd_files(_error_cases(tmp_path), out)
    assert sorted(r.log_dir.name for r in batch.imported) == ["womd_abc123", "womd_second"]
    reasons = [str(s) for s in batch.skipped]
    assert len(reasons) == 6, reasons
    expected = [
        ("mixed.tfrecord, record 0", "sdc_track_index"),
        ("mixed.tfrecord, record 1", "not a Scenario"),
        ("flipped.tfrecord, record 0", "CRC mismatch"),
        ("truncated.tfrecord, record 0", "truncated"),
        ("empty.tfrecord", "no records"),
        ("missing.tfrecord", "file is missing"),
    ]
    for (where, what), reason in zip(expected, reasons):
        assert where in reason and what in reason, reason
    assert sorted(p.name for p in out.iterdir()) == ["womd_abc123", "womd_second"]  # no half logs


def test_existing_log_is_skipped_unless_overwrite(tmp_path: Path) -> None:
    source = write_tfrecord(tmp_path / "a.tfrecord", [build_scenario(default_spec())])
    assert len(import_womd_files([source], tmp_path).imported) == 1
    again = import_womd_files([source], tmp_path)
    assert again.imported == [] and "already exists" in again.skipped[0].reason
    assert "--overwrite" in again.skipped[0].reason
    assert len(import_womd_files([source], tmp_path, overwrite=True).imported) == 1


def test_import_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = write_tfrecord(tmp_path / "a.tfrecord", [build_scenario(default_spec())])
    assert cli_main(["import", "womd", str(source), "--out", str(tmp_path / "logs")]) == 0
    out = capsys.readouterr().out
    assert "womd_abc123" in out and "imported 1 scenarios" in out
    files = _error_cases(tmp_path)
    assert cli_main(["import", "womd", *map(str, files), "--out", str(tmp_path / "more")]) == 1
    out = capsys.readouterr().out
    assert out.count("\nskipped ") == 6 and "imported 2 scenarios into" in out and out.endswith("skipped 6\n")
    metadata = json.loads((tmp_path / "logs" / "womd_abc123" / "log_metadata.json").read_text())
    assert metadata["extra"]["source_file"] == str(source)


def test_every_declared_message_builds() -> None:
    for name in ("Scenario", "Track", "ObjectState", "MapFeature", "LaneCenter", "MapPoint"):
        assert message_class(name)().DESCRIPTOR.name == name
    with pytest.raises(KeyError, match="not declared"):
        message_class("Frame")
