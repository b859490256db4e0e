"""Previews of synthetic clips: twice the old size at least, the object marked in the camera and in the BEV,
the ego marked, "no camera" where there is none, boxes without LiDAR or a map, scenario marks, and a GIF
that decodes to exactly the frames drawn."""

from __future__ import annotations

import io
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from encoders.clips import preview as pv
from encoders.clips import preview_canvas as canvas
from encoders.clips.build import build_clips
from encoders.clips.config import BevClipConfig, CameraClipConfig, ClipsConfig
from encoders.clips.layout import read_clip_table
from encoders.clips.views import open_log_arrays
from tests.encoders.clip_fixtures import synthetic_captions, write_synthetic_log

#: The demo's clips: a 64 × 32 camera and a 1.25 m BEV grid (previews 196 × 128 before this layout).
DEMO = ClipsConfig(frames_per_clip=8, previews=False, camera=CameraClipConfig(width_px=64, height_px=32),
                   bev=BevClipConfig(resolution_m=1.25))


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("clips_preview")
    with_camera = write_synthetic_log(root / "logs", "with_camera", num_frames=40)
    boxes_only = write_synthetic_log(root / "logs", "boxes_only", num_frames=40, with_camera=False, with_lidar=False)
    shutil.rmtree(boxes_only / "map")  # as the demo's extra logs: no sensors, no map
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions([with_camera, boxes_only]), root / "captions" / "captions.parquet")
    build_clips([with_camera, boxes_only], root / "captions", root / "clips", DEMO)
    rows = {(r["log_id"], r["track_id"]): r for r in read_clip_table(root / "clips").to_pylist()}
    return {"dir": root / "clips", "rows": rows}


def _draw(clips: dict[str, Any], log_id: str, track: str, **marks: Any) -> tuple[np.ndarray, np.ndarray]:
    arrays = open_log_arrays(clips["dir"], log_id)
    return pv.render_preview_indices(arrays, clips["rows"][(log_id, track)], DEMO, **marks)


def test_previews_are_at_least_twice_the_old_size(clips: dict[str, Any]) -> None:
    indices, palette = _draw(clips, "with_camera", "lead")
    layout = canvas.PreviewLayout.of(DEMO)
    assert indices.shape == (8, layout.height, layout.width) and palette.shape == (256, 3)
    assert layout.height >= 2 * 128 and layout.width >= 2 * 196


def test_the_object_is_outlined_in_the_camera_and_boxed_in_the_bev(clips: dict[str, Any]) -> None:
    layout = canvas.PreviewLayout.of(DEMO)
    indices, _ = _draw(clips, "with_camera", "lead")
    camera = indices[:, : layout.camera_h, : layout.camera_w]
    bev = indices[:, :, layout.camera_w + canvas.GAP_PX:]
    assert all((frame == canvas.OBJECT).sum() > 50 for frame in camera)  # outline and box in every frame
    assert all((frame == canvas.OBJECT).any() for frame in bev)
    assert all((frame == canvas.EGO).sum() > 50 for frame in bev)
    # The object's box in the BEV is where its track says: ahead of the ego (up) and to its left or in its lane.
    rows, cols = np.nonzero(bev[0] == canvas.OBJECT)
    ego_rows, ego_cols = np.nonzero(bev[0] == canvas.EGO)
    assert rows.mean() < ego_rows.min() and cols.mean() <= ego_cols.mean() + 2
    # The parked car, another clip, is marked in its own place: to the right.
    parked, _ = _draw(clips, "with_camera", "parked")
    _rows, p_cols = np.nonzero(parked[0, :, layout.camera_w + canvas.GAP_PX:] == canvas.OBJECT)
    assert p_cols.mean() > ego_cols.mean()
    # The legend says what the colours mean.
    assert (indices[0, layout.camera_h:, : layout.camera_w] == canvas.TEXT).sum() > 100


def test_a_clip_without_camera_says_so_and_box_logs_still_show_their_objects(clips: dict[str, Any]) -> None:
    layout = canvas.PreviewLayout.of(DEMO)
    indices, _ = _draw(clips, "boxes_only", "lead")
    camera = indices[:, : layout.camera_h, : layout.camera_w]
    assert (camera == canvas.NO_CAMERA).mean() > 0.9 and (camera == canvas.TEXT).sum() > 200  # "no camera" written
    bev = indices[:, :, layout.camera_w + canvas.GAP_PX:]
    assert all((frame == canvas.OBJECT).any() for frame in bev)  # not a lone ego on black
    assert all((frame == canvas.OTHER).any() for frame in bev)  # the other tracks' boxes and the notes
    assert (bev[0, :40] == canvas.OTHER).sum() > 20  # "no map", "boxes, no LiDAR" written at the top


def test_an_object_off_the_grid_gets_an_arrow_at_the_edge(clips: dict[str, Any]) -> None:
    arrays = open_log_arrays(clips["dir"], "with_camera")
    row = dict(clips["rows"][("with_camera", "lead")])
    boxes = np.array(arrays.track_boxes)
    boxes[:, arrays.track_value["lead"] - 1, 0] = 150.0  # 150 m ahead: beyond the 60 m of the grid
    far = replace(arrays, track_boxes=boxes)
    layout = canvas.PreviewLayout.of(DEMO)
    indices, _ = pv.render_preview_indices(far, row, DEMO)
    bev = indices[:, :, layout.camera_w + canvas.GAP_PX:]
    rows, _cols = np.nonzero(bev[0] == canvas.OBJECT)
    assert rows.size and rows.max() < 60  # the arrow and the distance, at the top edge


def test_scenario_marks_draw_the_referred_and_related_tracks(clips: dict[str, Any]) -> None:
    plain, _ = _draw(clips, "with_camera", "lead")
    marked, _ = _draw(clips, "with_camera", "lead", referred=["lead", "parked"], related=["follower"])
    assert not (plain == canvas.REFERRED).any() and not (plain == canvas.RELATED).any()
    assert (marked == canvas.REFERRED).any() and (marked == canvas.RELATED).any()


def test_the_gif_decodes_to_the_frames_drawn(clips: dict[str, Any]) -> None:
    row = clips["rows"][("with_camera", "lead")]
    indices, palette = _draw(clips, "with_camera", "lead")
    data = pv.preview_gif(clips["dir"], row, DEMO)
    with Image.open(io.BytesIO(data)) as gif:
        assert gif.n_frames == indices.shape[0]
        for i in range(gif.n_frames):
            gif.seek(i)
            np.testing.assert_array_equal(np.asarray(gif.convert("RGB")), palette[indices[i]])
    assert not (indices == canvas.TRANSPARENT).any()
    # The stored preview is the same file.
    out = pv.write_preview(clips["dir"], row["clip_id"], Path(clips["dir"]) / "one.gif", DEMO)
    assert out.read_bytes() == data
