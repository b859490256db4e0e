"""``scenesearch caption LOG_DIR... --out OUT_DIR [--config captioning.yaml]``: rule-based captions.

Writes ``OUT_DIR/frame_tags.parquet`` and ``OUT_DIR/captions.parquet`` (see
:mod:`captioning.pipeline`), published together (:mod:`scenesearch_base.publish`). Logs that cannot be
read are skipped and listed with the reason; so are tracks observed in single frames, or too short
for own-behaviour tags, and a log without a map with lanes is said to have null lane tags, once.
Exit status (as every batch command's): 0 when every log was captioned; 1 when some were skipped
or failed (listed; the others are written); 2 when nothing was done (no log could be captioned, or
``--out`` is refused), leaving the previous outputs untouched. ``--out`` must be a new or empty
folder or a captions folder, and neither a log folder nor inside one (:mod:`scenesearch_base.folders`); a log
given twice is captioned once.

``--workers N`` captions one log per task on a local Ray runtime, ``--ray-address`` on a cluster
(:mod:`scenesearch_base.ray_runner`); the files are the same as the serial path's. Log folders and ``--out``
may be ``pyarrow.fs`` URIs (``s3://bucket/logs/*`` lists the logs under a prefix).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_cluster import add_arguments as add_execution_arguments
from scenesearch_base.storage import Location, as_location, expand, is_uri, staged_output

if TYPE_CHECKING:
    from captioning.outputs import CaptionsWriter
    from captioning.pipeline import LogCaptions

HELP = "tag host and neighbour behaviour per frame and write temporal captions (Parquet)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", metavar="LOG_DIR",
                        help="log folders (AV2 layout): paths or URIs (s3://..., gs://..., PREFIX/* for all)")
    parser.add_argument("--out", required=True, metavar="OUT_DIR", help="folder (or URI) for the Parquet files")
    parser.add_argument("--config", type=Path, help="captioning YAML (thresholds; see captioning.config)")
    parser.add_argument("--strategy", choices=["host_segments", "sliding"], help="override windows.strategy")
    parser.add_argument("--seed", type=int, help="override text.seed (paraphrase choice)")
    parser.add_argument("--rules", choices=["behavior", "paper"],
                        help="override rules: paper = the paper's rules only (moving neighbours, no own action)")
    add_execution_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from captioning.batch import caption_logs
    from captioning.config import CaptioningConfig, RuleSet, WindowStrategy
    from captioning.outputs import CAPTIONS_FOLDER
    from captioning.pipeline import CAPTIONS_FILENAME, FRAME_TAGS_FILENAME
    from scenesearch_base.folders import claim_folder

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
    out, log_dirs = as_location(args.out), expand(args.log_dirs)
    claim_folder(out, CAPTIONS_FOLDER, log_dirs)  # before any log is read
    with contextlib.ExitStack() as opened:
        writers: list[CaptionsWriter] = []

        def write(result: LogCaptions) -> None:
            """Each log written as it comes; the folder is opened with the first, so that a run that
            captions no log leaves ``--out`` as it was."""
            if not writers:
                writers.append(opened.enter_context(_writer(out, config.rules is RuleSet.BEHAVIOR, log_dirs)))
            writers[0].add(result)

        batch = caption_logs(log_dirs, config, Execution.from_args(args), write=write)
    for log_dir, reason in batch.skipped_logs.items():
        print(f"skipped log {log_dir}: {reason}")
    for log_dir, reason in batch.failed_logs.items():
        print(f"failed log {log_dir}: {reason}")
    if not batch.summaries:
        print(f"no log could be captioned; {out} is left as it was")
        return 2
    frames_path, captions_path = (f"{str(out).rstrip('/')}/{name}" for name in (FRAME_TAGS_FILENAME,
                                                                                CAPTIONS_FILENAME))
    elapsed_s = time.perf_counter() - start
    for log in batch.summaries:
        skipped = log.skipped_tracks
        print(
            f"{log.log_id}: {log.frames} frames, {log.tracks} tracks ({log.stationary_tracks} stationary), "
            f"{log.captions} captions" + (f", skipped {len(skipped)} tracks: {_reasons(skipped)}" if skipped else "")
            + "".join(f"; {note}" for note in log.notes)
        )
    total = len(batch.summaries) + len(batch.skipped_logs) + len(batch.failed_logs)
    print(
        f"captioned {len(batch.summaries)} of {total} logs: "
        f"{sum(log.captions for log in batch.summaries)} captions, "
        f"{sum(log.object_frames for log in batch.summaries)} object-frames in {elapsed_s:.2f} s; "
        f"wrote {frames_path} and {captions_path}"
        + (f"; {len(batch.failed_logs)} log(s) failed: {', '.join(batch.failed_logs)}" if batch.failed_logs else "")
    )
    return 1 if batch.failed_logs or batch.skipped_logs else 0


@contextlib.contextmanager
def _writer(out: Location, behavior: bool, log_dirs: list[Location]) -> Iterator[CaptionsWriter]:
    """A captions writer publishing the folder's files together in a local folder, or uploading them to
    a URI (files, no links), when the block ends; nothing is written when it raises."""
    from captioning.outputs import CAPTIONS_FOLDER, CaptionsWriter, captions_folder
    from scenesearch_base.folders import mark_folder

    if not is_uri(out):
        with captions_folder(Path(out), behavior, log_dirs) as writer:
            yield writer
        return
    with staged_output(out) as local:
        mark_folder(local, CAPTIONS_FOLDER, CAPTIONS_FOLDER.entries)
        with CaptionsWriter(local, behavior, log_dirs) as writer:
            yield writer


def _reasons(skipped: dict[str, str]) -> str:
    counts: dict[str, int] = {}
    for reason in skipped.values():
        counts[reason] = counts.get(reason, 0) + 1
    return "; ".join(f"{n} × {reason}" for reason, n in counts.items())
