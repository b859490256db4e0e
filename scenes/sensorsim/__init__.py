"""Sensor simulation: LiDAR sweeps by ray casting and front-camera frames with instance masks.

Simulated logs get the same sensor files as real AV2 logs, rendered from the same scene as their
tracks, so that every later stage reads real and simulated logs through one path:

- :mod:`scenes.sensorsim.config`: :class:`SensorConfig` (LiDAR, camera, seed), YAML round trip.
- :mod:`scenes.sensorsim.ground`: the ground material raster and the kerbs, from the vector map.
- :mod:`scenes.sensorsim.world`: the static world (ground, kerbs, buildings) built once per log.
- :mod:`scenes.sensorsim.objects`: the shape of each category and the per-frame object meshes.
- :mod:`scenes.sensorsim.lidar`: :func:`~scenes.sensorsim.lidar.cast_sweep`, a spinning multi-beam LiDAR.
- :mod:`scenes.sensorsim.camera`: :func:`render_frame`, a pinhole camera drawn with OpenCV.
- :mod:`scenes.sensorsim.appearance`: time of day, weather and colours from the log metadata.
- :mod:`scenes.sensorsim.instance_masks`: per-frame instance masks beside the camera frames, and
  :func:`~scenes.sensorsim.instance_masks.read_instance_mask`.
- :mod:`scenes.sensorsim.render`: :func:`render_log_sensors`, everything for one log folder
  (``scenesearch render-sensors LOG_DIR``).
- :mod:`scenes.sensorsim.synthetic`: a small hand-built crossroad log for tests, benchmarks and
  the README images.

BEV rasters of boxes and map layers live in :mod:`scenes.bev`.
"""
