"""Errors raised by :mod:`retrieval`. Each says what was wrong and, where it helps, the valid options.

They derive from ``ValueError`` (bad arguments) or ``FileNotFoundError`` so that the CLI reports them
as one line and exits with status 2.
"""

from __future__ import annotations

from collections.abc import Iterable


class RetrievalError(ValueError):
    """Base class of the errors raised by :mod:`retrieval`."""


class EmptyQueryError(RetrievalError):
    """The query text is empty or only whitespace."""

    def __init__(self) -> None:
        super().__init__("the query is empty; type a sentence such as 'a car in the left lane approaches'")


class InvalidKError(RetrievalError):
    """``k`` is not an integer in 1 … the largest number of results a query may ask for."""

    def __init__(self, k: object, limit: int) -> None:
        self.k = k
        self.limit = limit
        super().__init__(f"k must be an integer in 1 … {limit}, got k={k!r}")


class UnknownClipError(RetrievalError):
    """A clip id that the index does not hold."""

    def __init__(self, clip_id: str, examples: Iterable[str] = ()) -> None:
        self.clip_id = clip_id
        shown = list(examples)[:5]
        hint = f"; examples of valid ids: {', '.join(shown)}" if shown else ""
        super().__init__(f"unknown clip id {clip_id!r}{hint} (list them with `scenesearch export`)")


class NoCameraError(RetrievalError):
    """A clip without camera frames, searched from in the camera view."""

    def __init__(self, clip_id: str) -> None:
        self.clip_id = clip_id
        super().__init__(f"clip {clip_id!r} has no camera frames, so the camera view has nothing of it to search "
                         "from; search from it in the fused or bev view")


class OtherMomentsError(RetrievalError):
    """Other moments asked of a search from clip arrays, whose log and time window the index does not know."""

    def __init__(self) -> None:
        super().__init__("other_moments needs an indexed clip id: the index knows the log and time window of its "
                         "own clips only")


class UnknownViewError(RetrievalError):
    """A view name other than the indexed ones."""

    def __init__(self, view: str, valid: Iterable[str]) -> None:
        super().__init__(f"unknown view {view!r}; valid views: {', '.join(valid)}")


class FilterSyntaxError(RetrievalError):
    """A filter that cannot be read or names an unknown field."""


class ModelMismatchError(RetrievalError):
    """The index was built by another model version than the one found in its run directory."""


class IndexDirError(RetrievalError):
    """An index directory is missing, incomplete, or of an unsupported format."""
