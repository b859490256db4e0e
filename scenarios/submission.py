"""Argoverse 2 scenario-mining submissions: write :class:`LogAnswer` s in the format, read and check one.

A submission (predictions or ground truth) is a pickled ``dict`` keyed by ``(log_id, description)``
whose values are lists of frame dicts, one per evaluation timestamp, increasing. A frame holds::

    seq_id             (log_id, description)
    timestamp_ns       int
    ego_translation_m  list of 3 floats: the ego's position in the city frame
    description        str
    track_id           (N,) int32: the object's track, an index into the answer's track ids
    label              (N,) int32: 0 referred, 1 related, 2 other object
    name               (N,) str: AV2 category (REGULAR_VEHICLE, PEDESTRIAN, …)
    score              (N,) float32: confidence that the object is referred to
    translation_m      (N, 3) float64: box centres in the city frame
    size               (N, 3) float32: box length, width, height
    yaw                (N,) float32: headings in the city frame, radians
    velocity_m_per_s   (N, 3) float64: velocities in the city frame

over the N objects observed at the frame. ``ego_translation_m`` is a list, not an array, because
av2's evaluator indexes every array of a frame by its objects. Evaluation timestamps are the log's
annotation timestamps at 2 Hz from the first (every 5th of a 10 Hz log).

The evaluator keeps the referred objects whose ``score`` passes a threshold it tunes per
description; for HOTA-Track it first relabels every frame of a track that is ever referred as
referred. So a referred object's score is its referred score at that frame, and every other
object's is the highest referred score of its track in the log (0 for a track never referred): a
threshold then keeps or drops an ever-referred track whole.

Reading never runs code from the file: the unpickler resolves only the numpy globals that arrays,
dtypes and scalars need, and refuses any other global (``os.system``, a class) by name.
"""

from __future__ import annotations

import importlib
import math
import pickle
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from scenarios.answer import LogAnswer
from scenes.categories import AV2_TO_CATEGORY, CATEGORY_TO_AV2, EGO_VEHICLE_LABEL, Category, category_from_label
from scenesearch_base.atomic import atomic_write_bytes

#: The period of evaluation timestamps.
EVALUATION_PERIOD_NS = 500_000_000
#: Labels of the scenario-mining categories, in av2's order.
REFERRED, RELATED, OTHER = 0, 1, 2
#: Frame fields every submission frame holds.
REQUIRED_FIELDS = ("timestamp_ns", "ego_translation_m", "track_id", "label", "name", "translation_m", "size", "yaw")
#: Per-object fields and the trailing shape of each, beyond the leading N.
OBJECT_FIELDS: dict[str, tuple[int, ...]] = {
    "track_id": (), "label": (), "name": (), "score": (), "translation_m": (3,), "size": (3,), "yaw": (),
    "velocity_m_per_s": (3,),
}
#: Globals a pickle of numpy arrays, dtypes and scalars needs, by numpy's module (``numpy.core`` before numpy 2).
_NUMPY_GLOBALS = {("multiarray", "_reconstruct"), ("multiarray", "scalar"), ("numeric", "_frombuffer")}
_PLAIN_GLOBALS = {("numpy", "ndarray"), ("numpy", "dtype"), ("builtins", "set"), ("builtins", "frozenset"),
                  ("builtins", "bytearray"), ("_codecs", "encode")}

Key = tuple[str, str]
Frame = dict[str, Any]
Submission = dict[Key, list[Frame]]


class SubmissionError(ValueError):
    """A submission file is unsafe or malformed; names the file, the key, the frame and the field."""


def evaluation_frames(timestamps_ns: NDArray[np.int64], all_timestamps: bool = False) -> NDArray[np.intp]:
    """Indices of the evaluation frames of a log: every frame at 2 Hz from the first.

    Args:
        timestamps_ns: (F,) the log's annotation timestamps, increasing.
        all_timestamps: keep every frame.

    Returns:
        (E,) increasing frame indices; the stride is ``max(1, round(0.5 s / median interval))``.
    """
    count = len(timestamps_ns)
    if all_timestamps or count < 2:
        return np.arange(count)
    median_interval_ns = float(np.median(np.diff(np.asarray(timestamps_ns, dtype=np.int64))))
    if median_interval_ns <= 0:
        raise ValueError(f"timestamps_ns: not increasing (median interval {median_interval_ns} ns)")
    return np.arange(0, count, max(1, round(EVALUATION_PERIOD_NS / median_interval_ns)))


