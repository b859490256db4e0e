"""Retrieval on real track-only logs with the demo's model: KITTI tracking 0000–0010 and the two
development AV2 logs (``../shared/realdata``, development files only), BEV rendered from boxes.

The logs are imported (KITTI), captioned and cut into clips with the demo's clip settings
(``demo_out/clips.yaml``), then every clip is evaluated (``eval --split all``): text → clip over the
logs' own captions, with random ranking, shuffled frames and rule-caption search from the same run, and
hybrid search (both mixed at the default weight: real logs have no validation clips to choose one on).
The model is the one ``make demo`` trained (``SCENESEARCH_RUN``, default ``demo_out/run``); without
it, or without the fixtures, the benchmark says so and measures nothing.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
REALDATA = ROOT.parent / "shared" / "realdata"
KITTI_SEQUENCES = [f"{i:04d}" for i in range(11)]
AV2_DEV_LOGS = ["7fab2350-7eaf-3b7e-a39d-6937a4c1bede", "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"]


def run(quick: bool) -> dict[str, Any]:
    from retrieval.cli import main

    run_dir = Path(os.environ.get("SCENESEARCH_RUN", ROOT / "demo_out" / "run"))
    clips_config = run_dir.parent / "clips.yaml"
    if not (run_dir / "model.safetensors").is_file() or not clips_config.is_file():
        return {"skipped": f"no demo model at {run_dir} (run `make demo`, or set SCENESEARCH_RUN)"}
    kitti = REALDATA / "kitti_tracking"
    sequences = KITTI_SEQUENCES[:3] if quick else KITTI_SEQUENCES
    if not kitti.is_dir():
        return {"skipped": f"{REALDATA} is absent"}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for seq in sequences:
            argv = ["import", "kitti", "--labels", str(kitti / "label_02" / f"{seq}.txt"),
                    "--poses", str(kitti / "poses_orbslam3" / f"{seq}.txt"),
                    "--calib", str(kitti / "calib" / f"{seq}.txt"), "--out", str(work / "logs")]
            if main(argv) != 0:
                return {"error": f"import of KITTI {seq} failed"}
        logs = sorted(str(p) for p in (work / "logs").iterdir())
        logs += [str(REALDATA / "av2" / name) for name in AV2_DEV_LOGS if (REALDATA / "av2" / name).is_dir()]
        steps = [
            ["caption", *logs, "--out", str(work / "captions")],
            ["clips", *logs, "--captions", str(work / "captions"), "--out", str(work / "clips"),
             "--bev-source", "boxes", "--config", str(clips_config)],
            ["eval", str(run_dir), str(work / "clips"), "--split", "all", "--out", str(work / "metrics.json")],
        ]
        for argv in steps:
            if main(argv) != 0:
                return {"error": f"scenesearch {argv[0]} failed"}
        metrics = json.loads((work / "metrics.json").read_text())
    base = metrics["baselines"]
    figures: dict[str, Any] = {"logs": len(logs), "kitti_sequences": len(sequences), **metrics["counts"]}
    for name, block in [("model", metrics), ("bag_of_frames", base["bag_of_frames"]), ("random", base["random"]),
                        ("rule_captions", base.get("rule_captions", {})), ("hybrid", metrics.get("hybrid", {}))]:
        t2c = block.get("text_to_clip", {})
        for key in ("R@1", "R@5", "mAP"):
            if key in t2c:
                figures[f"{name}_{key}"] = round(float(t2c[key]), 4)
    figures["model_temporal_order_accuracy"] = round(float(metrics["temporal_order_accuracy"]["accuracy"]), 4)
    if metrics.get("hybrid"):
        figures["hybrid_weight"] = metrics["hybrid"]["weight"]
        figures["hybrid_temporal_order_accuracy"] = metrics["hybrid"]["temporal_order_accuracy"]["accuracy"]
    figures["model_over_random_R@5"] = round(figures["model_R@5"] / max(figures["random_R@5"], 1e-9), 1)
    return figures
