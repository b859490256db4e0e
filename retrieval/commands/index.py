"""``scenesearch index``: embed every clip and its rule caption with a trained model; write an index directory."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "embed all clips (fused, camera-only, BEV-only) and their captions with a trained model; write an index"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="training run (model.safetensors, config.json)")
    parser.add_argument("clips_dir", type=Path, metavar="CLIPS_DIR", help="clips directory (clips.parquet, logs/)")
    parser.add_argument("--out", type=Path, required=True, metavar="INDEX_DIR", help="index directory to write")


def run(args: argparse.Namespace) -> int:
    from retrieval.scenesearch import SceneSearch

    search = SceneSearch.build(args.run_dir, args.clips_dir, args.out, progress=lambda m: print(m, flush=True))
    for item in search.manifest.skipped[:20]:
        print(f"skipped {item['item']}: {item['reason']}")
    if len(search.manifest.skipped) > 20:
        print(f"... and {len(search.manifest.skipped) - 20} more skipped (listed in {args.out}/manifest.json)")
    counts = ", ".join(f"{k} {v}" for k, v in search.manifest.counts.items())
    print(f"wrote {args.out}: {counts}")
    return 0
