"""Import KITTI tracking sequences into the Argoverse 2 log layout.

Modules: :mod:`~scenes.kitti.text` (reading the text files), :mod:`~scenes.kitti.calibration`
(``calib/<seq>.txt`` and the sensor frames), :mod:`~scenes.kitti.labels` (``label_02/<seq>.txt``),
:mod:`~scenes.kitti.poses` (``poses/<seq>.txt`` and the timestamps), :mod:`~scenes.kitti.boxes`
(camera-frame boxes to ego-frame boxes and back) and :mod:`~scenes.kitti.importer` (one sequence
into a log folder).

Inputs (one sequence ``<seq>``, e.g. ``0001``):

- ``label_02/<seq>.txt``: one object per line,
  ``frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]``.
- ``poses/<seq>.txt``: line i = frame i, a row-major 3×4 camera-to-world pose ``world_SE3_cam_i``.
- ``calib/<seq>.txt``: ``P0``–``P3``, ``R0_rect`` (or ``R_rect``), ``Tr_velo_to_cam`` (or ``Tr_velo_cam``).

Output: ``<out>/kitti_<seq>/`` with ``annotations.feather``, ``city_SE3_egovehicle.feather``,
``calibration/`` and ``log_metadata.json``.

Frames and the conversion
=========================

``cam``: the rectified reference camera of KITTI, in which labels and poses are given::

    cam:  x right, y down, z forward (optical axis)

``velo``: the Velodyne frame, x forward, y left, z up, mounted 1.73 m above the road (KITTI set-up).
A Velodyne point maps into the unrectified camera by ``Tr_velo_to_cam`` and then into the
rectified camera by ``R0_rect``, so::

    cam_SE3_velo = [R0_rect | 0] ∘ Tr_velo_to_cam

``ego``: the log's ego frame (x forward, y left, z up, as everywhere in :mod:`scenes`). Its axes are
the Velodyne's; its origin is the road point straight below the Velodyne, so that box centres sit at
about half their height, as in AV2 (whose origin is on the ground too)::

    ego_SE3_velo = translation (0, 0, +VELODYNE_HEIGHT_M)
    ego_SE3_cam  = ego_SE3_velo ∘ cam_SE3_velo⁻¹

Boxes. A KITTI label gives the *bottom* centre ``(x, y, z)`` in ``cam``, the size ``h w l`` and
``rotation_y``, the rotation about the camera's y axis. The KITTI devkit builds the box corners as
``R_y(ry) · corner + (x, y, z)`` with ``R_y(ry) = [[cos ry, 0, sin ry], [0, 1, 0], [−sin ry, 0, cos ry]]``,
the length along the object's own x axis, the height along −y (up) and the width along z. So the
object's heading (its length axis) in ``cam`` is ``R_y(ry)·(1, 0, 0) = (cos ry, 0, −sin ry)``: ry = 0
faces camera-right, ry = −π/2 faces forward (+z). The box centre is half a height above the bottom
centre, i.e. ``(x, y − h/2, z)`` because y points down.

The AV2 object frame (x along the length, y left, z up) written in KITTI object axes is
``x_obj = x_k``, ``z_obj = −y_k`` and ``y_obj = z_obj × x_obj = z_k``, i.e.::

    kobj_R_obj = [[1, 0, 0], [0, 0, −1], [0, 1, 0]]     (columns: obj x, y, z in KITTI object axes)
    ego_R_obj  = ego_R_cam · R_y(ry) · kobj_R_obj
    centre_ego = ego_SE3_cam · (x, y − h/2, z)
    size_lwh   = (l, w, h)

With the nominal calibration (``ego_R_cam`` maps cam z → ego x, cam x → −ego y, cam y → −ego z) the
heading ``(cos ry, 0, −sin ry)`` becomes ``(−sin ry, −cos ry, 0)`` in ``ego``, so
``yaw_ego = −ry − π/2``, the well-known KITTI camera → LiDAR yaw relation. The importer uses the
full rotation above (the real calibration tilts the camera by about a degree), which
:func:`ego_boxes_to_kitti` inverts exactly.

Ego poses. The pose file gives ``world_SE3_cam_i`` with ``world`` = the camera frame of some
reference frame (the first, as identity). The city frame is chosen as the ego frame at frame 0, so
that it is z up, x forward at the start::

    city_SE3_world = ego_SE3_cam ∘ world_SE3_cam_0⁻¹
    city_SE3_ego_i = city_SE3_world ∘ world_SE3_cam_i ∘ ego_SE3_cam⁻¹

Timestamps. KITTI tracking has no absolute times; frames are 10 Hz. Frame i gets
``KITTI_EPOCH_NS + i × FRAME_PERIOD_NS`` with ``KITTI_EPOCH_NS`` = 2011-09-26 00:00:00 UTC (the
first KITTI recording day), so timestamps look like real ones and never start at zero.

Categories. KITTI types map through :data:`scenes.categories.KITTI_TO_CATEGORY`; the file's
``category`` column holds the AV2 label of the mapped category (:data:`CATEGORY_TO_AV2`). Unknown
types map to ``other`` and are counted; ``DontCare`` rows are dropped and counted. Both counts and
the per-type row counts are kept in ``log_metadata.json``.

Line numbers in errors are 1-based, as in an editor.
"""

from scenes.kitti.boxes import ego_boxes_to_kitti, kitti_boxes_to_ego
from scenes.kitti.calibration import (
    CAMERA_NAME,
    DEFAULT_IMAGE_SIZE_PX,
    LIDAR_NAME,
    VELODYNE_HEIGHT_M,
    KittiCalibration,
    kitti_calibration_to_av2,
    read_kitti_calibration,
)
from scenes.kitti.importer import (
    KittiImportReport,
    import_kitti_sequence,
    kitti_labels_to_annotations,
    sequence_name,
    write_kitti_log,
)
from scenes.kitti.labels import DONTCARE, LABEL_FIELDS, KittiLabels, read_kitti_labels
from scenes.kitti.poses import (
    FRAME_PERIOD_NS,
    KITTI_EPOCH_NS,
    POSE_ORTHONORMAL_TOLERANCE,
    ego_trajectory_from_kitti,
    read_kitti_poses,
)

__all__ = [
    "CAMERA_NAME",
    "DEFAULT_IMAGE_SIZE_PX",
    "DONTCARE",
    "FRAME_PERIOD_NS",
    "KITTI_EPOCH_NS",
    "LABEL_FIELDS",
    "LIDAR_NAME",
    "POSE_ORTHONORMAL_TOLERANCE",
    "VELODYNE_HEIGHT_M",
    "KittiCalibration",
    "KittiImportReport",
    "KittiLabels",
    "ego_boxes_to_kitti",
    "ego_trajectory_from_kitti",
    "import_kitti_sequence",
    "kitti_boxes_to_ego",
    "kitti_calibration_to_av2",
    "kitti_labels_to_annotations",
    "read_kitti_calibration",
    "read_kitti_labels",
    "read_kitti_poses",
    "sequence_name",
    "write_kitti_log",
]
