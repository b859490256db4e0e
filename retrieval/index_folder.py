"""The folder kind of an index written by ``scenesearch index``: a model index or a caption index.

Both kinds of index live in a folder of kind ``index`` (:mod:`scenesearch_base.folders`), so either replaces the
other at the same ``--out``, and neither ever replaces clips, captions, a run or a user's folder.
"""

from __future__ import annotations

from indexes.integrity import STAMP_NAME
from scenesearch_base.folders import FolderKind

INDEX_FOLDER = FolderKind(
    "index", signature="manifest.json",
    entries=("manifest.json", "fused", "camera", "bev", "captions", "run", "*.parquet", "*.npy", STAMP_NAME),
)
