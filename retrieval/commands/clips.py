"""``scenesearch clips LOG_DIR... --captions CAPTIONS_DIR --out CLIPS_DIR [--config clips.yaml]``.

Renders each log's camera and BEV frames once into ``CLIPS_DIR/logs/<log_id>/``, writes
``CLIPS_DIR/clips.parquet`` (one clip per neighbour caption), ``manifest.json`` and, with
``--previews``, an animated GIF per clip under ``CLIPS_DIR/previews/`` (without them, the page and the
demo's report draw a clip's preview from the rendered frames when they show it). Reports what it skipped
and why (corrupt sweeps, windows outside a log, unreadable logs, duplicate clip ids) and which logs
failed. Exit status, as every batch command's: 0 when everything was made, 1 when something was
skipped or failed (listed), 2 when nothing was done (every log failed, or ``--out`` is refused: it
must be a new or empty folder or a clips folder, and not an input; :mod:`scenesearch_base.folders`).

``--train-only LOG_DIR...`` adds logs that always go to the train split (extra training data);
``--val-only`` and ``--test-only`` add logs that always validate or are always held out for test. The
logs given plainly split by a seeded hash of their id, as they would without the others.

``--workers N`` renders one log per task on a local Ray runtime, ``--ray-address`` on a cluster
(:mod:`scenesearch_base.ray_runner`); the files are the same as the serial path's. Logs, ``--captions`` and
``--out`` may be ``pyarrow.fs`` URIs (``--tag-targets`` needs a local or shared ``--out``).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from scenesearch_base.ray_cluster import Execution, held_runtime
from scenesearch_base.ray_cluster import add_arguments as add_execution_arguments
from scenesearch_base.storage import Location, as_location, expand, is_uri, name_of

if TYPE_CHECKING:
    from encoders.clips.config import ClipsConfig

HELP = "render camera + BEV clips of every neighbour caption (per-log arrays, clip table, splits, previews)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", metavar="LOG_DIR",
                        help="log folders (AV2 layout): paths or URIs (s3://..., gs://..., PREFIX/* for all)")
    parser.add_argument("--captions", required=True, help="folder with captions.parquet (or the file), or a URI")
    parser.add_argument("--out", required=True, help="clips folder (or URI) to write")
    parser.add_argument("--config", type=Path, help="clips.yaml (ClipsConfig); flags below override it")
    parser.add_argument("--frames-per-clip", type=int, help="T frames sampled over each caption window")
    parser.add_argument("--seed", type=int, help="seed of the train/val/test split by log")
    parser.add_argument("--train-only", nargs="+", default=[], metavar="LOG_DIR",
                        help="more log folders, rendered as the others but always in the train split (extra "
                             "training data, e.g. simulated logs beside the logs to evaluate on)")
    parser.add_argument("--val-only", nargs="+", default=[], metavar="LOG_DIR",
                        help="more log folders, always in the val split (where tag thresholds and the camera "
                             "weight are chosen)")
    parser.add_argument("--test-only", nargs="+", default=[], metavar="LOG_DIR",
                        help="more log folders, always held out in the test split")
    parser.add_argument("--bev-source", choices=["auto", "lidar", "boxes"], help="BEV occupancy source")
    parser.add_argument("--num-sweeps", type=int, help="sweeps aggregated per BEV frame")
    parser.add_argument("--previews", action="store_true",
                        help="also write an animated preview of every clip (the page draws the ones it shows)")
    parser.add_argument("--lenient", action="store_true",
                        help="skip (and report) captions naming logs or tracks that are not given, instead of failing")
    parser.add_argument("--no-reuse", action="store_true", help="re-render logs already rendered with this config")
    parser.add_argument("--tag-targets", action="store_true",
                        help="also rasterise attribute-tag targets, so that `scenesearch train` learns "
                             "spatio-temporal tags jointly: from the behaviour labels of simulated logs, from the "
                             "captioning rules on the tracks and map of any other log (the table printed says which)")
    parser.add_argument("--save-config", type=Path, help="also write the effective config as YAML")
    add_execution_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from encoders.clips.config import BevSourceChoice, ClipsConfig
    from scenesearch_base.config import with_option

    config = ClipsConfig.from_yaml(args.config) if args.config else ClipsConfig()
    if args.frames_per_clip is not None:
        config = with_option(config, "--frames-per-clip", frames_per_clip=args.frames_per_clip)
    if args.seed is not None:
        config = replace(config, split=replace(config.split, seed=args.seed))
    s = config.split
    config = replace(config, split=replace(s, train_only=(*s.train_only, *_log_ids(args.train_only)),
                                           val_only=(*s.val_only, *_log_ids(args.val_only)),
                                           test_only=(*s.test_only, *_log_ids(args.test_only))))
    if args.bev_source is not None:
        config = replace(config, bev=replace(config.bev, source=BevSourceChoice(args.bev_source)))
    if args.num_sweeps is not None:
        config = replace(config, bev=with_option(config.bev, "--num-sweeps", num_sweeps=args.num_sweeps))
    if args.previews:
        config = replace(config, previews=True)
    if args.lenient:
        config = replace(config, strict=False)
    if args.save_config:
        config.to_yaml(args.save_config)
    out, execution = as_location(args.out), Execution.from_args(args)
    if args.tag_targets and is_uri(out):
        raise ValueError("--tag-targets needs a clips folder on a local or shared file system, not a URI")
    with held_runtime(execution):  # one runtime for the clips and their tag targets
        return _run(args, config, out, execution)


def _log_ids(log_dirs: list[str]) -> tuple[str, ...]:
    """The log ids (folder names) of log folders given on the command line."""
    return tuple(name_of(log_dir) for log_dir in expand(log_dirs)) if log_dirs else ()


def _run(args: argparse.Namespace, config: ClipsConfig, out: Location, execution: Execution) -> int:
    from encoders.clips.build import build_clips
    from encoders.clips.layout import MANIFEST_FILE

    log_dirs = expand([*args.log_dirs, *args.train_only, *args.val_only, *args.test_only])
    report = build_clips(log_dirs, as_location(args.captions), out, config, progress=print,
                         reuse=not args.no_reuse, execution=execution)
    print(
        f"wrote {report.num_clips} clips from {len(report.logs)} log(s) to {args.out} "
        f"(render {report.render_s:.1f} s, {report.reused_logs} log(s) reused; table {report.table_s:.1f} s; "
        f"previews {report.preview_s:.1f} s)"
    )
    if report.skipped:
        print(f"skipped {len(report.skipped)} item(s):")
        for item in report.skipped[:50]:
            where = ", ".join(f"{k}={v}" for k, v in item.items() if k != "reason")
            print(f"  {where}: {item['reason']}")
        if len(report.skipped) > 50:
            print(f"  ... and {len(report.skipped) - 50} more (see {out}/{MANIFEST_FILE})")
    for log_id, stats in report.logs.items():
        if stats.get("corrupt_sweeps"):
            print(f"  {log_id}: skipped corrupt sweeps: {', '.join(stats['corrupt_sweeps'][:5])}")
        if stats.get("corrupt_camera_frames"):
            print(f"  {log_id}: skipped corrupt camera files: {', '.join(stats['corrupt_camera_frames'][:5])}")
    if args.tag_targets:
        from encoders.tagging.targets import add_attribute_targets

        targets = add_attribute_targets(Path(out), log_dirs, progress=print, execution=execution)
        print(f"tag targets: {len(targets.written)} log(s) written, {len(targets.reused)} reused")
        print(targets.table())
        for item in targets.skipped:
            print(f"  skipped {item.get('log_id', '?')}: {item.get('reason', '')}")
    for log_id, reason in report.failed.items():
        print(f"failed log {log_id}: {reason}")
    return 1 if report.failed or report.skipped else 0
