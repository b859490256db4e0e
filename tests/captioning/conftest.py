"""Hand-built scenes for the captioning tests: an ego path and objects given in the city frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest
from numpy.typing import NDArray

from captioning.config import CaptioningConfig, RuleSet
from captioning.pipeline import LogCaptions, caption_arrays
from scenes.geometry import batch_matrices, quat_to_rotmat, wrap_angle_rad, yaw_to_quat

DT_S = 0.1


@dataclass
class Scene:
    """Ego poses and object tracks; objects are given in the city frame and converted to the ego frame."""

    ego_xy_m: NDArray[np.float64]
    ego_yaw_rad: NDArray[np.float64]
    objects: list[tuple[str, str, NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]] = field(
        default_factory=list
    )
    timestamps_ns: NDArray[np.int64] | None = None

    @property
    def num_frames(self) -> int:
        return int(self.ego_xy_m.shape[0])

    def add(self, track_id: str, category: str, city_xy_m: NDArray, city_yaw_rad: NDArray | float,
            valid: NDArray | None = None) -> Scene:
        t = self.num_frames
        yaw = np.broadcast_to(np.asarray(city_yaw_rad, dtype=np.float64), (t,)).copy()
        ok = np.ones(t, bool) if valid is None else np.asarray(valid, bool)
        self.objects.append((track_id, category, np.asarray(city_xy_m, np.float64), yaw, ok))
        return self

    def add_relative(self, track_id: str, category: str, ego_xy_m: NDArray, ego_yaw_rad: NDArray | float,
                     valid: NDArray | None = None) -> Scene:
        """An object given directly in the ego frame at each frame."""
        t = self.num_frames
        rel = np.broadcast_to(np.asarray(ego_xy_m, np.float64), (t, 2))
        c, s = np.cos(self.ego_yaw_rad), np.sin(self.ego_yaw_rad)
        city = np.stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]], 1) + self.ego_xy_m
        yaw = np.broadcast_to(np.asarray(ego_yaw_rad, np.float64), (t,)) + self.ego_yaw_rad
        return self.add(track_id, category, city, yaw, valid)

    def arrays(self) -> dict[str, object]:
        t = self.num_frames
        ts = self.timestamps_ns if self.timestamps_ns is not None else (np.arange(t) * DT_S * 1e9).astype(np.int64)
        rot = quat_to_rotmat(yaw_to_quat(self.ego_yaw_rad))
        poses = batch_matrices(rot, np.c_[self.ego_xy_m, np.zeros(t)])
        k = len(self.objects)
        valid = np.zeros((k, t), bool)
        center = np.full((k, t, 2), np.nan)
        yaw = np.full((k, t), np.nan)
        c, s = np.cos(self.ego_yaw_rad), np.sin(self.ego_yaw_rad)
        for i, (_, _, xy, oyaw, ok) in enumerate(self.objects):
            d = xy - self.ego_xy_m
            ego_x = c * d[:, 0] + s * d[:, 1]
            ego_y = -s * d[:, 0] + c * d[:, 1]
            valid[i] = ok
            center[i] = np.where(ok[:, None], np.stack([ego_x, ego_y], 1), np.nan)
            yaw[i] = np.where(ok, wrap_angle_rad(oyaw - self.ego_yaw_rad), np.nan)
        return dict(
            log_id="scene",
            timestamps_ns=ts,
            track_ids=np.array([o[0] for o in self.objects], dtype=np.str_),
            categories=np.array([o[1] for o in self.objects], dtype=np.str_),
            valid=valid,
            center_ego_xy_m=center,
            yaw_ego_rad=yaw,
            city_SE3_ego=poses,
        )

    def caption(self, config: CaptioningConfig | None = None) -> LogCaptions:
        """Caption under ``config``; by default the paper's rules, which most tests here are about."""
        config = config or CaptioningConfig(rules=RuleSet.PAPER)
        return caption_arrays(config=config, **self.arrays())  # type: ignore[arg-type]


def ego_path(speed_mps: NDArray | float, yaw_rate_rps: NDArray | float = 0.0, num_frames: int = 60) -> Scene:
    """Integrate a planar ego path from per-frame speed and yaw rate, starting at the origin heading +x."""
    speed = np.broadcast_to(np.asarray(speed_mps, np.float64), (num_frames,))
    rate = np.broadcast_to(np.asarray(yaw_rate_rps, np.float64), (num_frames,))
    yaw = np.r_[0.0, np.cumsum(rate[:-1] * DT_S)]
    step = np.stack([speed * np.cos(yaw), speed * np.sin(yaw)], 1) * DT_S
    xy = np.r_[np.zeros((1, 2)), np.cumsum(step[:-1], 0)]
    return Scene(ego_xy_m=xy, ego_yaw_rad=yaw)


@pytest.fixture
def make_scene() -> object:
    """``make_scene(speed_mps, yaw_rate_rps=0, num_frames=60) -> Scene``."""
    return ego_path
