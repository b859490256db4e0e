"""Hand-built :class:`~scenarios.features.LogFeatures`: objects at known places, for the evaluation tests."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenarios.features import FLAGS, LogFeatures, flag_bit

HZ = 10


def make_features(objects: Sequence[dict[str, object]], frames: int = 20, has_map: bool = True) -> LogFeatures:
    """Features of ``objects`` (the ego last is added), each a dict with ``label``, ``category``, ``xy``
    ((frames, 2) or (2,) metres), ``yaw`` (rad), ``speed`` (m/s), ``size`` (l, w, h), ``flags`` (names
    set at every frame, or a dict name → (frames,) bool), ``valid`` ((frames,) bool), ``lane``, ``ego_lane``."""
    ego = {"label": "EGO_VEHICLE", "category": "ego", "xy": np.zeros(2), "yaw": 0.0, "speed": 0.0,
           "size": (4.877, 1.852, 1.5), "id": "ego"}
    rows = [*objects, ego]
    k = len(rows)
    ts = (np.arange(frames, dtype=np.int64) * (1_000_000_000 // HZ)) + 1_000_000_000_000
    valid = np.zeros((k, frames), bool)
    xy = np.full((k, frames, 2), np.nan, np.float32)
    yaw = np.zeros((k, frames), np.float32)
    speed = np.zeros((k, frames), np.float32)
    flags = np.zeros((k, frames), np.uint16)
    lane = np.full((k, frames), -1, np.int32)
    ego_lane = np.full((k, frames), -1, np.int8)
    for i, row in enumerate(rows):
        valid[i] = np.asarray(row.get("valid", np.ones(frames, bool)))
        pos = np.asarray(row.get("xy", np.zeros(2)), np.float32)
        xy[i] = np.broadcast_to(pos, (frames, 2)) if pos.ndim == 1 else pos
        yaw[i] = np.asarray(row.get("yaw", 0.0), np.float32)
        speed[i] = np.asarray(row.get("speed", 0.0), np.float32)
        lane[i] = np.asarray(row.get("lane", -1))
        ego_lane[i] = np.asarray(row.get("ego_lane", -1))
        given = row.get("flags", ())
        for name in given:  # type: ignore[attr-defined]
            mask = given[name] if isinstance(given, dict) else np.ones(frames, bool)
            flags[i] |= np.where(mask, flag_bit(name), 0).astype(np.uint16)
    assert set(FLAGS)  # every flag name used above is one of FLAGS (flag_bit raises otherwise)
    velocity = np.stack([np.cos(yaw) * speed, np.sin(yaw) * speed], axis=-1).astype(np.float32)
    return LogFeatures(
        log_id="synthetic", timestamps_ns=ts,
        track_ids=np.asarray([str(r.get("id", f"t{i}")) for i, r in enumerate(rows)]),
        labels=np.asarray([str(r["label"]) for r in rows]), categories=np.asarray([str(r["category"]) for r in rows]),
        valid=valid, xy_m=np.where(valid[..., None], xy, np.nan).astype(np.float32),
        z_m=np.zeros((k, frames), np.float32),
        yaw_rad=yaw, size_lwh_m=np.asarray([r.get("size", (4.5, 1.9, 1.6)) for r in rows], np.float32),
        velocity_mps=velocity, speed_mps=speed, accel_mps2=np.zeros((k, frames), np.float32),
        flags=np.where(valid, flags, 0).astype(np.uint16), ego_lane=ego_lane,
        lane=lane, to_junction_m=np.full((k, frames), np.inf, np.float32), has_map=has_map,
    )


def car(xy: object, **more: object) -> dict[str, object]:
    return {"label": "REGULAR_VEHICLE", "category": "car", "xy": xy, "speed": 5.0, **more}


def cyclist(xy: object, **more: object) -> dict[str, object]:
    return {"label": "BICYCLIST", "category": "cyclist", "xy": xy, "speed": 4.0, "size": (1.8, 0.6, 1.7), **more}


def pedestrian(xy: object, **more: object) -> dict[str, object]:
    return {"label": "PEDESTRIAN", "category": "pedestrian", "xy": xy, "speed": 1.2, "size": (0.6, 0.6, 1.7), **more}
