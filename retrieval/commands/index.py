"""``scenesearch index``: embed every clip and its rule caption with a trained model; write an index directory."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = ("embed all clips (fused, camera-only, BEV-only) and their captions with a trained model; write an index "
        "(or, with --captions, index rule captions alone: no model or sensors needed; or, with --check, "
        "verify every file of an index)")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, nargs="?", metavar="RUN_DIR",
                        help="training run (model.safetensors, config.json)")
    parser.add_argument("clips_dir", type=Path, nargs="?", metavar="CLIPS_DIR",
                        help="clips directory (clips.parquet, logs/)")
    parser.add_argument("--captions", type=Path, metavar="CAPTIONS_DIR",
                        help="instead: index the rule captions of `scenesearch caption` (tracks only, any log)")
    parser.add_argument("--out", type=Path, metavar="INDEX_DIR", help="index directory to write")
    parser.add_argument("--check", type=Path, metavar="INDEX_DIR",
                        help="instead: hash every file of an index and compare with its manifests (ignores the "
                             "record of files verified before, so it also finds corruption that changed no file "
                             "time); exit status 2 and the file named when one differs")


def run(args: argparse.Namespace) -> int:
    from retrieval.scenesearch import SceneSearch

    if args.check is not None:
        if args.run_dir is not None or args.clips_dir is not None or args.captions is not None or args.out is not None:
            raise ValueError("--check INDEX_DIR takes no other arguments")
        return _check(args.check)
    if args.out is None:
        raise ValueError("give --out INDEX_DIR, the index directory to write")
    if args.captions is not None:
        if args.run_dir is not None or args.clips_dir is not None:
            raise ValueError("give either RUN_DIR CLIPS_DIR or --captions CAPTIONS_DIR, not both")
        from retrieval.captions_search import CaptionSearch

        captions = CaptionSearch.build(args.captions, args.out)
        for skipped in captions.skipped[:20]:
            print(f"skipped {skipped.item}: {skipped.reason}")
        print(f"wrote {args.out}: {len(captions)} captions, {len(captions.texts)} distinct texts "
              f"({len(captions.skipped)} skipped)")
        return 0
    if args.run_dir is None or args.clips_dir is None:
        raise ValueError("give RUN_DIR and CLIPS_DIR (a trained model and its clips), or --captions CAPTIONS_DIR")

    search = SceneSearch.build(args.run_dir, args.clips_dir, args.out, progress=lambda m: print(m, flush=True))
    for item in search.manifest.skipped[:20]:
        print(f"skipped {item['item']}: {item['reason']}")
    if len(search.manifest.skipped) > 20:
        print(f"... and {len(search.manifest.skipped) - 20} more skipped (listed in {args.out}/manifest.json)")
    counts = ", ".join(f"{k} {v}" for k, v in search.manifest.counts.items())
    print(f"wrote {args.out}: {counts}")
    return 0


def _check(index_dir: Path) -> int:
    from retrieval.captions_search import CaptionSearch, is_caption_index
    from retrieval.scenesearch import SceneSearch

    if is_caption_index(index_dir):
        captions = CaptionSearch.open(index_dir, verify="full")
        print(f"{index_dir}: every file matches its checksum (caption index, {len(captions)} captions)")
        return 0
    search = SceneSearch.open(index_dir, verify="full")
    print(f"{index_dir}: every file matches its checksum (views {', '.join(search.views)}, {len(search)} clips, "
          f"{len(search.captions)} captions)")
    return 0
