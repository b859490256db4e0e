"""How much of the pedestrians a trained run's BEV embedding E carries: linear probes, by split.

    .venv/bin/python scripts/probe_pedestrians.py RUN_DIR CLIPS_DIR

Least squares (ridge 1e-2) from each E cell's D_e channels to the pedestrian fraction of that cell
(the tag target area-pooled to E's resolution), fitted on the training logs' frames (every second
one), and the same from the LiDAR input itself (each E cell's r × r grid cells × the height bins).
Prints, per split, the per-cell correlation of each probe with the truth and the per-frame
correlation of the scene's sums. The tagging head's own row is a linear read of E too, so a
probe that finds nothing in-sample says E holds nothing to read, whatever the head's loss.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from encoders.clips.layout import BEV_LIDAR_FILE, BEV_MAP_FILE, rendered_log_dir
from encoders.tagging.inference import Tagger, load_tagger
from encoders.tagging.targets import target_files

ATTRIBUTE = "pedestrian_density"
FRAME_STEP = 2
RIDGE = 1e-2

Cells = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]  # (E, LiDAR, truth) per cell


def log_cells(tagger: Tagger, clips_dir: Path, log_id: str) -> Cells:
    """E (N, D_e), LiDAR (N, r·r·Cl) and the truth (N,) of every E cell of every FRAME_STEP-th frame."""
    folder = rendered_log_dir(clips_dir, log_id)
    lidar = np.load(folder / BEV_LIDAR_FILE, mmap_mode="r")  # (F, Cl, H, W) uint8
    bev_map = np.load(folder / BEV_MAP_FILE, mmap_mode="r")
    targets = np.load(target_files(folder)[0], mmap_mode="r")  # (F, A, H, W)
    r = tagger.downsample
    frames = np.arange(0, lidar.shape[0], FRAME_STEP)
    parts = []
    with torch.no_grad():
        for lo in range(0, frames.shape[0], 32):
            f = frames[lo : lo + 32]
            li = torch.from_numpy(np.asarray(lidar[f], dtype=np.float32) / 255.0)  # (n, Cl, H, W)
            mp = torch.from_numpy(np.asarray(bev_map[f], dtype=np.float32) / 255.0)
            e = tagger.bev.embed_map(li[None], mp[None])[0]  # (n, D_e, h, w)
            n, cl, h, w = li.shape
            raw = li.reshape(n, cl, h // r, r, w // r, r).permute(0, 2, 4, 1, 3, 5).reshape(n, h // r, w // r, -1)
            truth = torch.from_numpy(np.asarray(targets[f, tagger.names.index(ATTRIBUTE)], dtype=np.float32))
            small = F.avg_pool2d(truth[:, None], r)[:, 0]  # (n, h, w): the covered fraction stays a fraction
            parts.append((e.permute(0, 2, 3, 1).reshape(-1, e.shape[1]), raw.reshape(-1, raw.shape[-1]),
                          small.reshape(-1)))
    return tuple(torch.cat([p[k] for p in parts]).double().numpy() for k in range(3))  # type: ignore[return-value]


def ridge(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    x1 = np.c_[x, np.ones(len(x))]
    return np.linalg.solve(x1.T @ x1 + RIDGE * np.eye(x1.shape[1]), x1.T @ y)


def correlation(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("clips_dir", type=Path)
    args = parser.parse_args()
    torch.manual_seed(0)
    tagger = load_tagger(args.run_dir)
    logs = json.loads((args.clips_dir / "manifest.json").read_text())["logs"]
    cells_per_frame = (tagger.grid.height // tagger.downsample) * (tagger.grid.width // tagger.downsample)
    data: dict[str, Cells] = {}
    for split in ("train", "val", "test"):
        per_log = [log_cells(tagger, args.clips_dir, lid) for lid in sorted(logs) if logs[lid].get("split") == split]
        data[split] = tuple(np.concatenate([c[k] for c in per_log]) for k in range(3))  # type: ignore[assignment]
    for name, k in (("E", 0), ("LiDAR", 1)):
        beta = ridge(data["train"][k], data["train"][2])
        line = [f"{name:5s} probe"]
        for split, (e, raw, truth) in data.items():
            x = (e, raw)[k]
            pred = np.c_[x, np.ones(len(x))] @ beta
            sums = pred.reshape(-1, cells_per_frame).sum(1), truth.reshape(-1, cells_per_frame).sum(1)
            line.append(f"{split}: cell {correlation(pred, truth):.2f}, frame sum {correlation(*sums):.2f}, "
                        f"cells with a pedestrian {float((truth > 0).mean()):.4f}")
        print("; ".join(line))


if __name__ == "__main__":
    main()
