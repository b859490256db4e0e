"""Training speed of the dual encoder, and the text-cache speed-up, same run.

Figures:

- training samples/s (forward, multi-positive loss, backward, AdamW step) of the default model at the
  default clip sizes (T = 16, camera 4 × 96 × 160, BEV 5 + 6 channels × 160 × 80) and at a small
  resolution (camera 48 × 80, BEV 80 × 40);
- the text side of a training step with the frozen MiniLM's embeddings cached per caption against
  re-encoding the captions every step (ratio);
- the frozen sentence encoder on a training step's strings with its matrix products in bfloat16
  against float32 (ratio; the cosine of the two embeddings; whether the CPU has bfloat16 instructions);
- the slots text tower over a run of training steps' captions from a cold cache, with the whole text as
  the mean of its sentences against in one piece (ratio; the strings and characters encoded);
- the BEV tower's raster stream at the demo's clip sizes, forward and backward: the masked and
  whole-grid means of each frame's features convolved over time after (what the tower does) against
  the same means of the convolved map (ratio; equal within float rounding);
- the BEV tower at inference on clips cut from a few logs, whose frames repeat from clip to clip,
  against as many clips whose frames all differ (ratio; equal frames run once); the same clips with
  their rasters as bytes against as floats, and pooled once per distinct frame against per frame
  (ratios, see :func:`distinct_frames_speedup`).

Rates are given per CPU second of this process (``time.process_time``, one torch thread), so that other
work on a shared machine does not count, and per wall second. The device is recorded.

``python -m benchmarks.bench_train --acceptance`` runs the quality check instead: the default model
trained on simulated clips against random ranking and against the same model trained and evaluated on
clips whose frames are shuffled in time (bag of frames), on the held-out test split.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from benchmarks.train_text_speed import (
    grouped_encoding_speedup,
    text_cache_speedup,
    text_precision_speedup,
    whole_text_speedup,
)
from encoders.loss import contrastive_loss, positives_matrix
from encoders.model import DualEncoder
from encoders.train import build_optimizer, evaluate, train
from encoders.train_config import TrainConfig
from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec, collate_clips

DEFAULT_SPEC = SyntheticSpec()
SMALL_SPEC = SyntheticSpec(camera_hw=(48, 80), bev_hw=(80, 40))
#: The acceptance check's clips: small enough to train twice in minutes on a shared 2-core machine.
#: The ego stands still: a moving ego's odometry counts time and would let a bag of frames sort itself.
ACCEPTANCE_SPEC = SyntheticSpec(frames=12, camera_hw=(32, 64), bev_hw=(64, 32), ego_speed_mps=(0.0, 0.0))
#: The acceptance check's figures (``--acceptance``, tens of minutes) are not rerun by ``make bench``,
#: which keeps them in ``results.json`` beside this run's.
FIGURES_FROM_OTHER_RUNS = ("acceptance_synthetic_clips",)


def _device() -> dict[str, Any]:
    return {
        "device": "cpu",
        "cpu": platform.processor() or platform.machine(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
    }


def train_rate(config: TrainConfig, spec: SyntheticSpec, batch_size: int, steps: int) -> dict[str, float]:
    """Samples per CPU second and per wall second of full training steps on synthetic clips."""
    torch.manual_seed(0)
    model = DualEncoder(config.model).train()
    opt = build_optimizer(model, config)
    ds = SyntheticClipDataset(batch_size * (steps + 1), spec=spec, seed=0)
    batches = [collate_clips([ds[i * batch_size + j] for j in range(batch_size)]) for i in range(steps + 1)]

    def step(batch: dict[str, Any]) -> None:
        video, text, scale = model(batch, batch["caption"])
        loss = contrastive_loss(video, text, scale, positives_matrix(batch["canonical_caption"]))
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    step(batches[0])  # warm-up (and caption cache fill for the first batch)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for batch in batches[1:]:
        step(batch)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    n = batch_size * steps
    return {"samples_per_cpu_s": round(n / cpu, 3), "samples_per_wall_s": round(n / wall, 3), "samples": n}


def _bev_batch(clips: int, frames: int, logs: int | None, seed: int = 0) -> dict[str, torch.Tensor]:
    """BEV inputs of ``clips`` clips at the demo's grid (64 × 32 cells) and the default model's channels:
    with ``logs``, windows of ``frames`` frames at random starts in that many logs of 40 frames, as a
    clip table's batch holds; None: every frame its own."""
    gen = torch.Generator().manual_seed(seed)
    h, w = 64, 32
    bev = TrainConfig().model.bev
    cl, cm = bev.lidar_channels, bev.map_channels
    if logs is None:
        lidar, bev_map = torch.rand(clips, frames, cl, h, w, generator=gen), torch.rand(clips, frames, cm, h, w,
                                                                                       generator=gen)
    else:
        log_lidar = torch.rand(logs, 40, cl, h, w, generator=gen)
        log_map = torch.rand(logs, 40, cm, h, w, generator=gen)
        which = torch.randint(logs, (clips,), generator=gen).sort().values
        start = torch.randint(40 - frames + 1, (clips,), generator=gen)
        lidar = torch.stack([log_lidar[int(i), int(s) : int(s) + frames] for i, s in zip(which, start)])
        bev_map = torch.stack([log_map[int(i), int(s) : int(s) + frames] for i, s in zip(which, start)])
    return {"bev_lidar": lidar, "bev_map": bev_map,
            "bev_object": (torch.rand(clips, frames, 1, h, w, generator=gen) > 0.95).float(),
            "ego_motion": torch.rand(clips, frames, 6, generator=gen)}


