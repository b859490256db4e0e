"""Clips: clips/s produced, samples/s loaded by the dataset, disk per clip and per log.

Logs come from the simulator with rendered sensors (``scenesearch simulate`` + the sensor
simulation) and captions from ``scenesearch caption``; where either is unavailable the benchmark
falls back to the synthetic logs of :mod:`tests.encoders.clip_fixtures` and caption windows cut every
2 s per track, and says so in ``log_source`` / ``caption_source``.

Baseline (same run): rendering each clip's frames on its own, from the log files, as a pipeline
without per-log arrays would (``naive_clips_per_s``). Figures:

- ``clips_per_s``: clips produced per second by ``build_clips`` (rendering + table, no previews)
- ``samples_per_s_workers2`` / ``_augmented`` / ``_augmented_uint8``: dataset samples per second
  through a DataLoader with 2 workers, batch 16, at the default clip settings; ``uint8`` keeps the
  image-like views as bytes (``ClipDataset(as_uint8=True)``; the model converts them on its device),
  which is how ``scenesearch train`` loads. Target: ≥ 200 on that training path (augmented, uint8),
  ``loading_target_200_met``
- ``samples_per_cpu_s_*``: item + collate per CPU-second of one process, which does not depend on
  other load on the machine (wall-clock rates do: ``load_average_during_loading``)
- ``*_vs_naive``: those divided by ``naive_clips_per_s``
- disk: ``mb_per_log``, ``kb_per_frame``, ``kb_per_clip`` (rendered arrays shared by clips),
  ``kb_per_preview``
- ``lidar_counting``: CPU milliseconds a frame of :func:`scenes.bev.count_points` (each sweep moved
  and binned by one float32 product) against the same counts binned in float64 behind masks, as
  rendering did before (the sweeps read beforehand for both), and how many counts differ (points
  within float32 rounding of a cell edge)
- ``block_codec``: every rendered array of the clips folder compressed in blocks by
  :func:`encoders.clips.blocks.write_blocks`'s codec (zstd) and by zlib at level 1, as the blocks were
  before, and decompressed again: CPU milliseconds a frame each way, the bytes, and their ratios
- ``image_filter``: the RGB image files (camera frames, object crops) written again with and without
  the Sub filter (``write_blocks(..., image=True)``) and read back: bytes, CPU milliseconds a frame
  each way; ``kb_per_frame_images_unfiltered`` is ``kb_per_frame`` as it would be without the
  filter, the baseline of the same run
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from scenesearch_base.ray_cluster import usable_cpus

WORK = Path(__file__).resolve().parent / "_work" / "clips"


def _simulated_logs(n: int, duration_s: float, out: Path) -> list[Path]:
    """Simulated logs with sensors, cached between runs."""
    marker = out / f".done_{n}_{duration_s:g}"
    if marker.is_file():
        return sorted(p for p in out.iterdir() if p.is_dir())
    shutil.rmtree(out, ignore_errors=True)
    subprocess.run(
        [sys.executable, "-m", "retrieval.cli", "simulate", "--out", str(out), "--logs", str(n),
         "--duration-s", str(duration_s), "--seed", "0"],
        check=True, capture_output=True, text=True,
    )
    from scenes.sensorsim.render import render_log_sensors

    logs = sorted(p for p in out.iterdir() if p.is_dir())
    for log_dir in logs:
        render_log_sensors(log_dir, progress=False)
    marker.write_text("ok")
    return logs


def _synthetic_logs(n: int, duration_s: float, out: Path) -> list[Path]:
    from tests.encoders.clip_fixtures import write_synthetic_log

    shutil.rmtree(out, ignore_errors=True)
    return [write_synthetic_log(out, f"synthetic_{i:04d}", num_frames=int(duration_s * 10), seed=i) for i in range(n)]


def _window_captions(logs: list[Path], out: Path) -> None:
    """One caption per track and 3 s window, every 2 s (the captioning stage stands in)."""
    from scenes.log import Log

    rows = []
    for log_dir in logs:
        dense = Log.open(log_dir).dense_tracks()
        ts = dense.timestamps_ns
        for k, track_id in enumerate(dense.track_ids):
            for start in range(0, ts.shape[0] - 30, 20):
                if dense.valid[k, start : start + 30].all():
                    rows.append({
                        "log_id": log_dir.name, "track_id": str(track_id), "category": str(dense.categories[k]),
                        "start_ns": int(ts[start]), "end_ns": int(ts[start + 29]), "tags": [],
                        "caption": "a vehicle", "canonical_caption": "a vehicle", "paraphrases": [], "host_tags": [],
                    })
    out.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), out / "captions.parquet")


def _captions(logs: list[Path], out: Path) -> str:
    shutil.rmtree(out, ignore_errors=True)
    try:
        subprocess.run([sys.executable, "-m", "retrieval.cli", "caption", *map(str, logs), "--out", str(out)],
                       check=True, capture_output=True, text=True)
        table = pq.read_table(out / "captions.parquet")
        if int((np.asarray(table.column("track_id").to_pylist()) != "ego").sum()) > 0:
            return "scenesearch caption"
    except (subprocess.CalledProcessError, FileNotFoundError, OSError):
        pass
    _window_captions(logs, out)
    return "windows every 2 s per track"


def _loader_rate(clips_dir: Path, augment: bool, workers: int, min_samples: int, as_uint8: bool = False) -> float:
    """Samples per second (wall) through a DataLoader, batch 16, after a warm-up batch."""
    import torch

    from encoders.data import ClipDataset, collate_clips

    ds = ClipDataset(clips_dir, augment=augment, as_uint8=as_uint8)
    loader = torch.utils.data.DataLoader(ds, batch_size=16, shuffle=True, num_workers=workers,
                                         collate_fn=collate_clips, persistent_workers=workers > 0)
    for _ in loader:  # warm-up: workers start, pages are cached
        break
    seen, start, epoch = 0, time.perf_counter(), 0
    while seen < min_samples:
        ds.set_epoch(epoch)
        for batch in loader:
            seen += len(batch["clip_id"])
        epoch += 1
    return seen / (time.perf_counter() - start)


def _cpu_rate(clips_dir: Path, augment: bool, as_uint8: bool, samples: int) -> float:
    """Samples (batched fetch + collate) per CPU-second of one process: independent of other load on the machine."""
    from encoders.data import ClipDataset, collate_clips

    ds = ClipDataset(clips_dir, augment=augment, as_uint8=as_uint8)
    ds.__getitems__([0])
    start = time.process_time()
    for first in range(0, samples, 16):  # the DataLoader's batched path
        collate_clips(ds.__getitems__([i % len(ds) for i in range(first, first + 16)]))
    return samples / (time.process_time() - start)


def _naive_clips_per_s(logs: list[Path], clips_dir: Path, config: Any, max_clips: int) -> float:
    """Render each clip's own frames from the log files (no per-log arrays)."""
    from encoders.clips.layout import read_clip_table
    from encoders.clips.render import render_log
    from scenes.log import Log

    table = read_clip_table(clips_dir).to_pylist()[:max_clips]
    by_id = {p.name: p for p in logs}
    opened: dict[str, Any] = {}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for row in table:
            if row["log_id"] not in opened:
                log = Log.open(by_id[row["log_id"]])
                opened[row["log_id"]] = (log, log.dense_tracks())
            log, dense = opened[row["log_id"]]
            frames = np.unique(np.asarray(row["frame_indices"]))
            subset = replace(
                dense, timestamps_ns=dense.timestamps_ns[frames], valid=dense.valid[:, frames],
                center_ego_xyz_m=dense.center_ego_xyz_m[:, frames], yaw_ego_rad=dense.yaw_ego_rad[:, frames],
                center_city_xyz_m=dense.center_city_xyz_m[:, frames], yaw_city_rad=dense.yaw_city_rad[:, frames],
                size_lwh_m=dense.size_lwh_m[:, frames], city_SE3_ego=dense.city_SE3_ego[frames],
            )
            render_log(log, config, Path(tmp), subset)
    return len(table) / (time.perf_counter() - start)


