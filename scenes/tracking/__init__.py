"""3D multi-object tracking: turn per-frame detections into the tracks of the log contract.

A Kalman-filter tracker in the spirit of AB3DMOT: constant velocity in the city frame (ego motion
removed with the log's poses), Hungarian association per category, birth after ``min_hits``
matches, death after ``max_age`` missed frames, and yaw-flip handling.
"""

from scenes.tracking.config import TrackerConfig
from scenes.tracking.detections import Detections
from scenes.tracking.kitti_detections import import_kitti_detections
from scenes.tracking.tracker import Tracker, track_detections

__all__ = ["Detections", "Tracker", "TrackerConfig", "import_kitti_detections", "track_detections"]
