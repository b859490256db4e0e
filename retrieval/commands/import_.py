"""``scenesearch import <format> ...``: convert foreign data into AV2-layout logs.

``scenesearch import kitti --labels L --poses P --calib C --out DIR [--overwrite]`` converts one
KITTI tracking sequence into ``DIR/kitti_<seq>/`` (see :mod:`scenes.kitti`).
``--detections D [D ...]`` instead of ``--labels`` builds tracks from per-frame detections with
:func:`scenes.tracking.import_kitti_detections`.

``scenesearch import womd FILE.tfrecord... --out DIR [--overwrite]`` converts every Waymo Open
Motion Dataset scenario of the files into ``DIR/womd_<scenario_id>/`` (see :mod:`scenes.womd`).
Scenarios that cannot be imported are listed with the reason and the rest go on; the exit status is
1 when any scenario was skipped, 2 when none was imported.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

HELP = "convert foreign logs into the AV2 layout (kitti, womd)"


def configure(parser: argparse.ArgumentParser) -> None:
    formats = parser.add_subparsers(dest="format", metavar="FORMAT")
    formats.required = True
    kitti = formats.add_parser(
        "kitti",
        help="a KITTI tracking sequence (labels or detections, poses, calib) → DIR/kitti_<seq>/",
        description="Convert a KITTI tracking sequence into an AV2-layout log DIR/kitti_<seq>/, "
        "<seq> being the label (or first detection) file's name.",
    )
    source = kitti.add_mutually_exclusive_group(required=True)
    source.add_argument("--labels", type=Path, help="label_02/<seq>.txt: ground-truth tracks")
    source.add_argument(
        "--detections", type=Path, nargs="+", help="per-class detection files of one sequence, tracked on import"
    )
    kitti.add_argument("--poses", type=Path, required=True, help="poses/<seq>.txt: 3×4 camera-to-world per frame")
    kitti.add_argument("--calib", type=Path, required=True, help="calib/<seq>.txt: P2, R0_rect, Tr_velo_to_cam")
    kitti.add_argument("--out", type=Path, required=True, help="folder that receives kitti_<seq>/")
    kitti.add_argument("--overwrite", action="store_true", help="replace an existing log of the same name")
    kitti.set_defaults(_import=_run_kitti)
    womd = formats.add_parser(
        "womd",
        help="Waymo Open Motion Dataset scenarios (TFRecord files) → DIR/womd_<scenario_id>/",
        description="Convert every Scenario of Waymo Open Motion Dataset TFRecord files into an AV2-layout "
        "log DIR/womd_<scenario_id>/. Scenarios that cannot be imported are listed with the reason; the "
        "others are imported. Exits 1 when any scenario was skipped, 2 when none was imported.",
    )
    womd.add_argument("files", nargs="+", type=Path, metavar="FILE", help="TFRecord files of Scenario records")
    womd.add_argument("--out", type=Path, required=True, help="folder that receives womd_<scenario_id>/")
    womd.add_argument("--overwrite", action="store_true", help="replace existing logs of the same name")
    womd.set_defaults(_import=_run_womd)


def run(args: argparse.Namespace) -> int:
    return int(args._import(args))


def _run_kitti(args: argparse.Namespace) -> int:
    if args.detections:
        try:
            tracking = importlib.import_module("scenes.tracking")
        except ModuleNotFoundError as exc:
            if exc.name == "scenes.tracking":
                raise ValueError("tracking from detections is not available in this installation") from exc
            raise
        if not hasattr(tracking, "import_kitti_detections"):
            raise ValueError("tracking from detections is not available in this installation")
        result = tracking.import_kitti_detections(
            args.detections, args.poses, args.calib, args.out, overwrite=args.overwrite
        )
        print(result.summary() if hasattr(result, "summary") else result)
        return 0
    from scenes.kitti import import_kitti_sequence

    report = import_kitti_sequence(args.labels, args.poses, args.calib, args.out, overwrite=args.overwrite)
    print(report.summary())
    return 0


def _run_womd(args: argparse.Namespace) -> int:
    from scenes.womd import import_womd_files

    batch = import_womd_files(args.files, args.out, overwrite=args.overwrite)
    for report in batch.imported:
        print(report.summary())
    for skip in batch.skipped:
        print(skip)
    print(f"imported {len(batch.imported)} scenarios into {args.out}; skipped {len(batch.skipped)}")
    return 2 if not batch.imported else 1 if batch.skipped else 0
