"""Captioning speed and quality: vectorised rules against the per-frame reference implementation, same run.

Synthetic fleet-like logs (10 Hz, tracks with random spans, rare gaps, a wandering ego). Figures:
object-frames per second of the tag computation for both implementations of the paper's rules
(host + neighbour tags; the reference is timed on a subset, it is slow by design, and must give
the same tags), their ratio, and the throughput of the whole ``caption_arrays`` (tags, windows,
text). The default rules (``rules: behavior``: own behaviour too, stationary objects captioned)
are timed against the paper's rules in the same run (``behavior_*`` figures; no map on synthetic
logs), and again on the simulated logs with their maps (map rasterisation included). Quality:
agreement of the tags with the simulator's behaviour labels on freshly simulated logs (ego turns →
steering tags, neighbour lane changes → lane transitions), when SUMO is available; the own-behaviour
F1 per label is ``benchmarks/bench_behavior_rules.py``.
Times are CPU seconds of this process (``time.process_time``), so that other work on a shared
machine does not count; numpy's elementwise kernels run on one core.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from captioning.agreement import agreement_for_logs
from captioning.config import CaptioningConfig, RuleSet
from captioning.host import host_tags
from captioning.neighbors import neighbor_tags, track_motion
from captioning.pipeline import caption_arrays, tag_arrays
from captioning.reference import reference_tags
from scenes.geometry import batch_matrices, quat_to_rotmat, yaw_to_quat
from scenes.log import Log


def synthetic_log(seed: int, num_tracks: int, num_frames: int) -> dict:
    """A log with ``num_tracks`` tracks on ``num_frames`` frames (arrays for ``caption_arrays``)."""
    rng = np.random.default_rng(seed)
    t = num_frames
    ts = (np.arange(t) * 100_000_000).astype(np.int64)
    yaw = np.cumsum(np.convolve(rng.normal(0, 1.0, t), np.ones(20) / 20, "same")) * 0.1
    speed = np.clip(8 + np.cumsum(rng.normal(0, 0.3, t)), 0, 20)
    xy = np.cumsum(np.stack([speed * np.cos(yaw), speed * np.sin(yaw)], 1) * 0.1, 0)
    poses = batch_matrices(quat_to_rotmat(yaw_to_quat(yaw)), np.c_[xy, np.zeros(t)])
    span = rng.integers(20, min(400, t), num_tracks)
    first = rng.integers(0, t - span + 1)
    frame = np.arange(t)[None, :]
    valid = (frame >= first[:, None]) & (frame < (first + span)[:, None]) & (rng.random((num_tracks, t)) > 0.01)
    vel = rng.normal(0, 6, (num_tracks, 1, 2)) + np.cumsum(rng.normal(0, 0.05, (num_tracks, t, 2)), 1)
    city = rng.normal(0, 40, (num_tracks, 1, 2)) + xy[None, :1] + np.cumsum(vel * 0.1, 1)
    c, s = np.cos(yaw)[None], np.sin(yaw)[None]
    d = city - xy[None]
    center = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=2)
    heading = np.arctan2(vel[..., 1], vel[..., 0]) - yaw[None]
    return dict(
        log_id=f"synthetic-{seed}", timestamps_ns=ts, track_ids=np.array([f"t{i}" for i in range(num_tracks)]),
        categories=np.array(["car"] * num_tracks), valid=valid,
        center_ego_xy_m=np.where(valid[..., None], center, np.nan), yaw_ego_rad=np.where(valid, heading, np.nan),
        city_SE3_ego=poses,
    )


def _tags(data: dict, config: CaptioningConfig) -> None:
    host_tags(data["timestamps_ns"], data["city_SE3_ego"], config)
    tracks = track_motion(data["timestamps_ns"], data["valid"], data["center_ego_xy_m"], data["yaw_ego_rad"],
                          data["city_SE3_ego"], config)
    neighbor_tags(tracks, data["valid"].shape, config)


def _best_of(repeats: int, fn, *args) -> float:  # type: ignore[no-untyped-def]
    """Best CPU time of this process (not wall time: the machine may be shared) over ``repeats`` runs."""
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        fn(*args)
        best = min(best, time.process_time() - start)
    return best


def run(quick: bool) -> dict:
    config = CaptioningConfig(rules=RuleSet.PAPER)
    rich = CaptioningConfig()
    num_logs, num_tracks, num_frames = (3, 100, 300) if quick else (8, 250, 1200)
    logs = [synthetic_log(seed, num_tracks, num_frames) for seed in range(num_logs)]
    object_frames = sum(int(d["valid"].sum()) for d in logs)
    repeats = 2 if quick else 3

    def all_tags() -> None:
        for d in logs:
            _tags(d, config)

    fast_s = _best_of(repeats, all_tags)
    full_s = _best_of(repeats, lambda: [caption_arrays(config=config, **d) for d in logs])
    # Before and after in the same run: every per-frame tag under each rule set, then whole captions.
    paper_tags_s = _best_of(repeats, lambda: [tag_arrays(config=config, **d) for d in logs])
    rich_tags_s = _best_of(repeats, lambda: [tag_arrays(config=rich, **d) for d in logs])
    rich_full_s = _best_of(repeats, lambda: [caption_arrays(config=rich, **d) for d in logs])

    subset = synthetic_log(100, 12 if quick else 30, num_frames)
    subset_frames = int(subset["valid"].sum())
    ref_s = _best_of(1, reference_tags, subset["timestamps_ns"], subset["valid"], subset["center_ego_xy_m"],
                     subset["yaw_ego_rad"], subset["city_SE3_ego"], config)
    ref = reference_tags(subset["timestamps_ns"], subset["valid"], subset["center_ego_xy_m"], subset["yaw_ego_rad"],
                         subset["city_SE3_ego"], config)
    fast = caption_arrays(config=config, **subset)
    agree = bool((fast.neighbors.lane == ref.lane).all() and (fast.neighbors.motion == ref.motion).all()
                 and (fast.host_motion == ref.host_motion).all())

    fast_rate = object_frames / fast_s
    ref_rate = subset_frames / ref_s
    real = [p for p in AV2_DEV_LOGS if p.is_dir()]
    return {
        **_simulated_agreement(num_logs=2 if quick else 8, duration_s=40 if quick else 60, repeats=repeats),
        **(_stage_speed("av2_dev", real, repeats) if real else {"stage_av2_dev": "development logs absent"}),
        "object_frames": object_frames,
        "vectorised_object_frames_per_s": round(fast_rate),
        "paper_rules_tags_object_frames_per_s": round(object_frames / paper_tags_s),
        "behavior_rules_tags_object_frames_per_s": round(object_frames / rich_tags_s),
        "behavior_tags_slowdown_vs_paper": round(rich_tags_s / paper_tags_s, 2),
        "behavior_rules_full_pipeline_object_frames_per_s": round(object_frames / rich_full_s),
        "behavior_full_slowdown_vs_paper": round(rich_full_s / full_s, 2),
        "reference_object_frames_per_s": round(ref_rate),
        "speedup_vs_reference": round(fast_rate / ref_rate, 1),
        "full_pipeline_object_frames_per_s": round(object_frames / full_s),
        "vectorised_s": round(fast_s, 4),
        "reference_s": round(ref_s, 4),
        "reference_object_frames": subset_frames,
        "reference_agrees": agree,
        "logs": num_logs,
        "tracks_per_log": num_tracks,
        "frames_per_log": num_frames,
    }


def _simulated_agreement(num_logs: int, duration_s: int, repeats: int) -> dict:
    """Agreement figures on simulated logs (empty with a reason when the simulator cannot run), and the
    speed of the paper's and the default rules on them, maps included."""
    from retrieval.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sim"
        argv = ["simulate", "--out", str(out), "--logs", str(num_logs), "--duration-s", str(duration_s),
                "--seed", "2", "--no-sensors", "--cache-dir", str(Path(tmp) / "cache")]
        try:
            if main(argv) != 0:
                return {"agreement_error": "simulate failed"}
        except Exception as exc:
            return {"agreement_error": f"{type(exc).__name__}: {exc}"}
        log_dirs = sorted(p for p in out.iterdir() if p.is_dir())
        report = agreement_for_logs(log_dirs, CaptioningConfig(rules=RuleSet.PAPER))
        speed = {**_simulated_speed(log_dirs, repeats), **_stage_speed("simulated", log_dirs, repeats)}
    return {**speed, **{f"agreement_{key}": (round(value, 3) if isinstance(value, float) else value)
                        for key, value in report.to_dict().items()}}


