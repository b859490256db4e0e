"""simulate --emit-detections → track → eval-tracking, through the command line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from retrieval.cli import main
from scenes.log import Log


@pytest.mark.slow
def test_simulated_detections_are_tracked_back_into_a_log(tmp_path: Path) -> None:
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--logs", "1", "--duration-s", "12", "--seed", "5",
                 "--warmup-s", "40", "--no-sensors", "--emit-detections"]) == 0
    (log_dir,) = [p for p in (tmp_path / "sim").iterdir() if p.is_dir()]
    assert (log_dir / "detections.parquet").is_file()
    assert main(["track", str(log_dir), "--detections", str(log_dir / "detections.parquet"),
                 "--out", str(tmp_path / "tracked")]) == 0
    tracked = Log.open(tmp_path / "tracked" / log_dir.name)
    assert tracked.map is not None  # the rest of the log travels with the new annotations
    assert main(["eval-tracking", str(tracked.log_dir), str(log_dir), "--out", str(tmp_path / "m.json")]) == 0
    car = json.loads((tmp_path / "m.json").read_text())["car"]
    assert car["MOTA"] > 0.5 and car["IDF1"] > 0.5


def test_track_refuses_a_detections_file_with_bad_rows(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from scenes import av2_io
    from scenes.tracks import EgoTrajectory

    log_dir = tmp_path / "log"
    ts = np.arange(10, dtype=np.int64) * 100_000_000
    av2_io.write_ego_poses(log_dir, EgoTrajectory.from_xy_yaw(ts, np.zeros((10, 2)), np.zeros(10)))
    rows = {"timestamp_ns": ts, "category": ["car"] * 10, "score": [0.9] * 9 + [1.7], "tx_m": [10.0] * 10,
            "ty_m": [0.0] * 10, "tz_m": [0.8] * 10, "length_m": [4.5] * 10, "width_m": [1.9] * 10,
            "height_m": [1.6] * 10, "yaw_rad": [0.0] * 10}
    pq.write_table(pa.table(rows), tmp_path / "d.parquet")
    assert main(["track", str(log_dir), "--detections", str(tmp_path / "d.parquet"), "--out",
                 str(tmp_path / "out")]) == 2
    assert "line 10" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