def bev_pooling_speedup(batch_size: int, steps: int) -> dict[str, float]:
    """The raster stream's frame features, forward and backward, at the demo's sizes: pooled from each
    frame's features and convolved over time after, against pooled from the convolved map."""
    import torch.nn.functional as F

    from encoders.bev import BevTower
    from encoders.camera import masked_mean

    torch.manual_seed(0)
    tower = BevTower(TrainConfig().model.bev, 256).train()
    with torch.no_grad():
        tower.header_time.weight.normal_(std=0.1)
    batch = _bev_batch(batch_size, 12, None)

    def of_convolved_map(space: torch.Tensor) -> torch.Tensor:
        b, t = space.shape[:2]
        e = tower.header_time(space).flatten(0, 1)  # (B*T, D_e, h, w)
        small = F.adaptive_avg_pool2d(batch["bev_object"].flatten(0, 1), e.shape[-2:])
        return torch.cat([masked_mean(e, small), e.mean(dim=(2, 3))], dim=-1).reshape(b, t, -1)

    def after(space: torch.Tensor) -> torch.Tensor:
        return tower.frame_features(space, batch["bev_object"], batch["ego_motion"])[..., : 2 * space.shape[2]]

    figures: dict[str, float] = {}
    outputs = {}
    for name, pool in (("convolved_map", of_convolved_map), ("convolved_after", after)):
        for i in range(steps + 1):  # the first is a warm-up
            if i == 1:
                cpu0 = time.process_time()
            out = pool(tower.embed_space(batch["bev_lidar"], batch["bev_map"]))
            out.square().mean().backward()
        figures[f"{name}_ms_per_step"] = round(1000 * (time.process_time() - cpu0) / steps, 1)
        outputs[name] = out.detach()
    figures["speedup"] = round(figures["convolved_map_ms_per_step"] / figures["convolved_after_ms_per_step"], 2)
    figures["max_abs_difference"] = float((outputs["convolved_map"] - outputs["convolved_after"]).abs().max())
    figures["batch_size"] = batch_size
    return figures


