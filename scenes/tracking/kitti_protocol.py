"""The KITTI tracking benchmark's ignore rules, for :func:`scenes.tracking.evaluate.tracking_counts`.

The official devkit and TrackEval's KITTI reader score car and pedestrian as follows; the same
rules apply here to every category (cyclist has no neighbouring class):

- ``DontCare`` rows of ``label_02/<seq>.txt`` are image regions, not objects. A predicted box
  that matches no object and has more than half of its image area inside one such region is
  dropped: neither a true nor a false positive.
- Neighbouring classes (``Van`` under car, ``Person_sitting`` under pedestrian) and objects more
  truncated than level 0 or occluded beyond level 2 (3 = unknown) are distractors: a predicted box
  that matches one is dropped, and missing one is no miss.
- A predicted box that matches no object and is at most 25 px tall in the image is dropped.

The benchmark works on image boxes; here objects and predictions are matched by centre distance
(:func:`scenes.tracking.evaluate.similarity`), and the image box of a predicted 3D box is its
projection into camera 2 (``image_02``, the camera the labels' boxes and ``DontCare`` regions are
drawn in), clipped at 0.1 m in front of the camera and to the image, as a tracker reports it for
the benchmark. Distractor flags come from the label file, joined to the ground-truth log's rows by
frame and track id: a log imported from that file (``scenesearch import kitti --labels``) has
exactly its non-``DontCare`` rows.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenes.calibration import Calibration, CameraIntrinsics
from scenes.errors import ImportFormatError
from scenes.geometry import SE3, FloatArray, quat_to_rotmat
from scenes.kitti import CAMERA_NAME, FRAME_PERIOD_NS, KITTI_EPOCH_NS, KittiLabels
from scenes.sensorsim.objects import BOX_CORNERS
from scenes.tracking.evaluate import IgnoreRules
from scenes.tracks import Annotations

#: KITTI types scored under another type's category but never counted (the devkit's neighbouring classes).
NEIGHBOURING_TYPES = ("Van", "Person_sitting")
#: Largest truncation level of a scored object (tracking labels: 0 none, 1 partly, 2 largely).
MAX_TRUNCATION = 0
#: Largest occlusion level of a scored object (0 visible, 1 partly, 2 largely occluded, 3 unknown).
MAX_OCCLUSION = 2
#: Unmatched predicted boxes this tall or less in the image are dropped.
MIN_HEIGHT_PX = 25.0
#: Unmatched predicted boxes with more than this fraction of their area in a ``DontCare`` region are dropped.
MAX_DONTCARE_OVERLAP = 0.5
#: Points closer than this to the camera plane are clipped away before projecting (metres).
NEAR_PLANE_M = 0.1

# The 12 edges of a box: corner pairs that differ in one coordinate (corner index = ix + 2 iy + 4 iz).
_EDGES = np.array([(i, i | bit) for i in range(8) for bit in (1, 2, 4) if not i & bit])


def project_boxes_px(boxes: Annotations, ego_SE3_cam: SE3, camera: CameraIntrinsics) -> FloatArray:
    """Image boxes of 3D boxes: the bounding rectangle of their projection, clipped to the image.

    Each edge of a box is cut at :data:`NEAR_PLANE_M` in front of the camera, so a box reaching
    behind the camera spans to the image border as it does on screen.

    Args:
        boxes: boxes in the ego frame.
        ego_SE3_cam: the camera's pose in the ego frame.
        camera: its intrinsics.

    Returns:
        (N, 4) ``x1 y1 x2 y2`` in pixels; all zeros for a box that is not in view.
    """
    n = len(boxes)
    if n == 0:
        return np.zeros((0, 4))
    rot = quat_to_rotmat(boxes.quat_wxyz)  # (N, 3, 3) ego_R_object
    corners_obj = BOX_CORNERS[None] * boxes.size_lwh_m[:, None, :]  # (N, 8, 3)
    corners_ego = np.einsum("nij,nkj->nki", rot, corners_obj) + boxes.center_xyz_m[:, None, :]
    cam_SE3_ego = ego_SE3_cam.inverse()
    corners = corners_ego @ cam_SE3_ego.rotation.T + cam_SE3_ego.translation  # (N, 8, 3)
    a, b = corners[:, _EDGES[:, 0]], corners[:, _EDGES[:, 1]]  # (N, 12, 3) edge ends
    za, zb = a[..., 2:], b[..., 2:]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((NEAR_PLANE_M - za) / (zb - za), 0.0, 1.0)
    cut = a + t * (b - a)  # where the edge crosses the near plane (meaningful when it does)
    ends = np.concatenate([np.where(za >= NEAR_PLANE_M, a, cut), np.where(zb >= NEAR_PLANE_M, b, cut)], axis=1)
    seen = np.concatenate([(za >= NEAR_PLANE_M) | (zb >= NEAR_PLANE_M)] * 2, axis=1)[..., 0]  # (N, 24)
    z = np.maximum(ends[..., 2], NEAR_PLANE_M)
    u = camera.fx_px * ends[..., 0] / z + camera.cx_px
    v = camera.fy_px * ends[..., 1] / z + camera.cy_px
    big = np.inf
    x1 = np.where(seen, u, big).min(1)
    y1 = np.where(seen, v, big).min(1)
    x2 = np.where(seen, u, -big).max(1)
    y2 = np.where(seen, v, -big).max(1)
    out = np.stack([np.clip(x1, 0, camera.width_px - 1), np.clip(y1, 0, camera.height_px - 1),
                    np.clip(x2, 0, camera.width_px - 1), np.clip(y2, 0, camera.height_px - 1)], axis=1)
    visible = seen.any(1) & (out[:, 2] > out[:, 0]) & (out[:, 3] > out[:, 1])
    out[~visible] = 0.0
    return np.asarray(out, dtype=np.float64)


def _frame_of(timestamps_ns: np.ndarray) -> np.ndarray:
    return (np.asarray(timestamps_ns, dtype=np.int64) - KITTI_EPOCH_NS) // FRAME_PERIOD_NS


def kitti_ignore_rules(
    gt: Annotations, labels: KittiLabels, labels_path: Path | str, pred: Annotations, calibration: Calibration,
) -> IgnoreRules:
    """The KITTI rules for a ground-truth log imported from ``labels`` and a predicted log.

    Args:
        gt: the ground-truth log's rows (one per non-``DontCare`` label row).
        labels: the label file, read by :func:`scenes.kitti.read_kitti_labels`.
        labels_path: its path, for errors.
        pred: the predicted log's rows (ego frame), projected into camera 2.
        calibration: a calibration holding camera 2 (``image_02``), as the KITTI importer writes it.

    Raises:
        ImportFormatError: a ground-truth row has no label row (not this log's label file), naming
            its frame and track.
        ValueError: the calibration has no camera 2.
    """
    if CAMERA_NAME not in calibration.intrinsics or CAMERA_NAME not in calibration.ego_SE3_sensor:
        raise ValueError(f"the calibration has no camera {CAMERA_NAME!r}: the KITTI rules need it to place "
                         "predicted boxes in the image")
    # Join on (frame, track id): both are small non-negative integers in KITTI.
    gt_frame = _frame_of(gt.timestamp_ns)
    try:
        gt_track = np.array([int(t) for t in gt.track_id], dtype=np.int64)
    except ValueError:
        raise ImportFormatError(labels_path, "the ground-truth log's track ids are not KITTI track numbers: it was "
                                "not imported from this label file", field="track_id") from None
    stride = int(max(labels.track_id.max(initial=0), gt_track.max(initial=0))) + 1
    label_key = labels.frame * stride + labels.track_id
    order = np.argsort(label_key)
    gt_key = gt_frame * stride + gt_track
    at = np.zeros(len(gt), dtype=np.intp)
    found = np.zeros(len(gt), dtype=bool)
    if len(labels):
        at = np.minimum(np.searchsorted(label_key[order], gt_key), len(labels) - 1)
        found = label_key[order][at] == gt_key
    if not found.all():
        i = int(np.argmin(found))
        raise ImportFormatError(labels_path, f"no row for frame {int(gt_frame[i])}, track {int(gt_track[i])} of the "
                                "ground-truth log: not this log's label file", field="track_id")
    row = order[at]
    distractor = (np.isin(labels.kitti_type[row], NEIGHBOURING_TYPES) | (labels.truncated[row] > MAX_TRUNCATION)
                  | (labels.occluded[row] > MAX_OCCLUSION))
    pred_box_px = project_boxes_px(pred, calibration.ego_SE3_sensor[CAMERA_NAME], calibration.intrinsics[CAMERA_NAME])
    return IgnoreRules(
        gt_distractor=np.asarray(distractor, dtype=bool),
        pred_box_px=pred_box_px,
        region_timestamp_ns=KITTI_EPOCH_NS + labels.dontcare_frame * FRAME_PERIOD_NS,
        region_box_px=labels.dontcare_box_px,
        min_height_px=MIN_HEIGHT_PX,
        max_region_overlap=MAX_DONTCARE_OVERLAP,
    )
