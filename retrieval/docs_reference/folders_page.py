"""``docs/reference/folders.md``: each folder kind scenesearch writes, its marker, files and columns.

The text comes from the docstrings of the modules that own each folder, the file names from their
:class:`scenesearch_base.folders.FolderKind`, the columns from the Arrow schemas the writers use.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from retrieval.docs_reference.markdown import GENERATED, code, page, rst_to_markdown, table

#: (title, module owning the folder, its FolderKind's name there, written by, modules whose docstrings
#: describe it, (schema title, module, attribute) column tables).
FOLDERS: tuple[tuple[str, str, str, str, tuple[str, ...], tuple[tuple[str, str, str], ...]], ...] = (
    ("Logs (Argoverse 2 sensor layout)", "scenes.av2_io", "LOG_FOLDER",
     "`simulate`, `import kitti`, `import womd`, `track`; real AV2 logs as they come",
     ("scenes.av2_io", "scenes.schema"),
     (("annotations.feather", "scenes.schema", "ANNOTATION_COLUMNS"),
      ("annotations.feather, optional", "scenes.schema", "OPTIONAL_ANNOTATION_COLUMNS"),
      ("city_SE3_egovehicle.feather", "scenes.schema", "POSE_COLUMNS"),
      ("calibration/egovehicle_SE3_sensor.feather", "scenes.schema", "EXTRINSICS_COLUMNS"),
      ("calibration/intrinsics.feather", "scenes.schema", "INTRINSICS_COLUMNS"),
      ("sensors/lidar/<timestamp_ns>.feather", "scenes.schema", "LIDAR_COLUMNS"))),
    ("Captions", "captioning.outputs", "CAPTIONS_FOLDER", "`caption`", ("captioning.outputs", "captioning.pipeline"),
     (("frame_tags.parquet", "captioning.tables", "FRAME_TAGS_BEHAVIOR_SCHEMA"),
      ("captions.parquet", "captioning.tables", "CAPTIONS_BEHAVIOR_SCHEMA"))),
    ("Clips", "encoders.clips.layout", "CLIPS_FOLDER", "`clips`", ("encoders.clips.layout",),
     (("clips.parquet", "encoders.clips.table", "CLIP_SCHEMA"),)),
    ("Training run", "encoders.run_folder", "RUN_FOLDER", "`train`", ("encoders.run_folder",), ()),
    ("Index", "retrieval.index_folder", "INDEX_FOLDER", "`index`",
     ("retrieval.index_folder", "retrieval.scenesearch"), ()),
    ("Demo", "retrieval.demo", "DEMO_FOLDER", "`demo`", ("retrieval.demo",), ()),
    ("Scenario features", "scenarios.cache", "FEATURES_FOLDER", "`mine --cache`, `index`", ("scenarios.cache",), ()),
    ("Tag report", "encoders.tagging.evaluate", "TAG_REPORT_FOLDER", "`eval-tags`", (), ()),
)


def _columns(schema: Any) -> list[list[str]]:
    if isinstance(schema, dict):  # scenes.schema: column → type family
        return [[code(name), kind] for name, kind in schema.items()]
    return [[code(f.name), str(f.type) + ("" if f.nullable else ", not null")] for f in schema]


def _doc(module_name: str) -> list[str]:
    doc = inspect.getdoc(importlib.import_module(module_name)) or ""
    return [*rst_to_markdown(doc), ""] if doc else []


def markdown() -> str:
    """The page (Markdown)."""
    from scenesearch_base import folders

    lines = ["# Folder formats", "", GENERATED, ""]
    kinds = []
    for title, module_name, attribute, writers, _, _ in FOLDERS:
        kind = getattr(importlib.import_module(module_name), attribute)
        kinds.append([f"[{title}](#{title.lower().replace(' ', '-').replace('(', '').replace(')', '')})",
                      code(kind.name), writers, code(kind.signature) if kind.signature else "",
                      ", ".join(code(e) for e in kind.entries)])
    header = ["folder", "kind in its marker", "written by", "signature file", "entries its writers make"]
    lines += [*table(header, kinds), ""]
    lines += [f"## Markers: `{folders.MARKER_FILE}`", "", *_doc("scenesearch_base.folders")]
    for title, _, _, _, docs, schemas in FOLDERS:
        lines += [f"## {title}", ""]
        for module_name in docs:
            lines += _doc(module_name)
        for file_name, module_name, attribute in schemas:
            schema = getattr(importlib.import_module(module_name), attribute)
            lines += [f"Columns of `{file_name}` (`{module_name}.{attribute}`):", ""]
            lines += [*table(["column", "type"], _columns(schema)), ""]
    return page(lines)
