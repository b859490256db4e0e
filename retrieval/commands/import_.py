"""``scenesearch import <format> ...``: convert foreign data into AV2-layout logs.

``scenesearch import kitti --labels L --poses P --calib C --out DIR [--overwrite]`` converts one
KITTI tracking sequence into ``DIR/kitti_<seq>/`` (see :mod:`scenes.kitti`).
``--detections D [D ...]`` instead of ``--labels`` builds tracks from per-frame detections with
:func:`scenes.tracking.import_kitti_detections`.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

HELP = "convert foreign logs into the AV2 layout (kitti)"


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
