"""``scenesearch simulate`` renders sensors by default, into the log before it appears."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from retrieval.cli import main
from scenes.log import Log
from scenes.sensorsim.instance_masks import read_instance_mask


@pytest.mark.slow
def test_simulate_writes_sweeps_frames_and_masks_at_10_hz(tmp_path: Path) -> None:
    config = tmp_path / "sensors.yaml"
    config.write_text("lidar: {beams: 16, azimuth_steps: 256}\ncamera: {width_px: 160, height_px: 90}\n")
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--logs", "1", "--duration-s", "4", "--seed", "2",
                 "--warmup-s", "40", "--sensor-config", str(config)]) == 0
    (log_dir,) = [p for p in (tmp_path / "sim").iterdir() if p.is_dir()]
    log = Log.open(log_dir)
    sweeps = log.lidar_timestamps_ns
    assert sweeps.size >= 40 and set(np.diff(sweeps).tolist()) == {100_000_000}
    frames = log.camera_timestamps_ns("ring_front_center")
    np.testing.assert_array_equal(frames, sweeps)
    assert log.camera_names() == ["ring_front_center"]
    sweep = log.lidar_sweep(int(sweeps[0]))
    assert len(sweep) > 1000 and int(sweep.laser_number.max()) == 15
    image = log.camera_frame("ring_front_center", int(frames[0]))
    assert image.shape == (90, 160, 3)
    mask, track_ids = read_instance_mask(log_dir, "ring_front_center", int(frames[0]))
    assert mask.shape == (90, 160) and int(mask.max()) <= len(track_ids)
    assert {"up_lidar", "ring_front_center"} <= set(log.calibration.ego_SE3_sensor)