def _counts_with_masks(grid: Any, z_bins_m: np.ndarray,
                       clouds: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(Z, H, W) the baseline of :func:`scenes.bev.count_points`: points moved in float32, then binned
    in float64 and kept by masks over every point."""
    moved = [(ego_SE3_cloud[:3, :3].astype(np.float32) @ xyz_m).T + ego_SE3_cloud[:3, 3].astype(np.float32)
             for xyz_m, ego_SE3_cloud in clouds]
    pts = np.concatenate(moved).astype(np.float64)
    h, w = grid.shape
    z_count = z_bins_m.shape[0] - 1
    row = np.floor((grid.x_max_m - pts[:, 0]) / grid.resolution_m).astype(np.int64)
    col = np.floor((grid.y_max_m - pts[:, 1]) / grid.resolution_m).astype(np.int64)
    z_bin = np.searchsorted(z_bins_m, pts[:, 2], side="right") - 1
    ok = (row >= 0) & (row < h) & (col >= 0) & (col < w) & (z_bin >= 0) & (z_bin < z_count)
    flat = (z_bin[ok] * h + row[ok]) * w + col[ok]
    return np.bincount(flat, minlength=z_count * h * w).reshape(z_count, h, w)


def _lidar_counting(logs: list[Path], config: Any, max_frames: int) -> dict[str, Any]:
    """:func:`scenes.bev.count_points` against :func:`_counts_with_masks` on the logs' own sweeps."""
    from encoders.clips.render import bev_grid, nearest_within
    from scenes.bev import count_points
    from scenes.geometry import invert_matrices
    from scenes.log import Log

    grid, b = bev_grid(config), config.bev
    z_bins_m = np.asarray(b.z_bins_m, dtype=np.float64)
    frames: list[list[tuple[np.ndarray, np.ndarray]]] = []
    for path in logs:
        log = Log.open(path)
        sweep_ts = log.lidar_timestamps_ns
        if sweep_ts.shape[0] == 0:
            continue
        dense = log.dense_tracks()
        sweep_index = nearest_within(sweep_ts, dense.timestamps_ns, b.sweep_tolerance_ns)
        city_SE3_sweep = log.ego.interpolate(sweep_ts).matrices
        ego_SE3_city = invert_matrices(dense.city_SE3_ego)
        points: dict[int, np.ndarray] = {}
        for fi in np.flatnonzero(sweep_index >= 0):
            j = int(sweep_index[fi])
            clouds = []
            for jj in range(j, max(j - b.num_sweeps, -1), -1):
                if jj not in points:
                    points[jj] = np.ascontiguousarray(log.lidar_points(int(sweep_ts[jj])).T)
                clouds.append((points[jj], ego_SE3_city[fi] @ city_SE3_sweep[jj]))
            frames.append(clouds)
            if len(frames) >= max_frames:
                break
        if len(frames) >= max_frames:
            break
    if not frames:
        return {"frames": 0}
    start = time.process_time()
    fast = [count_points(grid, z_bins_m, clouds) for clouds in frames]
    fast_s = time.process_time() - start
    start = time.process_time()
    reference = [_counts_with_masks(grid, z_bins_m, clouds) for clouds in frames]
    reference_s = time.process_time() - start
    differing = sum(int((a != r).sum()) for a, r in zip(fast, reference, strict=True))
    return {"frames": len(frames), "ms_per_frame": round(1e3 * fast_s / len(frames), 3),
            "masked_float64_ms_per_frame": round(1e3 * reference_s / len(frames), 3),
            "speedup": round(reference_s / max(fast_s, 1e-9), 2), "differing_counts": differing,
            "counts": int(sum(a.size for a in fast))}


def _block_codec(clips_dir: Path) -> dict[str, Any]:
    """The blocks' codec against zlib level 1 on the same rendered arrays (CPU time of this process)."""
    import zlib

    from encoders.clips.blocks import BLOCK_FRAMES, CODEC, CODEC_LEVEL, BlockArray

    blocks: list[bytes] = []
    frames = 0
    for path in sorted(clips_dir.glob("logs/*/*.blocks")):
        array = np.ascontiguousarray(BlockArray(path)[:])
        blocks += [array[i:i + BLOCK_FRAMES].tobytes() for i in range(0, array.shape[0], BLOCK_FRAMES)]
        if path.name == "bev_lidar.blocks":
            frames += array.shape[0]
    codec = pa.Codec(CODEC, compression_level=CODEC_LEVEL)
    figures: dict[str, dict[str, float]] = {}
    for name, compress, decompress in (
        (CODEC, lambda b: codec.compress(b, asbytes=True),
         lambda c, n: codec.decompress(c, decompressed_size=n, asbytes=True)),
        ("zlib_1", lambda b: zlib.compress(b, 1), lambda c, n: zlib.decompress(c)),
    ):
        start = time.process_time()
        packed = [compress(b) for b in blocks]
        compress_s = time.process_time() - start
        start = time.process_time()
        for c, b in zip(packed, blocks, strict=True):
            decompress(c, len(b))
        decompress_s = time.process_time() - start
        figures[name] = {"compress_ms_per_frame": round(1e3 * compress_s / max(frames, 1), 3),
                         "decompress_ms_per_frame": round(1e3 * decompress_s / max(frames, 1), 3),
                         "mb": round(sum(map(len, packed)) / 1e6, 2)}
    new, old = figures[CODEC], figures["zlib_1"]
    return {"frames": frames, "raw_mb": round(sum(map(len, blocks)) / 1e6, 2), **figures,
            "compress_speedup": round(old["compress_ms_per_frame"] / max(new["compress_ms_per_frame"], 1e-9), 2),
            "decompress_speedup": round(old["decompress_ms_per_frame"] / max(new["decompress_ms_per_frame"], 1e-9), 2),
            "size_ratio": round(new["mb"] / max(old["mb"], 1e-9), 3)}


def _image_filter(clips_dir: Path) -> dict[str, Any]:
    """The RGB image files (camera frames, object crops) written again without the Sub filter and with
    it, as the clips stage writes them (:mod:`encoders.clips.blocks`): bytes, CPU milliseconds a
    frame to write and to read each, and the bytes a frame the whole folder would take without it."""
    import tempfile

    from encoders.clips.blocks import BlockArray, write_blocks

    arrays = [np.asarray(BlockArray(p)[:]) for name in ("camera", "camera_crops")
              for p in sorted(clips_dir.glob(f"logs/*/{name}.blocks"))]
    frames = sum(BlockArray(p).shape[0] for p in clips_dir.glob("logs/*/bev_lidar.blocks"))
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, image in (("plain", False), ("sub", True)):
            paths = [Path(tmp) / f"{name}_{i}.blocks" for i in range(len(arrays))]
            start = time.process_time()
            for path, array in zip(paths, arrays, strict=True):
                write_blocks(path, array, image=image)
            write_s = time.process_time() - start
            start = time.process_time()
            for path in paths:  # new files: none of their blocks is decoded already
                BlockArray(path)[:]
            read_s = time.process_time() - start
            out[name] = {"mb": round(sum(p.stat().st_size for p in paths) / 1e6, 2),
                         "write_ms_per_frame": round(1e3 * write_s / max(frames, 1), 3),
                         "read_ms_per_frame": round(1e3 * read_s / max(frames, 1), 3)}
    out["size_ratio"] = round(out["sub"]["mb"] / max(out["plain"]["mb"], 1e-9), 3)
    out["extra_kb_per_frame_without"] = round(1e3 * (out["plain"]["mb"] - out["sub"]["mb"]) / max(frames, 1), 1)
    return out


def _track_kinematics(clips_dir: Path) -> dict[str, Any]:
    """:func:`encoders.clips.views.log_rates_and_velocity` against the same kinematics track by track."""
    from encoders.clips.views import log_rates_and_velocity, object_rates_and_velocity, open_log_arrays

    logs = [open_log_arrays(clips_dir, p.name) for p in sorted((clips_dir / "logs").iterdir()) if p.is_dir()]
    inputs = [(np.asarray(a.track_boxes[:]), a.pose_xy_yaw, a.time_s) for a in logs]
    start = time.process_time()
    together = [log_rates_and_velocity(*x) for x in inputs]
    log_s = time.process_time() - start
    start = time.process_time()
    alone = [np.stack([object_rates_and_velocity(boxes[:, k], pose, t) for k in range(boxes.shape[1])])
             for boxes, pose, t in inputs]
    track_s = time.process_time() - start
    tracks = sum(boxes.shape[1] for boxes, _, _ in inputs)
    return {"tracks": tracks, "per_log_ms_per_track": round(1e3 * log_s / max(tracks, 1), 3),
            "per_track_ms_per_track": round(1e3 * track_s / max(tracks, 1), 3),
            "speedup": round(track_s / max(log_s, 1e-9), 2),
            "equal": all(np.array_equal(a, b) for a, b in zip(together, alone, strict=True))}


def run(quick: bool) -> dict[str, Any]:
    from encoders.clips.build import build_clips
    from encoders.clips.config import ClipsConfig
    from encoders.clips.layout import PREVIEWS_DIR, preview_file_name, read_clip_table
    from encoders.clips.preview import write_preview

    n_logs, duration_s = (2, 10.0) if quick else (4, 20.0)
    WORK.mkdir(parents=True, exist_ok=True)
    try:
        logs = _simulated_logs(n_logs, duration_s, WORK / "sim_logs")
        log_source = "scenesearch simulate + sensor simulation"
    except Exception as exc:  # any simulator failure falls back to synthetic logs
        print(f"simulator unavailable ({type(exc).__name__}: {str(exc)[:200]}); using synthetic logs")
        logs = _synthetic_logs(n_logs, duration_s, WORK / "synthetic_logs")
        log_source = "tests.encoders.clip_fixtures synthetic logs"
    caption_source = _captions(logs, WORK / "captions")

    config = replace(ClipsConfig(), previews=False)
    clips_dir = WORK / "clips"
    shutil.rmtree(clips_dir, ignore_errors=True)
    start = time.perf_counter()
    report = build_clips(logs, WORK / "captions", clips_dir, config, reuse=False)
    build_s = time.perf_counter() - start
    num_clips = report.num_clips
    frames = sum(int(s["frames"]) for s in report.logs.values())
    log_bytes = sum(int(s["bytes"]) for s in report.logs.values())

    rows = read_clip_table(clips_dir).to_pylist()[: 8 if quick else 24]
    start = time.perf_counter()
    preview_bytes = 0
    for row in rows:
        path = clips_dir / PREVIEWS_DIR / preview_file_name(row["clip_id"])
        write_preview(clips_dir, row, path, config)
        preview_bytes += path.stat().st_size
    preview_s = time.perf_counter() - start

    naive = _naive_clips_per_s(logs, clips_dir, config, 4 if quick else 8)
    lidar_counting = _lidar_counting(logs, config, 40 if quick else 200)
    block_codec = _block_codec(clips_dir)
    image_filter = _image_filter(clips_dir)
    track_kinematics = _track_kinematics(clips_dir)
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the loop's own process; intra-op threads only contend with the workers
    try:
        min_samples = 160 if quick else 640
        load_before = os.getloadavg()[0]
        rate_0 = _loader_rate(clips_dir, augment=False, workers=0, min_samples=min_samples // 2)
        rate_2 = _loader_rate(clips_dir, augment=False, workers=2, min_samples=min_samples)
        rate_2_aug = _loader_rate(clips_dir, augment=True, workers=2, min_samples=min_samples)
        rate_2_u8 = _loader_rate(clips_dir, augment=True, workers=2, min_samples=min_samples, as_uint8=True)
        load_after = os.getloadavg()[0]
        cpu = {
            f"samples_per_cpu_s_{'uint8' if u8 else 'float32'}_{'augmented' if aug else 'plain'}": round(
                _cpu_rate(clips_dir, aug, u8, 64 if quick else 160), 1)
            for u8 in (False, True) for aug in (False, True)
        }
    finally:
        torch.set_num_threads(threads)
    clips_per_s = num_clips / build_s
    return {
        "log_source": log_source,
        "caption_source": caption_source,
        "logs": len(logs),
        "frames": frames,
        "clips": num_clips,
        "clips_with_camera": int(sum(int(s["clips_with_camera"]) for s in report.logs.values())),
        "bev_sources": sorted({str(s["bev_source"]) for s in report.logs.values()}),
        "build_s": round(build_s, 2),
        "render_s_per_log": round(report.render_s / max(len(report.logs), 1), 2),
        "clips_per_s": round(clips_per_s, 1),
        "naive_clips_per_s": round(naive, 2),
        "clips_per_s_vs_naive": round(clips_per_s / naive, 1),
        "previews_per_s": round(len(rows) / preview_s, 1),
        "samples_per_s_workers0": round(rate_0, 1),
        "samples_per_s_workers2": round(rate_2, 1),
        "samples_per_s_workers2_augmented": round(rate_2_aug, 1),
        "samples_per_s_workers2_augmented_uint8": round(rate_2_u8, 1),
        "samples_per_s_workers2_vs_naive": round(rate_2 / naive, 1),
        "loading_target_200_met": bool(rate_2_u8 >= 200.0),  # the path `scenesearch train` uses
        **cpu,
        "load_average_during_loading": [round(load_before, 2), round(load_after, 2)],
        "mb_per_log": round(log_bytes / max(len(report.logs), 1) / 1e6, 2),
        "kb_per_frame": round(log_bytes / max(frames, 1) / 1e3, 1),
        # The same run's baseline: the RGB images stored without the Sub filter.
        "kb_per_frame_images_unfiltered": round(log_bytes / max(frames, 1) / 1e3
                                                + image_filter["extra_kb_per_frame_without"], 1),
        "kb_per_clip": round(log_bytes / max(num_clips, 1) / 1e3, 1),
        "kb_per_preview": round(preview_bytes / max(len(rows), 1) / 1e3, 1),
        "lidar_counting": lidar_counting,
        "block_codec": block_codec,
        "image_filter": image_filter,
        "track_kinematics": track_kinematics,
        "cpus": usable_cpus(),
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
