"""Sensors on a SUMO-simulated log: the map of a real network, the appearance of the simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes.log import Log
from scenes.sensorsim.config import SensorConfig
from scenes.sensorsim.instance_masks import read_instance_mask
from scenes.sensorsim.render import render_log_sensors


@pytest.mark.slow
def test_render_a_simulated_log(tmp_path: Path) -> None:
    sim = pytest.importorskip("scenes.sim")
    config = sim.SimulationConfig(logs=1, duration_s=2.0, seed=5, warmup_s=15.0, egos_per_run=1, sensors=False,
                                  cache_dir=str(tmp_path / "cache"))
    try:
        (log_dir,) = sim.simulate(config, tmp_path / "sim")
    except sim.SimulationError as exc:  # SUMO missing on this machine
        pytest.skip(f"simulator unavailable: {exc}")
    small = SensorConfig.from_yaml_text(
        "lidar: {beams: 16, azimuth_steps: 256}\ncamera: {width_px: 160, height_px: 90}\n"
        "world: {raster_resolution_m: 0.25}\n"
    )
    report = render_log_sensors(log_dir, small, progress=False)
    log = Log.open(log_dir)
    # Every 10 Hz ego pose gets sensors, also frames where no object is annotated.
    assert report.frames == len(log.ego.timestamps_ns) == 20
    assert np.array_equal(log.lidar_timestamps_ns, log.ego.timestamps_ns)
    assert np.array_equal(log.camera_timestamps_ns("ring_front_center"), log.ego.timestamps_ns)
    assert set(log.timestamps_ns.tolist()) <= set(log.lidar_timestamps_ns.tolist())
    sweep = log.lidar_sweep(int(log.timestamps_ns[0]))
    assert len(sweep) > 1000
    # The ground under the ego is flat at z = 0 in the ego frame: most low points lie on it.
    assert np.median(sweep.xyz_m[sweep.xyz_m[:, 2] < 0.5, 2]) == pytest.approx(0.0, abs=0.05)
    mask, track_ids = read_instance_mask(log_dir, "ring_front_center", int(log.timestamps_ns[0]))
    assert track_ids == [str(t) for t in log.dense_tracks().track_ids]
    assert int(mask.max()) <= len(track_ids)
