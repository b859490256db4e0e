"""Errors raised by :mod:`indexes`; each names the file, row, id or field at fault.

The base class is :class:`IndexesError` (not ``IndexError``, which Python uses for sequence
positions). Errors about bad arguments also derive from ``ValueError`` so that callers that only
know the standard library still catch them.
"""

from __future__ import annotations

from pathlib import Path

import scenesearch_base.config


class IndexesError(Exception):
    """Base class of every error raised by :mod:`indexes`."""


class ConfigError(IndexesError, scenesearch_base.config.ConfigError):
    """An index configuration (:class:`~indexes.factory.AutoConfig`) holds unknown keys or values out of range."""


class VectorError(IndexesError, ValueError):
    """A vector batch has the wrong shape, dimension or dtype, or holds NaN/inf/zero rows."""

    def __init__(self, message: str, row: int | None = None) -> None:
        self.row = row
        self.reason = message
        super().__init__(message if row is None else f"row {row}: {message}")


class DimensionMismatchError(VectorError):
    """Vectors whose dimension differs from the index's."""

    def __init__(self, expected: int, got: int, what: str = "vectors") -> None:
        self.expected = expected
        self.got = got
        super().__init__(f"{what} have dimension {got}, the index has dimension {expected}")


class IdError(IndexesError, ValueError):
    """Ids that are duplicated, negative, reused after removal, or unknown."""

    def __init__(self, message: str, ids: list[int] | None = None) -> None:
        self.ids = list(ids or [])
        shown = ", ".join(str(i) for i in self.ids[:10])
        more = f" (and {len(self.ids) - 10} more)" if len(self.ids) > 10 else ""
        super().__init__(f"{message}: {shown}{more}" if self.ids else message)


class InvalidKError(IndexesError, ValueError):
    """``k`` is not positive or exceeds the number of vectors in the collection."""

    def __init__(self, k: int, size: int) -> None:
        self.k = k
        self.size = size
        if k <= 0:
            message = f"k must be positive, got k={k}"
        else:
            message = f"k={k} is larger than the collection, which holds {size} vectors"
        super().__init__(message)


class ReadOnlyIndexError(IndexesError):
    """A memory-mapped index was asked to change."""


class MemoryBudgetError(IndexesError, ValueError):
    """No index kind holds the collection within the given memory budget."""


class IndexFileError(IndexesError):
    """An index directory or one of its files is missing, truncated, corrupt or inconsistent."""

    def __init__(self, path: Path | str, message: str, field: str | None = None) -> None:
        self.path = Path(path)
        self.field = field
        where = str(self.path) + (f", field '{field}'" if field else "")
        super().__init__(f"{where}: {message}")


class ManifestError(IndexFileError):
    """``manifest.json`` is missing, unreadable, or disagrees with the files beside it."""


class UnsupportedFormatError(ManifestError):
    """``manifest.json`` was written in a format version other than the one this code reads (newer or older)."""


class FilterError(IndexesError, ValueError):
    """A filter expression cannot be parsed, or names a field or value of the wrong kind."""

    def __init__(self, message: str, expression: str | None = None, field: str | None = None) -> None:
        self.expression = expression
        self.field = field
        where = f"filter {expression!r}" if expression is not None else "filter"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {message}")


class MetadataError(IndexesError, ValueError):
    """Clip metadata rows are missing a column, hold duplicate clip ids, or mismatch the vectors."""

    def __init__(self, message: str, row: int | None = None, field: str | None = None) -> None:
        self.row = row
        self.field = field
        where = []
        if row is not None:
            where.append(f"row {row}")
        if field is not None:
            where.append(f"field '{field}'")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)


def faiss_message(exc: BaseException) -> str:
    """The useful line of a FAISS C++ exception (they start with a long source location)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
    return text.split("Error: ", 1)[-1] if "Error: " in text else text
