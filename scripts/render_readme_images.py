"""Render the sensor images shown in the README into ``docs/images/``.

    .venv/bin/python scripts/render_readme_images.py [--out docs/images]

From the hand-built crossroad log (:mod:`scenes.sensorsim.synthetic`), rendered through the same
path as simulated logs (:func:`scenes.sensorsim.render.render_log_sensors`), it writes:

- ``camera_day.png``, ``camera_dusk_rain.png``, ``camera_night.png``, ``camera_fog.png``: the front
  camera under four appearances;
- ``camera_instances.png``: the day frame with its instance mask overlaid (each track its colour);
- ``lidar_bev.png``: one LiDAR sweep seen from above, coloured by height, with the annotated boxes;
- ``bev_raster.png``: the BEV raster of map layers and boxes (:mod:`scenes.bev`).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from scenes.bev import BevGrid, MapRasterizer, rasterize_boxes
from scenes.geometry import SE3
from scenes.log import Log
from scenes.sensorsim.config import SensorConfig
from scenes.sensorsim.instance_masks import read_instance_mask
from scenes.sensorsim.render import render_log_sensors
from scenes.sensorsim.synthetic import write_synthetic_log

FRAME = 12  # the frame shown (1.2 s into the log)
LOOKS = {"day": ("day", "clear"), "dusk_rain": ("dusk", "rain"), "night": ("night", "clear"), "fog": ("day", "fog")}


def _palette(n: int) -> NDArray[np.uint8]:
    hue = (np.arange(n) * 47) % 180
    hsv = np.stack([hue, np.full(n, 200), np.full(n, 255)], axis=1).astype(np.uint8)[None]
    return np.asarray(cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0], dtype=np.uint8)


def _write_png(path: Path, image: NDArray[np.uint8]) -> None:
    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise RuntimeError(f"cannot encode {path}")
    path.write_bytes(data.tobytes())
    print(f"wrote {path} ({len(data) // 1024} KB)")


def _lidar_bev(log: Log, ts: int, grid: BevGrid, scale: int) -> NDArray[np.uint8]:
    sweep = log.lidar_sweep(ts)
    h, w = grid.height * scale, grid.width * scale
    image = np.full((h, w, 3), 12, np.uint8)
    fine = BevGrid(grid.x_min_m, grid.x_max_m, grid.y_min_m, grid.y_max_m, grid.resolution_m / scale)
    px = np.round(fine.ego_to_pixel(sweep.xyz_m[:, :2].astype(np.float64))).astype(np.int64)
    ok = (px[:, 0] >= 0) & (px[:, 0] < w - 1) & (px[:, 1] >= 0) & (px[:, 1] < h - 1)
    z = sweep.xyz_m[ok, 2].astype(np.float64)
    # Ground by intensity (paint shows up bright), everything above it by height.
    gray = np.clip(40 + 1.6 * sweep.intensity[ok].astype(np.float64), 0, 255).astype(np.uint8)
    colors = np.repeat(gray[:, None], 3, axis=1)
    above = z > 0.25
    heat = np.round(np.clip(0.15 + z[above] / 4.0, 0.0, 1.0) * 255).astype(np.uint8)[:, None]
    colors[above] = cv2.applyColorMap(heat, cv2.COLORMAP_TURBO)[:, 0]
    order = np.argsort(z)  # higher points drawn last
    rows, cols = px[ok, 1][order], px[ok, 0][order]
    for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
        image[rows + dr, cols + dc] = colors[order]
    dense = log.dense_tracks()
    frame = int(np.searchsorted(dense.timestamps_ns, ts))
    for k in np.flatnonzero(dense.valid[:, frame]):
        c, s = np.cos(dense.yaw_ego_rad[k, frame]), np.sin(dense.yaw_ego_rad[k, frame])
        half = 0.5 * dense.size_lwh_m[k, frame, :2]
        corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * half
        xy = dense.center_ego_xyz_m[k, frame, :2] + corners @ np.array([[c, s], [-s, c]])
        poly = np.round(fine.ego_to_pixel(xy) * 16).astype(np.int32)
        cv2.polylines(image, [poly], True, (0, 220, 255), 1, cv2.LINE_AA, shift=4)
    ego = np.round(fine.ego_to_pixel(np.array([[0.0, 0.0]]))[0]).astype(int)
    cv2.circle(image, (int(ego[0]), int(ego[1])), 4, (0, 0, 255), -1)
    return image


def _bev_raster(log: Log, ts: int, grid: BevGrid, scale: int) -> NDArray[np.uint8]:
    dense = log.dense_tracks()
    frame = int(np.searchsorted(dense.timestamps_ns, ts))
    assert log.map is not None
    layers = MapRasterizer(log.map).rasterize(grid, SE3.from_matrix(dense.city_SE3_ego[frame]))
    image = np.zeros((*grid.shape, 3), np.float32)
    image[layers["drivable_area"] > 0] = (70, 70, 70)
    heading = np.arctan2(layers["lane_direction_sin"], layers["lane_direction_cos"])
    on_lane = (layers["lane_direction_cos"] != 0) | (layers["lane_direction_sin"] != 0)
    image[on_lane & (np.abs(heading) < np.pi / 2)] = (90, 80, 60)  # lanes running with the ego
    image[on_lane & (np.abs(heading) >= np.pi / 2)] = (60, 70, 95)  # lanes running against it
    image[layers["intersections"] > 0] = (100, 100, 100)
    image[layers["crosswalks"] > 0] = (200, 200, 200)
    image[layers["lane_boundaries"] > 0] = (240, 240, 240)
    valid = np.flatnonzero(dense.valid[:, frame])
    ids = rasterize_boxes(grid, dense.center_ego_xyz_m[valid, frame, :2], dense.size_lwh_m[valid, frame, :2],
                          dense.yaw_ego_rad[valid, frame], values=(valid + 1).astype(np.float32))
    colors = _palette(len(dense.track_ids) + 1)
    hit = ids > 0
    image[hit] = colors[ids[hit].astype(np.int64)]
    big = cv2.resize(image.astype(np.uint8), (grid.width * scale, grid.height * scale),
                     interpolation=cv2.INTER_NEAREST)
    ego = np.round(grid.ego_to_pixel(np.array([[0.0, 0.0]]))[0] * scale + scale / 2).astype(int)
    cv2.circle(big, (int(ego[0]), int(ego[1])), 4, (0, 0, 255), -1)
    return np.asarray(big, dtype=np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "images")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    config = SensorConfig()
    with tempfile.TemporaryDirectory() as tmp:
        logs: dict[str, Path] = {}
        for name, (tod, weather) in LOOKS.items():
            log_dir = write_synthetic_log(Path(tmp) / name, num_frames=FRAME + 1, num_objects=40, seed=4,
                                          time_of_day=tod, weather=weather, ego_start_x_m=62.0)
            render_log_sensors(log_dir, config if name == "day" else SensorConfig(render_lidar=False), progress=False)
            logs[name] = log_dir
        day = Log.open(logs["day"])
        ts = int(day.timestamps_ns[FRAME])
        for name, log_dir in logs.items():
            _write_png(args.out / f"camera_{name}.png", Log.open(log_dir).camera_frame(config.camera.name, ts))
        image = day.camera_frame(config.camera.name, ts)
        mask, track_ids = read_instance_mask(logs["day"], config.camera.name, ts)
        colors = _palette(len(track_ids) + 1)
        overlay = image.copy()
        overlay[mask > 0] = (0.35 * image[mask > 0] + 0.65 * colors[mask[mask > 0]]).astype(np.uint8)
        _write_png(args.out / "camera_instances.png", overlay)
        grid = BevGrid(x_min_m=-20.0, x_max_m=60.0, y_min_m=-20.0, y_max_m=20.0, resolution_m=0.25)
        _write_png(args.out / "lidar_bev.png", _lidar_bev(day, ts, grid, scale=2))
        _write_png(args.out / "bev_raster.png", _bev_raster(day, ts, BevGrid(), scale=4))


if __name__ == "__main__":
    main()
