"""The KITTI tracking label file ``label_02/<seq>.txt``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scenes.errors import ImportFormatError
from scenes.geometry import FloatArray
from scenes.kitti.text import parse_floats, read_lines

DONTCARE = "DontCare"
LABEL_FIELDS = (
    "frame", "track_id", "type", "truncated", "occluded", "alpha",
    "x1", "y1", "x2", "y2", "h", "w", "l", "x", "y", "z", "rotation_y",
)


@dataclass(frozen=True)
class KittiLabels:
    """Labelled boxes of one sequence, ``DontCare`` rows removed.

    Attributes:
        frame: (N,) frame index of each box.
        track_id: (N,) KITTI track id.
        kitti_type: (N,) KITTI type (``Car``, ``Pedestrian``, …).
        size_hwl_m: (N, 3) height, width, length.
        bottom_center_cam_xyz_m: (N, 3) bottom centre of the box in the rectified camera frame.
        rotation_y_rad: (N,) rotation about the camera's y axis.
        dropped_dontcare: number of ``DontCare`` rows removed.
        num_label_frames: number of distinct frames in the file (``DontCare``-only frames included).
        truncated: (N,) truncation level (tracking labels: 0 none, 1 partly, 2 largely out of the image).
        occluded: (N,) occlusion level (0 visible, 1 partly, 2 largely occluded, 3 unknown).
        box_px: (N, 4) image box ``x1 y1 x2 y2`` of each object in camera 2.
        dontcare_frame: (M,) frame of each ``DontCare`` region.
        dontcare_box_px: (M, 4) image box of each ``DontCare`` region, kept for evaluation's
            ignore rules although the rows are not objects.
    """

    frame: NDArray[np.int64]
    track_id: NDArray[np.int64]
    kitti_type: NDArray[np.str_]
    size_hwl_m: FloatArray
    bottom_center_cam_xyz_m: FloatArray
    rotation_y_rad: FloatArray
    dropped_dontcare: int
    num_label_frames: int
    truncated: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    occluded: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    box_px: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    dontcare_frame: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    dontcare_box_px: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))

    def __len__(self) -> int:
        return int(self.frame.shape[0])


def read_kitti_labels(path: Path | str) -> KittiLabels:
    """Read ``label_02/<seq>.txt``; ``DontCare`` rows are dropped and counted.

    Raises:
        ImportFormatError: naming the (1-based) line and field of a wrong column count, a value that
            is not a number, a non-positive box size, frames out of order, or a track id twice in
            one frame.
    """
    path = Path(path)
    frames: list[int] = []
    track_ids: list[int] = []
    types: list[str] = []
    values: list[FloatArray] = []
    image: list[FloatArray] = []  # truncated occluded x1 y1 x2 y2 of each object row
    dontcare_frames: list[int] = []
    dontcare_boxes: list[FloatArray] = []
    dropped = 0
    all_frames: set[int] = set()
    seen: dict[tuple[int, int], int] = {}
    last_frame = -1
    float_names = list(LABEL_FIELDS[10:17])
    for line_no, line in enumerate(read_lines(path), start=1):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) not in (17, 18):
            raise ImportFormatError(
                path, f"expected 17 columns ({' '.join(LABEL_FIELDS)}), got {len(tokens)}", line=line_no
            )
        try:
            frame = int(tokens[0])
        except ValueError as exc:
            raise ImportFormatError(path, f"not an integer: {tokens[0]!r}", line=line_no, field="frame") from exc
        try:
            track = int(tokens[1])
        except ValueError as exc:
            raise ImportFormatError(path, f"not an integer: {tokens[1]!r}", line=line_no, field="track_id") from exc
        if frame < 0:
            raise ImportFormatError(path, f"negative frame {frame}", line=line_no, field="frame")
        if frame < last_frame:
            raise ImportFormatError(path, f"frame {frame} after frame {last_frame}: not in order", line=line_no,
                                    field="frame")
        last_frame = frame
        all_frames.add(frame)
        kitti_type = tokens[2]
        if kitti_type == DONTCARE:
            dropped += 1
            dontcare_frames.append(frame)
            dontcare_boxes.append(parse_floats(path, line_no, tokens[6:10], list(LABEL_FIELDS[6:10])))
            continue
        if track < 0:
            raise ImportFormatError(path, f"negative track id {track} on a {kitti_type} row", line=line_no,
                                    field="track_id")
        if (frame, track) in seen:
            raise ImportFormatError(
                path, f"track {track} appears twice in frame {frame} (first on line {seen[(frame, track)]})",
                line=line_no, field="track_id",
            )
        seen[(frame, track)] = line_no
        box = parse_floats(path, line_no, tokens[10:17], float_names)
        for i, name in enumerate(("h", "w", "l")):
            if box[i] <= 0:
                raise ImportFormatError(path, f"box size must be positive, got {box[i]}", line=line_no, field=name)
        frames.append(frame)
        track_ids.append(track)
        types.append(kitti_type)
        values.append(box)
        image.append(parse_floats(path, line_no, [tokens[3], tokens[4], *tokens[6:10]],
                                  [*LABEL_FIELDS[3:5], *LABEL_FIELDS[6:10]]))
    if not all_frames:
        raise ImportFormatError(path, "label file has no rows")
    box_array = np.stack(values) if values else np.zeros((0, 7))
    image_array = np.stack(image) if image else np.zeros((0, 6))
    return KittiLabels(
        frame=np.asarray(frames, dtype=np.int64),
        track_id=np.asarray(track_ids, dtype=np.int64),
        kitti_type=np.asarray(types, dtype=np.str_),
        size_hwl_m=box_array[:, 0:3],
        bottom_center_cam_xyz_m=box_array[:, 3:6],
        rotation_y_rad=box_array[:, 6],
        dropped_dontcare=dropped,
        num_label_frames=len(all_frames),
        truncated=image_array[:, 0].astype(np.int64),
        occluded=image_array[:, 1].astype(np.int64),
        box_px=image_array[:, 2:6],
        dontcare_frame=np.asarray(dontcare_frames, dtype=np.int64),
        dontcare_box_px=np.stack(dontcare_boxes) if dontcare_boxes else np.zeros((0, 4)),
    )
