"""Errors for bad input: each names the file, the row or frame, and the field."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import ParamSpec, TypeVar

import scenesearch_base.config

P = ParamSpec("P")
T = TypeVar("T")


class ScenesError(Exception):
    """Base class of every error raised by :mod:`scenes`."""


class ConfigError(ScenesError, scenesearch_base.config.ConfigError):
    """A config of a scenes stage (simulator, sensors, tracker) is invalid; names the file and the key."""


class TrackFrameError(ScenesError):
    """A value of one track at one frame that a stage cannot use (a NaN centre, a flat box).

    The message reads ``PLACE, frame F (timestamp_ns N), field 'FIELD': MESSAGE``, where ``place`` names
    the log or file and the track as the raising stage writes them.

    Attributes:
        track_id: the track.
        frame: 0-based frame index.
        timestamp_ns: the frame's timestamp.
        field: the field at fault.
    """

    def __init__(self, place: str, track_id: str, frame: int, timestamp_ns: int, field: str, message: str) -> None:
        self.track_id = track_id
        self.frame = frame
        self.timestamp_ns = timestamp_ns
        self.field = field
        super().__init__(f"{place}, frame {frame} (timestamp_ns {timestamp_ns}), field '{field}': {message}")


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an input file.

    Attributes:
        path: the file (or folder) at fault.
        message: what is wrong, in words.
        field: the column or key at fault, if any.
        row: the 0-based row, line or frame at fault, if any.
    """

    path: Path
    message: str
    field: str | None = None
    row: int | None = None

    def __str__(self) -> str:
        where = str(self.path)
        if self.row is not None:
            where += f", row {self.row}"
        if self.field is not None:
            where += f", field '{self.field}'"
        return f"{where}: {self.message}"


class LogFormatError(ScenesError):
    """A log file is missing, unreadable, or holds values that break the log contract."""

    def __init__(self, problems: list[Problem] | Problem) -> None:
        self.problems = [problems] if isinstance(problems, Problem) else list(problems)
        if not self.problems:
            raise ValueError("LogFormatError needs at least one problem")
        lines = [str(p) for p in self.problems[:20]]
        if len(self.problems) > 20:
            lines.append(f"... and {len(self.problems) - 20} more")
        super().__init__("\n".join(lines))

    @staticmethod
    def single(path: Path | str, message: str, field: str | None = None, row: int | None = None) -> LogFormatError:
        return LogFormatError(Problem(Path(path), message, field, row))


def collect_problems(problems: list[Problem], read: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T | None:
    """``read(*args, **kwargs)``, or None with its :class:`LogFormatError`'s problems added to ``problems``.

    For checks that go on after a bad file, so that every problem of a log is reported, not just the first.
    """
    try:
        return read(*args, **kwargs)
    except LogFormatError as exc:
        problems.extend(exc.problems)
        return None


class MapFormatError(ScenesError, ValueError):
    """A map JSON object does not have the AV2 map shape; names the key of every bad part.

    Attributes:
        errors: ``(key, message, row)`` of each bad part: ``key`` is a path such as
            ``lane_segments[42].left_lane_boundary`` (None for the top level), ``row`` the 0-based
            point of a polyline, if any.
    """

    def __init__(self, errors: list[tuple[str | None, str, int | None]]) -> None:
        if not errors:
            raise ValueError("MapFormatError needs at least one error")
        self.errors = list(errors)
        lines = [f"{key or 'map'}{'' if row is None else f', point {row}'}: {message}"
                 for key, message, row in self.errors[:20]]
        if len(self.errors) > 20:
            lines.append(f"... and {len(self.errors) - 20} more")
        super().__init__("\n".join(lines))

    def problems(self, path: Path) -> list[Problem]:
        """The errors as :class:`Problem` records of the file they were read from."""
        return [Problem(Path(path), message, field=key, row=row) for key, message, row in self.errors]


class ImportFormatError(ScenesError):
    """A file of a foreign format (KITTI, detections, …) cannot be converted."""

    #: What ``line`` counts in the message: lines of a text file, records of a record file, …
    unit = "line"

    def __init__(self, path: Path | str, message: str, line: int | None = None, field: str | None = None) -> None:
        self.path = Path(path)
        self.line = line
        self.field = field
        self.reason = message
        where = str(self.path)
        if line is not None:
            where += f", {self.unit} {line}"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {message}")
