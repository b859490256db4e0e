from pathlib import Path

import numpy as np
import pytest

from scenes.av2_io import ANNOTATIONS_FILENAME, MAP_DIRNAME, find_map_file
from scenes.behavior import BEHAVIOR_FILENAME, EGO_TRACK_ID, read_behavior_labels, read_junctions
from scenes.log import Log
from scenes.metadata import MAP_WITHHELD_KEY
from scenes.sim import NetworkKind, SimulationConfig, SimulationError, simulate
from scenes.sim.network import build_network
from scenes.validate import validate_log


def _config(cache: Path, **kw: object) -> SimulationConfig:
    base = {"logs": 2, "duration_s": 4.0, "seed": 1, "warmup_s": 20.0, "egos_per_run": 2, "cache_dir": str(cache)}
    base.update(kw)
    return SimulationConfig(**base)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("netcache")


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory, cache: Path) -> list[Path]:
    return simulate(_config(cache), tmp_path_factory.mktemp("sim"))


def test_logs_open_and_validate(logs: list[Path]) -> None:
    assert len(logs) == 2
    for log_dir in logs:
        log = Log.open(log_dir)
        assert validate_log(log_dir).ok
        assert len(log.ego) == 40
        assert len(log.annotations) > 0
        assert log.map is not None and len(log.map.lane_segments) > 0
        meta = log.metadata
        assert meta.source == "sumo"
        assert meta.appearance["time_of_day"] in {"day", "dusk", "night"}
        assert meta.appearance["weather"] in {"clear", "rain", "fog"}
        assert set(log.annotations.track_id) <= set(meta.appearance["vehicle_colors"])
        assert read_junctions(log_dir) is not None


def test_annotations_are_realistic(logs: list[Path]) -> None:
    log = Log.open(logs[0])
    ann = log.annotations
    assert np.all(np.linalg.norm(ann.center_xyz_m[:, :2], axis=1) <= 80.0 + 1e-6)
    np.testing.assert_allclose(ann.center_xyz_m[:, 2], ann.size_lwh_m[:, 2] / 2)
    cars = ann.category == "REGULAR_VEHICLE"
    assert np.all((ann.size_lwh_m[cars, 0] > 3.5) & (ann.size_lwh_m[cars, 0] < 5.5))


def test_box_heading_follows_motion_in_the_city_frame(logs: list[Path]) -> None:
    # Checks the whole conversion chain: SUMO compass angle → yaw, front bumper → centre, city → ego.
    checked = 0
    for log_dir in logs:
        for track in Log.open(log_dir).tracks().values():
            if track.raw_category == "PEDESTRIAN" or len(track) < 10:
                continue
            step = np.diff(track.center_city_xyz_m[:, :2], axis=0)
            dist = np.linalg.norm(step, axis=1)
            consecutive = np.diff(track.timestamps_ns) == 100_000_000
            # > 8 m/s between consecutive frames: lane changes and turns bend the path only slightly.
            fast = (dist > 0.8) & consecutive
            if not fast.any():
                continue
            motion = np.arctan2(step[fast, 1], step[fast, 0])
            err = np.angle(np.exp(1j * (motion - track.yaw_city_rad[1:][fast])))
            assert np.median(np.abs(err)) < 0.15, track.track_id
            checked += 1
    assert checked > 0


def test_ego_labels_match_ego_poses(logs: list[Path]) -> None:
    log = Log.open(logs[0])
    labels = read_behavior_labels(logs[0])
    assert labels is not None
    ego_rows = np.asarray(labels.column("track_id").to_pylist()) == EGO_TRACK_ID
    assert ego_rows.sum() == len(log.ego)
    label_speed = labels.column("speed_mps").to_numpy()[ego_rows]
    pose_speed = log.ego.speed_mps()
    assert np.median(np.abs(label_speed[1:-1] - pose_speed[1:-1])) < 0.5
    # Every annotated (timestamp, track) has a label row.
    label_keys = set(zip(labels.column("timestamp_ns").to_pylist(), labels.column("track_id").to_pylist()))
    ann = log.annotations
    assert set(zip(ann.timestamp_ns.tolist(), ann.track_id.tolist())) <= label_keys


