"""An error about one track at one frame names the place, the frame with its timestamp, and the field."""

from __future__ import annotations

import pytest

from scenes.errors import ScenesError, TrackFrameError
from scenes.sensorsim.errors import BadObjectError


def test_track_frame_error_names_place_frame_timestamp_and_field() -> None:
    error = TrackFrameError("log a, track 7", "7", 3, 300_000_000, "yaw_ego_rad", "value is not finite")
    assert str(error) == "log a, track 7, frame 3 (timestamp_ns 300000000), field 'yaw_ego_rad': value is not finite"
    assert (error.track_id, error.frame, error.timestamp_ns, error.field) == ("7", 3, 300_000_000, "yaw_ego_rad")
    assert isinstance(error, ScenesError)


def test_a_stage_error_keeps_its_own_place_and_is_caught_as_a_track_frame_error() -> None:
    with pytest.raises(TrackFrameError) as info:
        raise BadObjectError("log/annotations.feather", "bus-1", 2, 20, "width_m", "box is flat")
    assert str(info.value) == ("log/annotations.feather, track 'bus-1', frame 2 (timestamp_ns 20), "
                               "field 'width_m': box is flat")
    assert isinstance(info.value, BadObjectError) and info.value.field == "width_m"
