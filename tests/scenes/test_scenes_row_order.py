"""Real AV2 annotation tables in the row orders real releases use read the same as the original.

Scenario-mining releases keep ``annotations.feather`` rows out of time order: rows grouped by track,
and the ego's own ``EGO_VEHICLE`` box appended at the end. av2-api reads such files; so must the
readers, and the ego's box must never become a neighbour in any consumer (tracks, the dense
(K, T) arrays that captioning and clips use, captions, the validate report). Each test log is a
development fixture with only its annotations rewritten, in a temporary folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from captioning.pipeline import caption_log
from scenes import av2_io
from scenes.categories import EGO_VEHICLE_LABEL
from scenes.log import Log
from scenes.tracks import Annotations
from scenes.validate import validate_log
from tests.scenes.av2_fixtures import DEV_LOGS, EGO_UUID, VARIANTS, require, rewritten_log, shuffled


@pytest.fixture(scope="module")
def originals() -> dict[str, Log]:
    return {name: Log.open(require(path)) for name, path in DEV_LOGS.items()}


def _assert_same_annotations(got: Annotations, expect: Annotations) -> None:
    for name in ("timestamp_ns", "track_id", "category", "center_xyz_m", "size_lwh_m", "quat_wxyz",
                 "num_interior_pts"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expect, name), err_msg=name)


def test_variants_really_are_out_of_time_order(originals: dict[str, Log], tmp_path: Path) -> None:
    """The test logs hold what made the readers refuse real logs: time going backwards in the file."""
    for variant, change in VARIANTS.items():
        log_dir = rewritten_log(DEV_LOGS["7fab2350"], tmp_path / variant, change)
        ts = feather.read_table(log_dir / av2_io.ANNOTATIONS_FILENAME).column("timestamp_ns").to_numpy()
        assert (np.diff(ts) < 0).any(), variant


@pytest.mark.parametrize("log_name", sorted(DEV_LOGS))
@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_any_row_order_reads_like_the_original(
    originals: dict[str, Log], tmp_path: Path, log_name: str, variant: str
) -> None:
    original = originals[log_name]
    log_dir = rewritten_log(DEV_LOGS[log_name], tmp_path / original.log_id, VARIANTS[variant])
    log = Log.open(log_dir)

    # The reader: the rows sorted by (timestamp, track id); the ego's box is kept in the table as the ego.
    ann = log.annotations
    assert np.all(np.diff(ann.timestamp_ns) >= 0)
    _assert_same_annotations(ann.without_ego(), original.annotations)
    has_ego = "ego" in variant
    assert (ann.category == EGO_VEHICLE_LABEL).any() == has_ego
    assert log.unknown_categories == original.unknown_categories

    # Every consumer sees the same neighbours: per-track views, the dense arrays of captioning and clips.
    tracks, expect_tracks = log.tracks(), original.tracks()
    assert EGO_UUID not in tracks and list(tracks) == list(expect_tracks)
    for tid in list(tracks)[::9]:
        np.testing.assert_array_equal(tracks[tid].center_city_xyz_m, expect_tracks[tid].center_city_xyz_m)
    dense, expect_dense = log.dense_tracks(), original.dense_tracks()
    assert EGO_UUID not in dense.track_ids
    np.testing.assert_array_equal(dense.track_ids, expect_dense.track_ids)
    np.testing.assert_array_equal(dense.timestamps_ns, expect_dense.timestamps_ns)
    np.testing.assert_array_equal(dense.valid, expect_dense.valid)
    np.testing.assert_array_equal(dense.center_city_xyz_m, expect_dense.center_city_xyz_m)
    np.testing.assert_array_equal(dense.city_SE3_ego, expect_dense.city_SE3_ego)

    # Captions, and what validate reports.
    captions = caption_log(log).captions_table()
    assert captions.equals(caption_log(original).captions_table())
    report = validate_log(log_dir)
    assert report.ok, report.problems
    assert report.facts == validate_log(DEV_LOGS[log_name]).facts


def test_a_repeated_track_in_one_frame_is_still_refused_by_its_file_row(tmp_path: Path) -> None:
    """Sorting does not hide a duplicate: the problem names the row as it is in the rewritten file."""

    def duplicate_last_row_first(table: pa.Table) -> pa.Table:
        table = shuffled(table)
        return pa.concat_tables([table, table.slice(0, 1)])

    log_dir = rewritten_log(require(DEV_LOGS["adcf7d18"]), tmp_path / "dup", duplicate_last_row_first)
    n_rows = feather.read_table(log_dir / av2_io.ANNOTATIONS_FILENAME).num_rows
    (problem,) = validate_log(log_dir).problems
    assert (problem.path.name, problem.field, problem.row) == (av2_io.ANNOTATIONS_FILENAME, "track_uuid", n_rows - 1)
    assert "twice" in problem.message