def distinct_frames_speedup(batch_size: int, steps: int, logs: int = 4) -> dict[str, float]:
    """The BEV tower's raster stream at inference (eval mode: :meth:`encoders.bev.BevTower.embed_distinct`
    and :meth:`~encoders.bev.BevTower.frame_features`) on rasters as bytes, as a batch of
    ``ClipDataset(as_uint8=True)`` gives them, same run:

    - ``speedup``: clips cut from ``logs`` logs (their frames repeat from clip to clip) against as many
      clips whose frames all differ: equal frames run once;
    - ``bytes_vs_float_speedup``: the clips cut from logs given as bytes against the same rasters
      converted to float before the tower: equal frames are found on a quarter of the bytes, and only
      the distinct ones are converted;
    - ``pooled_once_speedup``: each distinct frame's features pooled once for all its clips against a
      copy of them made for every frame first (:meth:`~encoders.bev.BevTower.embed_space`), with
      ``max_abs_difference`` between the two.
    """
    from encoders.bev import BevTower, distinct_frames
    from encoders.camera import unit_pixels

    torch.manual_seed(0)
    tower = BevTower(TrainConfig().model.bev, 256).eval()

    def as_bytes(batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return batch | {k: (batch[k] * 255).round().to(torch.uint8) for k in ("bev_lidar", "bev_map")}

    def pooled_once(batch: dict[str, torch.Tensor]) -> torch.Tensor:
        space, inverse = tower.embed_distinct(batch["bev_lidar"], batch["bev_map"])
        return tower.frame_features(space, batch["bev_object"], batch["ego_motion"], inverse)

    def copied_per_frame(batch: dict[str, torch.Tensor]) -> torch.Tensor:
        space = tower.embed_space(batch["bev_lidar"], batch["bev_map"])
        return tower.frame_features(space, batch["bev_object"], batch["ego_motion"])

    cut = as_bytes(_bev_batch(batch_size, 12, logs))
    runs: dict[str, tuple[Callable[[dict[str, torch.Tensor]], torch.Tensor], dict[str, torch.Tensor]]] = {
        "all_distinct": (pooled_once, as_bytes(_bev_batch(batch_size, 12, None))),
        "cut_from_logs": (pooled_once, cut),
        "cut_from_logs_float": (pooled_once, cut | {k: unit_pixels(cut[k]) for k in ("bev_lidar", "bev_map")}),
        "cut_from_logs_copied": (copied_per_frame, cut),
    }
    figures: dict[str, float] = {}
    outputs = {}
    for name, (fn, batch) in runs.items():
        with torch.no_grad():
            for i in range(steps + 1):  # the first is a warm-up
                if i == 1:
                    cpu0 = time.process_time()
                outputs[name] = fn(batch)
        figures[f"{name}_ms_per_batch"] = round(1000 * (time.process_time() - cpu0) / steps, 1)
    for name in ("all_distinct", "cut_from_logs"):
        batch = runs[name][1]
        first, inverse = distinct_frames(batch["bev_lidar"].flatten(0, 1), batch["bev_map"].flatten(0, 1))
        figures[f"{name}_distinct_frames_share"] = round(len(first) / len(inverse), 3)
    ms = {k[: -len("_ms_per_batch")]: v for k, v in figures.items() if k.endswith("_ms_per_batch")}
    figures["speedup"] = round(ms["all_distinct"] / ms["cut_from_logs"], 2)
    figures["bytes_vs_float_speedup"] = round(ms["cut_from_logs_float"] / ms["cut_from_logs"], 2)
    figures["pooled_once_speedup"] = round(ms["cut_from_logs_copied"] / ms["cut_from_logs"], 2)
    figures["max_abs_difference"] = float((outputs["cut_from_logs"] - outputs["cut_from_logs_copied"]).abs().max())
    figures.update(batch_size=batch_size, logs=logs)
    return figures


def run(quick: bool) -> dict[str, Any]:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    torch.set_num_threads(1)
    batch, steps = (8, 1) if quick else (32, 2)
    config = TrainConfig()
    out: dict[str, Any] = {"machine": _device(), "batch_size": batch, "steps": steps}
    out["default_resolution"] = train_rate(config, DEFAULT_SPEC, batch, steps)
    out["small_resolution"] = train_rate(config, SMALL_SPEC, batch, steps)
    out["small_resolution"]["ratio_vs_default"] = round(
        out["small_resolution"]["samples_per_cpu_s"] / out["default_resolution"]["samples_per_cpu_s"], 2
    )
    out["text_cache"] = text_cache_speedup(32, 3 if quick else 10)
    out["grouped_text_encoding"] = grouped_encoding_speedup(16, 2 if quick else 10)
    out["text_precision"] = text_precision_speedup(16, 2 if quick else 10)
    out["whole_text"] = whole_text_speedup(16, 2 if quick else 30)
    out["bev_pooling"] = bev_pooling_speedup(16, 2 if quick else 10)
    out["bev_distinct_frames"] = distinct_frames_speedup(32, 2 if quick else 10)
    return out


# --- acceptance ---------------------------------------------------------------------------------------
def acceptance(
    out_dir: Path, train_size: int, epochs: int, spec: SyntheticSpec, batch_size: int = 32
) -> dict[str, Any]:
    """Train the default model and its bag-of-frames twin on simulated clips; compare on the test split."""
    torch.set_num_threads(1)  # a second thread only adds contention on a shared 2-core machine
    data: dict[str, Dataset[dict[str, Any]]] = {
        "train": SyntheticClipDataset(train_size, "train", spec, seed=0, augment=True),
        "val": SyntheticClipDataset(max(40, train_size // 8), "val", spec, seed=0),
    }
    test = SyntheticClipDataset(max(200, train_size // 2), "test", spec, seed=0)
    base = dataclasses.replace(TrainConfig(), epochs=epochs, batch_size=batch_size, warmup_steps=20)
    results: dict[str, Any] = {"train_clips": train_size, "test_clips": len(test), "epochs": epochs,
                               "batch_size": batch_size, "spec": dataclasses.asdict(spec)}
    for name, shuffled in (("ordered", False), ("bag_of_frames", True)):
        run_dir = out_dir / name
        t0 = time.perf_counter()
        config = dataclasses.replace(base, shuffle_frames=shuffled)
        train("synthetic", run_dir, config, datasets=data, resume=(run_dir / "checkpoints" / "last.pt").exists())
        from encoders.inference import load_model

        model = load_model(run_dir)
        results[name] = {
            "train_s": round(time.perf_counter() - t0, 1),
            "all": evaluate(model, test, shuffle_frames=shuffled),
            "multi_step": evaluate(model, test, shuffle_frames=shuffled, min_steps=2),
        }
        if not shuffled:
            results[name]["views"] = {v: evaluate(model, test, view=v)["R@5"] for v in ("camera", "bev")}
    results["random"] = random_ranking(test)
    return results


def random_ranking(dataset: SyntheticClipDataset, trials: int = 20) -> dict[str, dict[str, float]]:
    from encoders.metrics import text_to_clip_metrics

    captions = [dataset.record(i)["canonical_caption"] for i in range(len(dataset))]
    steps = {dataset.record(i)["canonical_caption"]: len(dataset.record(i)["tags"]) for i in range(len(dataset))}
    rng = np.random.default_rng(0)
    out: dict[str, dict[str, float]] = {}
    for name, min_steps in (("all", 1), ("multi_step", 2)):
        queries = sorted({c for c in captions if steps[c] >= min_steps})
        relevant = np.array(captions)[None, :] == np.array(queries)[:, None]
        runs = [text_to_clip_metrics(rng.random(relevant.shape), relevant) for _ in range(trials)]
        out[name] = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--acceptance", action="store_true", help="run the quality check instead of the speed run")
    parser.add_argument("--out", type=Path, help="run folders of the acceptance check (default: a temp folder)")
    parser.add_argument("--train-clips", type=int, default=384)
    parser.add_argument("--epochs", type=int, default=14)
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--spec", choices=["acceptance", "small", "default"], default="acceptance",
                        help="clip sizes of the acceptance check")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    if not args.acceptance:
        print(json.dumps(run(args.quick), indent=2))
        return 0
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_train_"))
    spec = {"acceptance": ACCEPTANCE_SPEC, "small": SMALL_SPEC, "default": DEFAULT_SPEC}[args.spec]
    results = acceptance(out, args.train_clips, args.epochs, spec, args.batch_size)
    text = json.dumps(results, indent=2)
    (out / "acceptance.json").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
