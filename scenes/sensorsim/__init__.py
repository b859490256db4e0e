"""Sensor simulation: LiDAR sweeps by ray casting and front-camera frames with instance masks.

Simulated logs get the same sensor files as real AV2 logs, rendered from the same scene as their
tracks, so that every later stage reads real and simulated logs through one path:

- :mod:`scenes.sensorsim.config`: :class:`SensorConfig` (LiDAR, camera, seed), YAML round trip.
- :mod:`scenes.sensorsim.scene`: the static world (ground, kerbs, buildings) built once per log,
  and the per-frame object meshes.
- :mod:`scenes.sensorsim.lidar`: :func:`simulate_sweep`, a spinning multi-beam LiDAR.
- :mod:`scenes.sensorsim.camera`: :func:`render_frame`, a pinhole camera drawn with OpenCV.
- :mod:`scenes.sensorsim.instance_masks`: per-frame instance masks beside the camera frames.
- :mod:`scenes.sensorsim.render`: :func:`render_log_sensors`, everything for one log folder.
"""