#: Development AV2 logs (see ../shared/realdata/README.md), timed when present.
AV2_DEV_LOGS = [Path(__file__).resolve().parents[2] / "shared" / "realdata" / "av2" / name
                for name in ("7fab2350-7eaf-3b7e-a39d-6937a4c1bede", "adcf7d18-0510-35b0-a2fa-b4cea13a6d76")]


def _stage_speed(name: str, log_dirs: list[Path], repeats: int) -> dict:
    """The whole caption stage (read logs and maps, tags, captions, both tables written) under the
    paper's and the default rules; maps are parsed cold in every repeat."""
    from captioning.batch import caption_logs
    from captioning.outputs import write_outputs
    from scenes.av2_io import forget_parsed_maps

    def stage(config: CaptioningConfig) -> None:
        forget_parsed_maps()
        with tempfile.TemporaryDirectory() as tmp:
            write_outputs(tmp, caption_logs(log_dirs, config).results)

    frames = sum(int(r.valid.sum()) for r in caption_logs(log_dirs, CaptioningConfig()).results)
    paper_s = _best_of(repeats, stage, CaptioningConfig(rules=RuleSet.PAPER))
    rich_s = _best_of(repeats, stage, CaptioningConfig())
    return {
        f"stage_{name}_logs": len(log_dirs),
        f"stage_{name}_object_frames": frames,
        f"stage_{name}_paper_object_frames_per_s": round(frames / paper_s),
        f"stage_{name}_behavior_object_frames_per_s": round(frames / rich_s),
        f"stage_{name}_behavior_slowdown_vs_paper": round(rich_s / paper_s, 2),
    }


