"""Reading the KITTI text files: lines, and numbers named by their 1-based line and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenes.errors import ImportFormatError
from scenes.geometry import FloatArray


def read_lines(path: Path) -> list[str]:
    """The lines of a text file; ``FileNotFoundError`` when it is missing."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file is missing")
    try:
        return path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ImportFormatError(path, f"unreadable text file: {exc}") from exc


def parse_floats(path: Path, line_no: int, tokens: list[str], names: list[str] | None = None) -> FloatArray:
    """(len(tokens),) the numbers of one line; the error names ``names[i]`` (or ``value i``) of the bad one."""
    try:
        values = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError as exc:
        bad = next(i for i, t in enumerate(tokens) if not _is_float(t))
        name = names[bad] if names else f"value {bad + 1}"
        raise ImportFormatError(path, f"not a number: {tokens[bad]!r}", line=line_no, field=name) from exc
    if not np.isfinite(values).all():
        bad = int(np.argmax(~np.isfinite(values)))
        name = names[bad] if names else f"value {bad + 1}"
        raise ImportFormatError(path, "NaN or inf value", line=line_no, field=name)
    return values


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True
