"""``scenesearch export``: clip metadata and embeddings for use elsewhere."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "export clip metadata and embeddings (.parquet with embedding columns, or .npy + .json)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index_dir", type=Path, metavar="INDEX_DIR", help="index directory (`scenesearch index`)")
    parser.add_argument("--out", type=Path, required=True, metavar="FILE",
                        help="FILE.parquet (metadata + one embedding column per view) or FILE.npy (+ FILE.json)")
    parser.add_argument("--view", action="append", choices=["fused", "camera", "bev"], dest="views",
                        help="views to export (repeatable; default all for Parquet, fused for .npy)")


def run(args: argparse.Namespace) -> int:
    from retrieval.scenesearch import SceneSearch
    from scenesearch_base.atomic import check_output_file
    from scenesearch_base.folders import check_inputs

    check_output_file(args.out)  # before the work that would fill it
    check_inputs(args.out, [args.index_dir])  # a file written inside the index would break it

    views = tuple(args.views) if args.views else None
    if views is None and args.out.suffix == ".npy":
        views = ("fused",)
    if args.out.suffix == ".npy" and views is not None and len(views) > 1:
        raise ValueError(f"--out {args.out}: a .npy file holds one view; export {', '.join(views)} to .parquet, "
                         "or one view per .npy file")
    if args.out.suffix not in (".parquet", ".npy"):
        raise ValueError(f"{args.out}: unknown export format {args.out.suffix!r}; use .parquet or .npy")
    # Neither the model nor the rule captions are exported: the caption index is never read.
    search = SceneSearch.open(args.index_dir, views=views or ("fused", "camera", "bev"), lazy_captions=True,
                              mmap=True)
    path = search.export(args.out, views=views)
    extra = f" and {path.with_suffix('.json')}" if path.suffix == ".npy" else ""
    print(f"wrote {path}{extra}: {len(search)} clips, views {', '.join(views or tuple(search.views))}")
    return 0