def av2_name(category: str) -> str:
    """The AV2 category written for a category: an AV2 label stays, a public category maps to its AV2 label."""
    if category in AV2_TO_CATEGORY or category == EGO_VEHICLE_LABEL:
        return category
    return CATEGORY_TO_AV2[category_from_label(category) or Category.OTHER]


def frames_of(answer: LogAnswer, all_timestamps: bool = False) -> list[Frame]:
    """The frame dicts of one ``(log_id, description)`` of a submission, at the evaluation timestamps.

    Args:
        answer: the description's answer in one log.
        all_timestamps: write every annotation timestamp instead of those at 2 Hz.

    Returns:
        One frame dict per evaluation timestamp (see the module docstring), over the objects
        observed there.
    """
    num_tracks, num_frames = answer.valid.shape
    _check_answer_shapes(answer, num_tracks, num_frames)
    valid = np.asarray(answer.valid, dtype=bool)
    referred = answer.referred_mask & valid
    related = np.asarray(answer.related, dtype=bool) & valid & ~referred
    labels = np.where(referred, REFERRED, np.where(related, RELATED, OTHER)).astype(np.int32)  # (K, F)
    referred_score = np.where(referred, answer.referred, 0.0).astype(np.float32)  # (K, F)
    track_score = referred_score.max(axis=1, initial=0.0)  # (K,)
    scores = np.where(referred, referred_score, track_score[:, None]).astype(np.float32)  # (K, F)
    names = np.array([av2_name(str(c)) for c in answer.categories], dtype="<U31").reshape(num_tracks)
    track_ids = np.arange(num_tracks, dtype=np.int32)
    key = (answer.log_id, answer.description)
    frames: list[Frame] = []
    for f in evaluation_frames(answer.timestamps_ns, all_timestamps):
        on = valid[:, f]
        frames.append({
            "seq_id": key,
            "timestamp_ns": int(answer.timestamps_ns[f]),
            "ego_translation_m": [float(v) for v in answer.ego_city_xyz_m[f]],
            "description": answer.description,
            "track_id": track_ids[on],
            "label": labels[on, f],
            "name": names[on],
            "score": scores[on, f],
            "translation_m": np.asarray(answer.center_city_xyz_m[on, f], dtype=np.float64).reshape(-1, 3),
            "size": np.asarray(answer.size_lwh_m[on, f], dtype=np.float32).reshape(-1, 3),
            "yaw": np.asarray(answer.yaw_city_rad[on, f], dtype=np.float32),
            "velocity_m_per_s": np.asarray(answer.velocity_city_mps[on, f], dtype=np.float64).reshape(-1, 3),
        })
    return frames


def _check_answer_shapes(answer: LogAnswer, num_tracks: int, num_frames: int) -> None:
    expected: dict[str, tuple[int, ...]] = {
        "timestamps_ns": (num_frames,), "track_ids": (num_tracks,), "categories": (num_tracks,),
        "referred": (num_tracks, num_frames), "related": (num_tracks, num_frames),
        "center_city_xyz_m": (num_tracks, num_frames, 3), "size_lwh_m": (num_tracks, num_frames, 3),
        "yaw_city_rad": (num_tracks, num_frames), "velocity_city_mps": (num_tracks, num_frames, 3),
        "ego_city_xyz_m": (num_frames, 3),
    }
    for field, shape in expected.items():
        got = np.shape(getattr(answer, field))
        if got != shape:
            raise ValueError(f"answer ({answer.log_id!r}, {answer.description!r}), field '{field}': shape {got}, "
                             f"expected {shape} for {num_tracks} tracks × {num_frames} frames")


