"""Score predicted logs against ground-truth logs (``scenesearch eval-tracking``), one pair or a split.

Which boxes count is the protocol's choice (:class:`Protocol`): every box (``plain``), or the KITTI
benchmark's ignore rules (``kitti``, :mod:`scenes.tracking.kitti_protocol`), which need the
sequence's official label file for its ``DontCare`` regions and the truncation, occlusion and type
of each object. ``auto`` applies the KITTI rules to logs imported from KITTI labels and finds their
label file where the import read it, unless told where it is.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from scenes import av2_io
from scenes.categories import Category
from scenes.kitti import read_kitti_labels
from scenes.log import Log
from scenes.tracking.evaluate import DEFAULT_CATEGORIES, TrackingCounts, tracking_counts
from scenes.tracking.kitti_protocol import kitti_ignore_rules


class Protocol(StrEnum):
    """Which boxes a score counts."""

    #: ``kitti`` for logs imported from KITTI labels, ``plain`` otherwise.
    AUTO = "auto"
    #: Every box of the scored categories.
    PLAIN = "plain"
    #: The KITTI tracking benchmark's ignore rules (``DontCare``, neighbouring classes, truncation, occlusion).
    KITTI = "kitti"


@dataclass(frozen=True)
class PairEvaluation:
    """The counts of one predicted log against its ground truth, and how they were made.

    Attributes:
        pred_log: the predicted log folder.
        gt_log: the ground-truth log folder.
        protocol: the protocol applied (``plain`` or ``kitti``, never ``auto``).
        labels_path: the KITTI label file read, under the KITTI protocol.
        counts: per category, to pool or turn into figures.
    """

    pred_log: Path
    gt_log: Path
    protocol: Protocol
    labels_path: Path | None
    counts: dict[Category, TrackingCounts]

    def figures(self) -> dict[str, dict[str, Any]]:
        """Per category with scored ground truth, as :meth:`TrackingCounts.figures`."""
        return {c.value: n.figures() for c, n in self.counts.items() if n.num_gt > 0}


def kitti_label_file(gt_log: Log, labels: Path | None = None) -> Path:
    """The official label file of a ground-truth log imported from KITTI.

    Args:
        gt_log: the ground-truth log.
        labels: a label file, or a ``label_02`` folder holding ``<sequence>.txt``; without it, the
            file the import read (recorded in the log's metadata; relative paths are relative to
            the working folder, as they were at import).

    Raises:
        FileNotFoundError: naming the file looked for, and how to point at another.
    """
    extra = gt_log.metadata.extra
    sequence = str(extra.get("sequence") or gt_log.log_id.removeprefix("kitti_"))
    if labels is not None:
        path = labels / f"{sequence}.txt" if labels.is_dir() else labels
        where = "--kitti-labels"
    else:
        recorded = (extra.get("sources") or {}).get("labels")
        if not recorded:
            raise FileNotFoundError(f"{gt_log.log_dir}: the log's metadata records no KITTI label file; pass "
                                    "--kitti-labels (the file or the label_02 folder), or --protocol plain")
        path, where = Path(str(recorded)), "the log's metadata (sources.labels)"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: KITTI label file of {gt_log.log_dir} (from {where}) is missing; pass "
                                "--kitti-labels (the file or the label_02 folder), or --protocol plain to count "
                                "every box")
    return path


def evaluate_log_pair(
    pred_dir: Path | str,
    gt_dir: Path | str,
    protocol: Protocol = Protocol.AUTO,
    kitti_labels: Path | None = None,
    max_distance_m: float = 2.0,
    categories: tuple[Category, ...] = DEFAULT_CATEGORIES,
) -> PairEvaluation:
    """Score one predicted log against its ground truth.

    Args:
        pred_dir: the predicted log.
        gt_dir: the ground-truth log.
        protocol: which boxes count.
        kitti_labels: under the KITTI protocol, the label file or ``label_02`` folder (see
            :func:`kitti_label_file`).
        max_distance_m: largest centre distance of a CLEAR-MOT / IDF1 match.
        categories: categories to score.

    Raises:
        LogFormatError: a log is unreadable.
        FileNotFoundError: the KITTI label file is missing.
        ImportFormatError: the label file is malformed or belongs to another log.
    """
    pred, gt = Log.open(pred_dir), Log.open(gt_dir)
    if protocol is Protocol.AUTO:
        protocol = Protocol.KITTI if gt.metadata.source == "kitti" else Protocol.PLAIN
    labels_path: Path | None = None
    ignore = None
    if protocol is Protocol.KITTI:
        labels_path = kitti_label_file(gt, kitti_labels)
        ignore = kitti_ignore_rules(gt.annotations, read_kitti_labels(labels_path), labels_path, pred.annotations,
                                    gt.calibration)
    counts = tracking_counts(pred.annotations, pred.ego, gt.annotations, gt.ego, max_distance_m, categories, ignore)
    return PairEvaluation(pred.log_dir, gt.log_dir, protocol, labels_path, counts)


def is_log_folder(path: Path) -> bool:
    """Whether ``path`` is one log (it has annotations or ego poses) rather than a folder of logs."""
    return (path / av2_io.ANNOTATIONS_FILENAME).is_file() or (path / av2_io.POSES_FILENAME).is_file()


def pair_logs(pred: Path, gt: Path) -> tuple[list[tuple[Path, Path]], dict[str, str]]:
    """The (predicted, ground-truth) log pairs to score, and the logs left out with the reason.

    Two logs make one pair; two folders of logs are paired by log folder name.

    Raises:
        FileNotFoundError: a path is missing.
        ValueError: one path is a log and the other a folder of logs.
    """
    for path in (pred, gt):
        if not path.is_dir():
            raise FileNotFoundError(f"{path}: no such folder")
    if is_log_folder(pred) and is_log_folder(gt):
        return [(pred, gt)], {}
    if is_log_folder(pred) or is_log_folder(gt):
        raise ValueError(f"{pred} and {gt}: give two logs, or two folders of logs")
    pred_logs = {p.name: p for p in sorted(pred.iterdir()) if p.is_dir() and not p.name.startswith(".")}
    gt_logs = {p.name: p for p in sorted(gt.iterdir()) if p.is_dir() and not p.name.startswith(".")}
    pairs = [(pred_logs[name], gt_logs[name]) for name in sorted(pred_logs.keys() & gt_logs.keys())]
    skipped = {name: f"no ground-truth log of that name in {gt}" for name in sorted(pred_logs.keys() - gt_logs.keys())}
    skipped.update({name: f"no predicted log of that name in {pred}"
                    for name in sorted(gt_logs.keys() - pred_logs.keys())})
    return pairs, skipped


def pool(evaluations: list[PairEvaluation]) -> dict[Category, TrackingCounts]:
    """Counts pooled over logs per category, as a benchmark scores a split."""
    pooled: dict[Category, TrackingCounts] = {}
    for evaluation in evaluations:
        for category, counts in evaluation.counts.items():
            pooled[category] = pooled.get(category, TrackingCounts()) + counts
    return pooled
