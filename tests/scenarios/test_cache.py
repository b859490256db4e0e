"""The feature cache: small, faithful, and never used once it no longer matches its log."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from scenarios.cache import cached_features, decode, encode
from scenarios.features import build_features
from scenes.log import Log
from tests.scenarios.synthetic import car, cyclist, make_features
from tests.scenes.av2_fixtures import DEV_LOGS, require


def test_round_trip_keeps_every_feature_within_its_step() -> None:
    frames = 30
    path = np.stack([np.linspace(0, 30, frames), np.full(frames, 5.0)], axis=1)
    x = make_features([car(path, flags=("braking",), lane=3), cyclist((10, -4), valid=np.arange(frames) > 4)],
                      frames=frames)
    y, stamp = decode(encode(x, "stamp"))
    assert stamp == "stamp" and y.log_id == x.log_id
    for name in ("valid", "track_ids", "labels", "categories", "flags", "ego_lane", "lane"):
        np.testing.assert_array_equal(getattr(y, name), getattr(x, name), err_msg=name)
    m = x.valid
    assert np.abs(y.xy_m - x.xy_m)[m].max() <= 0.005 and np.abs(y.speed_mps - x.speed_mps)[m].max() <= 0.005
    assert np.abs(y.yaw_rad - x.yaw_rad)[m].max() <= 1e-4


def test_damaged_bytes_are_refused() -> None:
    data = bytearray(encode(make_features([car((0, 0))]), "s"))
    data[len(data) // 2] ^= 0xFF
    with pytest.raises(ValueError, match="not a feature file"):
        decode(bytes(data))


def test_a_development_log_caches_small_and_is_rebuilt_when_it_changes(tmp_path: Path) -> None:
    source = require(DEV_LOGS["7fab2350"])
    log = tmp_path / "logs" / source.name
    log.mkdir(parents=True)
    for entry in source.iterdir():
        if entry.name == "annotations.feather":
            shutil.copy(entry, log / entry.name)  # a copy this test may touch
        else:
            (log / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
    cache = tmp_path / "cache"
    cache.mkdir()
    built, cached = cached_features(log, cache)
    assert not cached and (cache / f"{source.name}.features").is_file()
    size = (cache / f"{source.name}.features").stat().st_size
    assert size <= 0.10 * (source / "annotations.feather").stat().st_size
    again, cached = cached_features(log, cache)
    assert cached and np.array_equal(again.valid, built.valid)
    reference = build_features(Log.open(log))
    assert np.abs(again.xy_m - reference.xy_m)[reference.valid].max() <= 0.005
    (cache / f"{source.name}.features").write_bytes(b"not a feature file")  # damaged: built again, never used
    _, cached = cached_features(log, cache)
    assert not cached
    damaged = bytearray((cache / f"{source.name}.features").read_bytes())
    damaged[len(damaged) // 2] ^= 0xFF  # a flipped byte inside the compressed stream fails its checksum
    (cache / f"{source.name}.features").write_bytes(bytes(damaged))
    with pytest.raises(ValueError, match="not a feature file"):
        decode(bytes(damaged))
    _, cached = cached_features(log, cache)
    assert not cached
    st = (log / "annotations.feather").stat()
    os.utime(log / "annotations.feather", ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # the log changed
    _, cached = cached_features(log, cache)
    assert not cached
    _, cached = cached_features(log, cache)
    assert cached