def build_submission(answers: Iterable[LogAnswer], all_timestamps: bool = False) -> Submission:
    """The submission dict of several answers; a ``(log_id, description)`` given twice is an error."""
    submission: Submission = {}
    for answer in answers:
        key = (answer.log_id, answer.description)
        if key in submission:
            raise ValueError(f"answer {key!r}: given twice")
        submission[key] = frames_of(answer, all_timestamps)
    return submission


def write_submission(answers: Iterable[LogAnswer], path: Path | str, all_timestamps: bool = False) -> Submission:
    """Write the answers as one submission pickle (protocol 4), atomically, and return what was written.

    The submission passes :func:`check_submission` first, so a file written here always loads.
    """
    submission = build_submission(answers, all_timestamps)
    check_submission(submission, Path(path))
    atomic_write_bytes(path, pickle.dumps(submission, protocol=4))
    return submission


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Resolves the globals of numpy arrays, dtypes and scalars, and of plain containers; refuses any other."""

    def __init__(self, file: IO[bytes], path: Path) -> None:
        super().__init__(file)
        self._path = path

    def find_class(self, module: str, name: str) -> Any:
        for prefix in ("numpy._core.", "numpy.core."):
            if module.startswith(prefix) and (module.removeprefix(prefix), name) in _NUMPY_GLOBALS:
                return _numpy_core_global(module.removeprefix(prefix), name)
        if (module, name) in _PLAIN_GLOBALS:
            return super().find_class(module, name)
        raise SubmissionError(f"{self._path}: refuses the global {module}.{name}: a submission holds only numpy "
                              "arrays, numbers, strings and containers")


def _numpy_core_global(submodule: str, name: str) -> Any:
    """``numpy._core.<submodule>.<name>`` (numpy 2), or ``numpy.core.…`` where numpy has no ``_core``."""
    try:
        return getattr(importlib.import_module(f"numpy._core.{submodule}"), name)
    except ImportError:
        return getattr(importlib.import_module(f"numpy.core.{submodule}"), name)


def load_submission(path: Path | str, require_score: bool = False) -> Submission:
    """Read a prediction or ground-truth pickle safely and check its structure.

    Args:
        path: the pickle.
        require_score: every frame must hold ``score`` (predictions; ground truth may omit it).

    Returns:
        The submission dict, as stored.

    Raises:
        SubmissionError: the file is not a pickle, holds a global other than numpy's, or breaks the
            format (naming the key, the frame and the field).
        FileNotFoundError: there is no such file.
    """
    path = Path(path)
    with path.open("rb") as file:
        try:
            submission = _NumpyOnlyUnpickler(file, path).load()
        except SubmissionError:
            raise
        except Exception as exc:  # any byte string: truncated, not a pickle, wrong arguments to numpy
            raise SubmissionError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc})") from None
    check_submission(submission, path, require_score)
    return submission


def check_submission(submission: object, path: Path, require_score: bool = False) -> None:
    """Raise :class:`SubmissionError` at the first thing in ``submission`` that breaks the format.

    Keys are ``(log_id, description)`` string pairs; values non-empty lists of frame dicts with
    increasing ``timestamp_ns``; every frame holds :data:`REQUIRED_FIELDS` (and ``score`` where
    ``require_score``); per-object arrays share one length N with the trailing shapes of
    :data:`OBJECT_FIELDS`; numbers are finite; labels are 0, 1 or 2; track ids are unique in a frame.
    """
    if not isinstance(submission, Mapping):
        raise SubmissionError(f"{path}: holds a {type(submission).__name__}, not a dict keyed by "
                              "(log_id, description)")
    for key, frames in submission.items():
        if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(k, str) for k in key)):
            raise SubmissionError(f"{path}: key {key!r}: not a (log_id, description) pair of strings")
        if not isinstance(frames, list) or not frames:
            raise SubmissionError(f"{path}: key {key!r}: not a non-empty list of frames")
        previous_ns: int | None = None
        for index, frame in enumerate(frames):
            where = f"{path}: key {key!r}, frame {index}"
            if not isinstance(frame, dict):
                raise SubmissionError(f"{where}: a {type(frame).__name__}, not a dict")
            _check_frame(frame, where, require_score)
            timestamp_ns = int(frame["timestamp_ns"])
            if previous_ns is not None and timestamp_ns <= previous_ns:
                raise SubmissionError(f"{where}, field 'timestamp_ns': {timestamp_ns} does not follow the previous "
                                      f"frame's {previous_ns}")
            previous_ns = timestamp_ns


def _check_frame(frame: Frame, where: str, require_score: bool) -> None:
    required = (*REQUIRED_FIELDS, "score") if require_score else REQUIRED_FIELDS
    for field in required:
        if field not in frame:
            raise SubmissionError(f"{where}, field '{field}': missing")
    timestamp_ns = frame["timestamp_ns"]
    if isinstance(timestamp_ns, bool | np.bool_) or not isinstance(timestamp_ns, int | np.integer):
        raise SubmissionError(f"{where}, field 'timestamp_ns': {timestamp_ns!r} is not an integer")
    ego = frame["ego_translation_m"]
    if not (isinstance(ego, list | tuple) and len(ego) == 3
            and all(isinstance(v, int | float | np.integer | np.floating) and math.isfinite(float(v)) for v in ego)):
        raise SubmissionError(f"{where}, field 'ego_translation_m': {ego!r} is not a list of 3 finite numbers")
    if "description" in frame and not isinstance(frame["description"], str):
        raise SubmissionError(f"{where}, field 'description': {frame['description']!r} is not a string")
    positive = frame.get("is_positive")
    if positive is not None and not isinstance(positive, bool | np.bool_):
        raise SubmissionError(f"{where}, field 'is_positive': {positive!r} is not true, false or None")
    num_objects = _num_objects(frame["track_id"], where)
    for field, trailing in OBJECT_FIELDS.items():
        if field in frame:
            _check_object_array(frame[field], field, (num_objects, *trailing), where)
    for field, value in frame.items():
        if (field not in OBJECT_FIELDS and isinstance(value, np.ndarray)
                and (value.ndim == 0 or len(value) != num_objects)):
            raise SubmissionError(f"{where}, field '{field}': shape {value.shape}, expected ({num_objects}, …) as "
                                  "every array of a frame is indexed by its objects")
    labels = frame["label"]
    bad = ~np.isin(labels, (REFERRED, RELATED, OTHER))
    if bad.any():
        raise SubmissionError(f"{where}, field 'label': {labels[bad][0]} at object {int(np.argmax(bad))} is not "
                              "0 (referred), 1 (related) or 2 (other)")
    if len(np.unique(frame["track_id"])) != num_objects:
        raise SubmissionError(f"{where}, field 'track_id': a track id occurs twice")


def _num_objects(track_id: object, where: str) -> int:
    if not isinstance(track_id, np.ndarray) or track_id.ndim != 1:
        raise SubmissionError(f"{where}, field 'track_id': not a 1-D numpy array")
    return len(track_id)


def _check_object_array(value: object, field: str, shape: tuple[int, ...], where: str) -> None:
    if not isinstance(value, np.ndarray):
        raise SubmissionError(f"{where}, field '{field}': a {type(value).__name__}, not a numpy array")
    if value.shape != shape:
        raise SubmissionError(f"{where}, field '{field}': shape {value.shape}, expected {shape} (N = "
                              f"{shape[0]} objects, the length of 'track_id')")
    if field == "name":
        if value.dtype.kind != "U" and not (value.dtype.kind == "O" and all(isinstance(v, str) for v in value)):
            raise SubmissionError(f"{where}, field 'name': dtype {value.dtype}, not strings")
        return
    integral = field in ("track_id", "label")
    if value.dtype.kind not in ("iu" if integral else "iuf"):
        raise SubmissionError(f"{where}, field '{field}': dtype {value.dtype}, not "
                              f"{'integers' if integral else 'numbers'}")
    finite = np.isfinite(value)
    if not finite.all():
        at = np.unravel_index(int(np.argmax(~finite)), value.shape)[0]
        raise SubmissionError(f"{where}, field '{field}': {value[~finite][0]} at object {at} is not finite")