def test_same_seed_gives_identical_bytes(logs: list[Path], tmp_path: Path, cache: Path) -> None:
    again = simulate(_config(cache), tmp_path)
    for a, b in zip(logs, again):
        assert a.name == b.name
        for name in (ANNOTATIONS_FILENAME, BEHAVIOR_FILENAME, "city_SE3_egovehicle.feather", "log_metadata.json"):
            assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_different_seed_gives_different_traffic(logs: list[Path], tmp_path: Path, cache: Path) -> None:
    other = simulate(_config(cache, seed=2), tmp_path)
    assert other[0].name != logs[0].name
    assert (other[0] / ANNOTATIONS_FILENAME).read_bytes() != (logs[0] / ANNOTATIONS_FILENAME).read_bytes()


def test_refuses_to_overwrite_logs_unless_asked(tmp_path: Path, cache: Path) -> None:
    first = simulate(_config(cache, logs=2, duration_s=1.0, warmup_s=20.0), tmp_path)
    stamp = (first[0] / ANNOTATIONS_FILENAME).read_bytes()
    with pytest.raises(FileExistsError, match="overwrite"):
        simulate(_config(cache, logs=2, duration_s=1.0, warmup_s=20.0, seed=5), tmp_path)
    assert (first[0] / ANNOTATIONS_FILENAME).read_bytes() == stamp  # untouched
    again = simulate(_config(cache, logs=1, duration_s=1.0, warmup_s=20.0), tmp_path, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == [again[0].name]  # stale logs removed


def test_tracker_noise_changes_boxes_not_labels(logs: list[Path], tmp_path: Path, cache: Path) -> None:
    noisy = simulate(_config(cache, tracker_noise=True), tmp_path)
    clean_ann, noisy_ann = Log.open(logs[0]).annotations, Log.open(noisy[0]).annotations
    assert len(noisy_ann) < len(clean_ann)
    assert (noisy[0] / BEHAVIOR_FILENAME).read_bytes() == (logs[0] / BEHAVIOR_FILENAME).read_bytes()


def test_sumo_failure_surfaces_its_message_and_leaves_no_log(
    tmp_path: Path, cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A network that parses but that SUMO refuses: a junction names a traffic light that is missing.
    good = build_network(NetworkKind.GRID, 0, cache).read_text()
    broken = tmp_path / "broken.net.xml"
    broken.write_text(good.replace('<tlLogic id="B1"', '<tlLogic id="NOPE"'))
    monkeypatch.setattr("scenes.sim.pipeline.build_network", lambda *a, **k: broken)
    out = tmp_path / "out"
    with pytest.raises(SimulationError, match="tls 'B1' is not known"):
        simulate(_config(cache), out)
    assert not out.exists() or not any(out.iterdir())


def test_post_log_hooks_run_before_the_log_appears(tmp_path: Path, cache: Path) -> None:
    seen: list[Path] = []

    def hook(log_dir: Path) -> None:
        assert (log_dir / ANNOTATIONS_FILENAME).is_file()
        (log_dir / "extra.txt").write_text("rendered")
        seen.append(log_dir)

    out = simulate(_config(cache, logs=1), tmp_path / "o", post_log=[hook])
    assert len(seen) == 1 and seen[0] != out[0]
    assert (out[0] / "extra.txt").read_text() == "rendered"


def test_a_log_without_objects_stops_the_run_before_writing(tmp_path: Path, cache: Path) -> None:
    out = tmp_path / "o"
    with pytest.raises(SimulationError, match="warmup_s"):
        simulate(_config(cache, warmup_s=0.0, duration_s=0.5, range_m=1.0), out)
    assert not out.exists() or not any(out.iterdir())


def test_map_less_share_withholds_the_map_of_that_share_after_the_hooks(tmp_path: Path, cache: Path) -> None:
    maps_seen_by_hooks: list[bool] = []

    def hook(log_dir: Path) -> None:  # e.g. the sensor rendering, which builds the world from the map
        maps_seen_by_hooks.append(find_map_file(log_dir) is not None)

    config = _config(cache, logs=4, duration_s=1.0, map_less_share=0.5)
    out = simulate(config, tmp_path / "o", post_log=[hook])
    assert maps_seen_by_hooks == [True] * 4
    without = [i for i, log_dir in enumerate(out) if Log.open(log_dir).map is None]
    assert sorted(without) == sorted(config.map_less_logs()) and len(without) == 2
    for i, log_dir in enumerate(out):
        assert not (log_dir / MAP_DIRNAME).exists() if i in without else find_map_file(log_dir) is not None
        assert read_junctions(log_dir) is not None and read_behavior_labels(log_dir) is not None  # simulator truth
        assert Log.open(log_dir).metadata.extra[MAP_WITHHELD_KEY] is (i in without)
        assert validate_log(log_dir).ok
    # The same logs and bytes as without the option, the map aside.
    full = simulate(_config(cache, logs=4, duration_s=1.0), tmp_path / "full")
    for a, b in zip(out, full):
        assert (a / ANNOTATIONS_FILENAME).read_bytes() == (b / ANNOTATIONS_FILENAME).read_bytes()


@pytest.mark.parametrize("share", [-0.1, 1.5])
@pytest.mark.parametrize("name", ["map_less_share", "jitter_share"])
def test_a_share_outside_zero_one_is_refused(name: str, share: float) -> None:
    with pytest.raises(ValueError, match=name):
        SimulationConfig(**{name: share})  # type: ignore[arg-type]


def test_map_less_logs_are_a_seeded_draw_of_the_share() -> None:
    assert SimulationConfig(logs=10, map_less_share=0.0).map_less_logs() == frozenset()
    assert len(SimulationConfig(logs=10, map_less_share=0.3).map_less_logs()) == 3
    assert SimulationConfig(logs=10, map_less_share=1.0).map_less_logs() == frozenset(range(10))
    assert SimulationConfig(logs=10, seed=3, map_less_share=0.5).map_less_logs() == \
        SimulationConfig(logs=10, seed=3, map_less_share=0.5).map_less_logs()


def test_jitter_share_scatters_the_boxes_of_that_share_and_keeps_the_labels(tmp_path: Path, cache: Path) -> None:
    config = _config(cache, logs=4, duration_s=1.0, jitter_share=0.5)
    out = simulate(config, tmp_path / "o")
    exact = simulate(_config(cache, logs=4, duration_s=1.0), tmp_path / "exact")
    assert len(config.jittered_logs()) == 2
    for i, (a, b) in enumerate(zip(out, exact)):
        jittered, log, ann_exact = i in config.jittered_logs(), Log.open(a), Log.open(b).annotations
        ann = log.annotations
        assert log.metadata.extra["box_jitter"] is jittered
        np.testing.assert_array_equal(ann.track_id, ann_exact.track_id)  # every box kept, under its id
        shift = np.linalg.norm(ann.center_xyz_m[:, :2] - ann_exact.center_xyz_m[:, :2], axis=1)
        if jittered:
            assert 0.1 < np.median(shift) < 0.3  # ~ sqrt(2 ln 2) * 0.15 m for 2-D Gaussian noise
        else:
            assert (a / ANNOTATIONS_FILENAME).read_bytes() == (b / ANNOTATIONS_FILENAME).read_bytes()
        assert (a / BEHAVIOR_FILENAME).read_bytes() == (b / BEHAVIOR_FILENAME).read_bytes()  # labels stay exact


def test_jittered_logs_are_a_seeded_draw_apart_from_the_map_less_one() -> None:
    assert SimulationConfig(logs=10, jitter_share=0.0).jittered_logs() == frozenset()
    assert len(SimulationConfig(logs=10, jitter_share=0.3).jittered_logs()) == 3
    config = SimulationConfig(logs=40, seed=3, jitter_share=0.5, map_less_share=0.5)
    assert config.jittered_logs() == SimulationConfig(logs=40, seed=3, jitter_share=0.5).jittered_logs()
    assert config.jittered_logs() != config.map_less_logs()
    # The tracker's noise already jitters every box: no log is jittered twice.
    assert SimulationConfig(logs=10, jitter_share=1.0, tracker_noise=True).jittered_logs() == frozenset()
