"""``scenesearch caption LOG_DIR... --out OUT_DIR [--config captioning.yaml]``: rule-based captions.

Writes ``OUT_DIR/frame_tags.parquet`` and ``OUT_DIR/captions.parquet`` (see
:mod:`captioning.pipeline`), published together (:mod:`common.publish`). Logs that cannot be
read are skipped and listed with the reason; so are tracks observed in single frames, or too short
for own-behaviour tags, and a log without a map with lanes is said to have null lane tags, once.
Exits 1, leaving the previous outputs untouched, when no log could be captioned.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

HELP = "tag host and neighbour behaviour per frame and write temporal captions (Parquet)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", type=Path, metavar="LOG_DIR", help="log folders (AV2 layout)")
    parser.add_argument("--out", type=Path, required=True, metavar="OUT_DIR", help="folder for the Parquet files")
    parser.add_argument("--config", type=Path, help="captioning YAML (thresholds; see captioning.config)")
    parser.add_argument("--strategy", choices=["host_segments", "sliding"], help="override windows.strategy")
    parser.add_argument("--seed", type=int, help="override text.seed (paraphrase choice)")
    parser.add_argument("--rules", choices=["behavior", "paper"],
                        help="override rules: paper = the paper's rules only (moving neighbours, no own action)")


def run(args: argparse.Namespace) -> int:
    from captioning.config import CaptioningConfig, RuleSet, WindowStrategy
    from captioning.pipeline import caption_logs, write_outputs

    config = CaptioningConfig.from_yaml(args.config) if args.config else CaptioningConfig()
    if args.strategy:
        config = dataclasses.replace(
            config, windows=dataclasses.replace(config.windows, strategy=WindowStrategy(args.strategy))
        )
    if args.seed is not None:
        config = dataclasses.replace(config, text=dataclasses.replace(config.text, seed=args.seed))
    if args.rules:
        config = dataclasses.replace(config, rules=RuleSet(args.rules))
    start = time.perf_counter()
    batch = caption_logs(args.log_dirs, config)
    for log_dir, reason in batch.skipped_logs.items():
        print(f"skipped log {log_dir}: {reason}")
    if not batch.results:
        print(f"no log could be captioned; {args.out} is left as it was")
        return 1
    frames_path, captions_path = write_outputs(args.out, batch.results)
    elapsed_s = time.perf_counter() - start
    object_frames = sum(int(r.valid.sum()) for r in batch.results)
    num_captions = sum(len(r.captions) for r in batch.results)
    for result in batch.results:
        skipped = result.skipped_tracks
        print(
            f"{result.log_id}: {len(result.timestamps_ns)} frames, {len(result.track_ids)} tracks "
            f"({int(result.neighbors.stationary.sum())} stationary), {len(result.captions)} captions"
            + (f", skipped {len(skipped)} tracks: {_reasons(skipped)}" if skipped else "")
            + "".join(f"; {note}" for note in result.notes)
        )
    print(
        f"captioned {len(batch.results)} of {len(batch.results) + len(batch.skipped_logs)} logs: "
        f"{num_captions} captions, {object_frames} object-frames in {elapsed_s:.2f} s; "
        f"wrote {frames_path} and {captions_path}"
    )
    return 0


def _reasons(skipped: dict[str, str]) -> str:
    counts: dict[str, int] = {}
    for reason in skipped.values():
        counts[reason] = counts.get(reason, 0) + 1
    return "; ".join(f"{n} × {reason}" for reason, n in counts.items())
