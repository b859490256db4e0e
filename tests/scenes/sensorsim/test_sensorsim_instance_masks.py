"""The instance-mask reader: values index the log's track list, which names each track once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes.errors import LogFormatError
from scenes.sensorsim.instance_masks import (
    read_instance_mask,
    read_instance_track_ids,
    track_ids_path,
    write_instance_mask,
    write_instance_track_ids,
)


def _mask(log_dir: Path, top: int) -> None:
    mask = np.zeros((4, 6), np.uint16)
    mask[1:3, 2:4] = top
    write_instance_mask(log_dir, "ring_front_center", 0, mask)


def test_a_track_listed_twice_is_refused_naming_the_file_and_row(tmp_path: Path) -> None:
    write_instance_track_ids(tmp_path, ["a", "b", "a"])
    with pytest.raises(LogFormatError) as info:
        read_instance_track_ids(tmp_path)
    (problem,) = info.value.problems
    assert (problem.path, problem.field, problem.row) == (track_ids_path(tmp_path), "track_id", 2)
    assert "'a' is listed twice (first at row 0)" in problem.message


def test_a_value_beyond_the_list_is_refused_and_a_list_read_once_serves_every_frame(tmp_path: Path) -> None:
    write_instance_track_ids(tmp_path, ["a", "b"])
    _mask(tmp_path, 3)
    with pytest.raises(LogFormatError, match="mask value 3 is beyond the 2 tracks"):
        read_instance_mask(tmp_path, "ring_front_center", 0)
    _mask(tmp_path, 2)
    ids = read_instance_track_ids(tmp_path)
    track_ids_path(tmp_path).unlink()  # given the list, the frame's read does not open it again
    mask, listed = read_instance_mask(tmp_path, "ring_front_center", 0, ids)
    assert listed == ["a", "b"] and int(mask.max()) == 2
