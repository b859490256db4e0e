"""``IndexManifest``: what ``INDEX_DIR/manifest.json`` of a :class:`retrieval.scenesearch.SceneSearch` index
holds, read and checked."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from indexes.errors import IndexesError
from indexes.integrity import parse_file_entries
from indexes.persistence import read_json_manifest
from retrieval.errors import IndexDirError
from retrieval.hybrid import InvalidWeightError, WeightChoice
from retrieval.index_folder import INDEX_FOLDER

#: The layout version: the manifest holds checksums (``files``, ``content_sha256``). Other versions are refused.
FORMAT_VERSION = 2
KIND = "scenesearch_index"
MANIFEST = "manifest.json"


@dataclass(frozen=True)
class IndexManifest:
    """Contents of ``INDEX_DIR/manifest.json``.

    Attributes:
        format_version: layout version; other ones are refused.
        kind: always ``scenesearch_index``.
        model_sha256: SHA-256 of the ``model.safetensors`` the clip and text embeddings came from.
        run_dir: absolute path of the training run (its model encodes text queries).
        clips_dir: absolute path of the clips directory (previews are relative to it).
        embed_dim: dimension of the clip embeddings.
        views: the indexed views (subdirectories).
        counts: clips per view, captions, and clips per split.
        text_encoder: the sentence encoder of the caption index.
        created: UTC time of the build, ISO 8601.
        skipped: clips left out, with the reason.
        files: size and SHA-256 of ``<view>/manifest.json``, ``captions/manifest.json`` and
            ``run/config.json`` (each sub-manifest in turn covers its own files).
        hybrid: the weight of hybrid search and how it was chosen (:class:`retrieval.hybrid.WeightChoice`).
        scenarios: the logs whose scenario features the index holds, and those it lacks with the reason
            (:func:`retrieval.scenario_search.build_store`).
    """

    format_version: int
    kind: str
    model_sha256: str
    run_dir: str
    clips_dir: str
    embed_dim: int
    views: list[str]
    counts: dict[str, int]
    text_encoder: str
    created: str
    skipped: list[dict[str, str]] = field(default_factory=list)
    files: dict[str, dict[str, Any]] = field(default_factory=dict)
    hybrid: dict[str, Any] = field(default_factory=dict)
    scenarios: dict[str, Any] = field(default_factory=dict)

    @staticmethod
    def read(index_dir: Path) -> IndexManifest:
        path = index_dir / MANIFEST
        if not index_dir.is_dir():
            raise IndexDirError(f"{index_dir}: no index directory here (build one with `scenesearch index`)")
        if not path.is_file():
            raise IndexDirError(f"{path}: missing; {index_dir} is not a scenesearch index (or its build never "
                                "finished)")
        _refuse_other_kind(index_dir)
        try:
            raw = read_json_manifest(path, KIND, FORMAT_VERSION)
            parse_file_entries(raw.get("files"), path)
        except IndexesError as exc:
            raise IndexDirError(str(exc)) from exc
        names = {f for f in IndexManifest.__dataclass_fields__}
        missing = sorted(n for n in names if n not in raw and n not in ("skipped", "files", "scenarios"))
        if missing:
            raise IndexDirError(f"{path}: missing fields {missing}")
        try:
            WeightChoice.from_json(raw.get("hybrid"))
        except (InvalidWeightError, ValueError) as exc:
            raise IndexDirError(f"{path}, field 'hybrid': {exc}") from None
        return IndexManifest(**{k: v for k, v in raw.items() if k in names})


def _refuse_other_kind(index_dir: Path) -> None:
    """A folder whose marker says it is another of scenesearch's outputs (a clips folder also holds a
    ``manifest.json``): said as such, rather than as an index of an older format."""
    from scenesearch_base.folders import FolderClaimError, read_marker

    try:
        marker = read_marker(index_dir)
    except FolderClaimError:
        return  # the manifest's own checks speak
    if marker is not None and marker.kind != INDEX_FOLDER.name:
        raise IndexDirError(f"{index_dir}: a {marker.kind} folder, not an index (build one from it with "
                            "`scenesearch index RUN_DIR CLIPS_DIR --out INDEX`)")

