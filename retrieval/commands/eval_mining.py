"""``scenesearch eval-mining``: score a scenario-mining submission with Argoverse 2's own evaluator.

Both pickles are read with :func:`scenarios.submission.load_submission` first, so an unsafe or
malformed file is refused with its key, frame and field before the evaluator sees it. The
predictions are then laid on the ground truth's frames:

* a ground-truth ``(log_id, description)`` missing from the predictions counts as predicting no
  object at any of its frames; predicted keys absent from the ground truth are left out;
* predicted frames are picked by the ground truth's timestamps (extra predicted timestamps, such
  as a 10 Hz prediction against 2 Hz ground truth, are left out); a ground-truth timestamp missing
  from a prediction is an error.

av2's evaluator reads the description out of ``str((log_id, description))`` at fixed character
positions that hold for the 36-character AV2 log ids; other log ids are handed to it under stable
36-character stand-ins (with ``--dataset-dir`` linked under the same names).

The evaluator (``av2.evaluation.scenario_mining.eval.evaluate``) scores HOTA-Temporal (referred
objects at the frames they are referred), HOTA-Track (the whole track of any object ever referred),
and the balanced accuracies of "is the description anywhere at this timestamp" and "… in this log",
each averaged over descriptions.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import multiprocessing
import sys
import tempfile
import uuid
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from scenarios.submission import Frame, Key, Submission

HELP = ("HOTA-Temporal, HOTA-Track and timestamp/log balanced accuracy of an Argoverse 2 scenario-mining "
        "prediction pickle against ground truth (av2's own evaluator)")

#: The length of an AV2 log id, which av2's evaluator assumes when it reads descriptions out of sequence ids.
AV2_LOG_ID_CHARS = 36
#: Names of the figures in the JSON and the printout, in the evaluator's return order.
FIGURES = ("hota_temporal", "hota_track", "timestamp_balanced_accuracy", "log_balanced_accuracy")
_TITLES = ("HOTA-Temporal", "HOTA-Track", "Timestamp balanced accuracy", "Log balanced accuracy")
_STAND_IN_NAMESPACE = uuid.UUID("6f1c1b0e-8a51-4d43-9a43-3d5a3c1f4e10")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("pred", type=Path, help="predictions pickle ({(log_id, description): [frame, ...]})")
    parser.add_argument("gt", type=Path, help="ground-truth pickle in the same format")
    parser.add_argument("--dataset-dir", type=Path,
                        help="folder of the logs (AV2 layout with map rasters): objects outside the region of "
                             "interest are left out, as in the official evaluation; default: none left out")
    parser.add_argument("--max-range-m", type=int, default=50,
                        help="objects farther than this from the ego are left out (default 50, the official range)")
    parser.add_argument("--out", type=Path, help="metrics.json to write (the figures and each description's)")


def run(args: argparse.Namespace) -> int:
    from scenarios.submission import load_submission
    from scenesearch_base.atomic import atomic_write_text, check_output_file

    if args.out is not None:
        check_output_file(args.out)  # before the work that would fill it

    if not args.max_range_m > 0:
        raise ValueError(f"--max-range-m must be positive, got {args.max_range_m}")
    if args.dataset_dir is not None and not args.dataset_dir.is_dir():
        what = "is not a folder" if args.dataset_dir.exists() else "does not exist"
        raise FileNotFoundError(f"--dataset-dir {args.dataset_dir}: {what} (expected the folder of the logs, "
                                "one sub-folder per log id)")
    predictions = load_submission(args.pred, require_score=True)
    labels = load_submission(args.gt)
    predictions, notes = align_predictions(predictions, labels, args.pred)
    for note in notes:
        print(note, file=sys.stderr)
    metrics = score_submission(predictions, labels, args.max_range_m, args.dataset_dir)
    for name, title in zip(FIGURES, _TITLES):
        print(f"{title:<30}{metrics[name]:.4f}")
    if args.out is not None:
        atomic_write_text(args.out, json.dumps(metrics, indent=2, sort_keys=True))
        print(f"wrote {args.out}")
    return 0


def align_predictions(predictions: Submission, labels: Submission, pred_path: Path) -> tuple[Submission, list[str]]:
    """The predictions on the ground truth's keys and frames, and notes on what was filled in or left out.

    Raises:
        SubmissionError: a prediction lacks one of its ground truth's timestamps (names the key and the frame).
    """
    from scenarios.submission import SubmissionError

    aligned: Submission = {}
    missing: list[Key] = []
    for key, gt_frames in labels.items():
        if key not in predictions:
            missing.append(key)
            aligned[key] = [_empty_frame(key, gt) for gt in gt_frames]
            continue
        by_timestamp = {int(frame["timestamp_ns"]): frame for frame in predictions[key]}
        frames = []
        for index, gt in enumerate(gt_frames):
            frame = by_timestamp.get(int(gt["timestamp_ns"]))
            if frame is None:
                raise SubmissionError(f"{pred_path}: key {key!r}: no frame at the ground truth's frame {index}, "
                                      f"field 'timestamp_ns' {int(gt['timestamp_ns'])}")
            frames.append(frame)
        aligned[key] = frames
    notes = []
    if missing:
        notes.append(f"{len(missing)} ground-truth (log_id, description) pairs have no prediction, scored as "
                     f"predicting nothing: {', '.join(map(repr, missing[:3]))}{' …' if len(missing) > 3 else ''}")
    extra = [key for key in predictions if key not in labels]
    if extra:
        notes.append(f"{len(extra)} predicted (log_id, description) pairs are not in the ground truth and are "
                     f"left out: {', '.join(map(repr, extra[:3]))}{' …' if len(extra) > 3 else ''}")
    return aligned, notes


def _empty_frame(key: Key, gt: Frame) -> Frame:
    import numpy as np

    return {
        "seq_id": key, "timestamp_ns": gt["timestamp_ns"], "ego_translation_m": list(gt["ego_translation_m"]),
        "description": key[1], "track_id": np.zeros(0, np.int32), "label": np.zeros(0, np.int32),
        "name": np.zeros(0, "<U31"), "score": np.zeros(0, np.float32), "translation_m": np.zeros((0, 3)),
        "size": np.zeros((0, 3), np.float32), "yaw": np.zeros(0, np.float32), "velocity_m_per_s": np.zeros((0, 3)),
    }


def score_submission(predictions: Submission, labels: Submission, max_range_m: int,
                     dataset_dir: Path | None) -> dict[str, Any]:
    """The four figures of av2's evaluator and each description's, for aligned predictions.

    Returns:
        ``{figure: value}`` for :data:`FIGURES`, plus ``"by_description"``: ``{description: {figure: value}}``.
    """
    stand_in = {log_id: _stand_in(log_id) for log_id, _ in labels}
    with contextlib.ExitStack() as stack:
        work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="eval-mining-")))
        logs_dir = None if dataset_dir is None else str(_link_logs(dataset_dir, stand_in, work / "logs"))
        evaluate = _av2_evaluate()
        with contextlib.redirect_stdout(sys.stderr):  # the evaluator's progress is not the command's output
            figures = evaluate(_renamed(predictions, stand_in), _renamed(labels, stand_in), "HOTA", max_range_m,
                               logs_dir, str(work / "av2"))
        by_class = _read_by_class(work / "av2")
    metrics: dict[str, Any] = {name: float(value) for name, value in zip(FIGURES, figures)}
    class_of = {_class_name(stand_in[log_id], description): description for log_id, description in labels}
    metrics["by_description"] = {
        class_of.get(name, name): {figure: values[figure] for figure in FIGURES if figure in values}
        for name, values in by_class.items()
    }
    return metrics


def _av2_evaluate() -> Callable[..., tuple[float, float, float, float]]:
    """av2's evaluator, imported with its imports' notices (trackeval's optional datasets, numpy aliases) muted."""
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        from av2.evaluation.scenario_mining.eval import evaluate
        from av2.evaluation.tracking import eval as tracking_eval
    # The evaluator's worker pool forks this process by default; a fork of a process whose other threads
    # hold locks (a Ray runtime's, torch's) can hang its children. Its workers start from a fresh server
    # process instead.
    setattr(tracking_eval, "mp", multiprocessing.get_context("forkserver"))  # noqa: B010
    return evaluate


def _stand_in(log_id: str) -> str:
    """The log id itself where it has AV2's length, else a stable 36-character UUID derived from it."""
    return log_id if len(log_id) == AV2_LOG_ID_CHARS else str(uuid.uuid5(_STAND_IN_NAMESPACE, log_id))


def _class_name(log_id: str, description: str) -> str:
    """The name av2's evaluator gives a description: its characters in ``str((log_id, description))``."""
    return str((log_id, description))[AV2_LOG_ID_CHARS + 6:-2]


def _renamed(submission: Submission, stand_in: dict[str, str]) -> dict[str, list[Frame]]:
    """The submission keyed by ``str((stand-in log id, description))``, frames copied shallowly."""
    renamed: dict[str, list[Frame]] = {}
    for (log_id, description), frames in submission.items():
        key = (stand_in[log_id], description)
        renamed[str(key)] = [{**frame, "seq_id": str(key)} for frame in frames]
    return renamed


def _link_logs(dataset_dir: Path, stand_in: dict[str, str], links: Path) -> Path:
    """A folder of the logs under their stand-in names, after checking each has what the ROI filter reads."""
    links.mkdir()
    for log_id, name in stand_in.items():
        log_dir = dataset_dir / log_id
        needed = [("city_SE3_egovehicle.feather",), ("map", "log_map_archive_*.json"),
                  ("map", "*_ground_height_surface____*.npy"), ("map", "*___img_Sim2_city.json")]
        if not log_dir.is_dir():
            raise FileNotFoundError(f"--dataset-dir {dataset_dir}: no folder {log_dir} for the log {log_id!r} of the "
                                    "ground truth; leave out --dataset-dir to score without the region of interest")
        for parts in needed:
            if not any(log_dir.glob("/".join(parts))):
                raise FileNotFoundError(f"--dataset-dir {dataset_dir}: {log_dir / '/'.join(parts)} not found "
                                        "(the region-of-interest filter needs the log's poses, vector map and "
                                        "map rasters); leave out --dataset-dir to score without it")
        for raster in log_dir.glob("map/*_ground_height_surface____*.npy"):
            _check_raster(raster)
        (links / name).symlink_to(log_dir.resolve(), target_is_directory=True)
    return links


def _check_raster(path: Path) -> None:
    """A map raster the evaluator's region-of-interest filter can read whole (a truncated one aborts it)."""
    import numpy as np

    try:
        array = np.load(path, mmap_mode="r", allow_pickle=False)
        if array.ndim != 2:
            raise ValueError(f"expected a 2-D array, got shape {array.shape}")
    except (OSError, ValueError) as exc:
        raise ValueError(f"--dataset-dir: {path}: not a readable map raster ({exc})") from None


def _read_by_class(folder: Path) -> dict[str, dict[str, float]]:
    """Each description's figures from the files av2's evaluator writes into ``folder``."""
    sources = {
        "temporal_metrics.json": {"timestamp_balanced_accuracy_by_class": "timestamp_balanced_accuracy",
                                  "scenario_balanced_accuracy_by_class": "log_balanced_accuracy"},
        "spatiotemporal_metrics.json": {"hota_temporal_by_class": "hota_temporal",
                                        "hota_track_by_class": "hota_track"},
    }
    by_class: dict[str, dict[str, float]] = {}
    for file_name, fields in sources.items():
        path = folder / file_name
        if not path.exists():
            continue
        written = json.loads(path.read_text())
        for field, figure in fields.items():
            for name, value in written.get(field, {}).items():
                by_class.setdefault(name, {})[figure] = float(value)
    return by_class