def _simulated_speed(log_dirs: list[Path], repeats: int) -> dict:
    """Per-frame tags of simulated logs with their maps: the paper's rules against the default rules."""
    inputs = []
    for log_dir in log_dirs:
        log = Log.open(log_dir)
        dense = log.dense_tracks()
        inputs.append((dict(log_id=log.log_id, timestamps_ns=dense.timestamps_ns, track_ids=dense.track_ids,
                            categories=dense.categories, valid=dense.valid,
                            center_ego_xy_m=dense.center_ego_xyz_m[..., :2], yaw_ego_rad=dense.yaw_ego_rad,
                            city_SE3_ego=dense.city_SE3_ego), log.map, dense.size_lwh_m[..., 0]))
    object_frames = sum(int(d["valid"].sum()) for d, _, _ in inputs)

    def tags(config: CaptioningConfig) -> None:
        for d, vector_map, length in inputs:
            tag_arrays(config=config, vector_map=vector_map, length_m=length, **d)

    paper_s = _best_of(repeats, tags, CaptioningConfig(rules=RuleSet.PAPER))
    rich_s = _best_of(repeats, tags, CaptioningConfig())
    return {
        "simulated_object_frames": object_frames,
        "simulated_paper_tags_object_frames_per_s": round(object_frames / paper_s),
        "simulated_behavior_tags_with_map_object_frames_per_s": round(object_frames / rich_s),
        "simulated_behavior_slowdown_vs_paper": round(rich_s / paper_s, 2),
    }


if __name__ == "__main__":
    import json
    import sys

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
