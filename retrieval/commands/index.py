"""``scenesearch index``: embed every clip and its rule caption with a trained model; write an index directory.

With ``--workers N`` (a local Ray runtime) or ``--ray-address`` (a cluster) the clips are embedded on
Ray Data by a pool of actors, one model each (a GPU each when the cluster has them), written as
Parquet shards (``--embeddings-dir``, kept when given) and indexed from them; the embeddings equal
the serial ones (within 1e-4). ``--batch-size`` (at most :data:`MAX_BATCH_SIZE`) and ``--num-workers``
(at most :data:`MAX_NUM_WORKERS`) are checked before anything is loaded.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from encoders.config import EMBED_BATCH_CLIPS
from scenesearch_base.config import check_flag_bound
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_cluster import add_arguments as add_execution_arguments

if TYPE_CHECKING:
    from retrieval.scenesearch import SceneSearch

#: Clips embedded at a time (``--batch-size``) and loader processes (``--num-workers``), at most: as
#: :class:`encoders.train_config.TrainConfig` bounds them for training.
MAX_BATCH_SIZE = 4096
MAX_NUM_WORKERS = 256

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
    parser.add_argument("--device", default="auto",
                        help="where the model embeds the clips: auto (CUDA when available, the default), cpu or "
                             "cuda[:i]; with --workers/--ray-address each actor takes a GPU when the cluster has them")
    parser.add_argument("--batch-size", type=int, default=EMBED_BATCH_CLIPS, metavar="N",
                        help=f"clips embedded at a time (default {EMBED_BATCH_CLIPS})")
    parser.add_argument("--num-workers", type=int, default=0, metavar="N",
                        help="processes that load the clips beside the model's (default 0: the model's own); on a "
                             "GPU, loading is what limits the embedding")
    parser.add_argument("--hybrid-weight", type=float, metavar="W",
                        help="the weight of hybrid search recorded in the index, the rule captions' share in [0, 1] "
                             "(default: chosen on the clips' validation split, 0.5 without one)")
    add_execution_arguments(parser)
    parser.add_argument("--embeddings-dir", metavar="DIR",
                        help="with --workers/--ray-address: keep the embedding shards (Parquet, part-*.parquet, "
                             "replacing those of an earlier run) here, a path or a URI every node can write "
                             "(default: a temporary folder, removed afterwards)")


def check_sizes(args: argparse.Namespace) -> None:
    """Refuse a ``--batch-size`` or ``--num-workers`` out of range, naming the flag, before anything is loaded."""
    for option, value, low, high in (("--batch-size", args.batch_size, 1, MAX_BATCH_SIZE),
                                     ("--num-workers", args.num_workers, 0, MAX_NUM_WORKERS)):
        if value < low:
            raise ValueError(f"{option} {value}: must be at least {low}")
        check_flag_bound(option, value, high)


def run(args: argparse.Namespace) -> int:
    check_sizes(args)
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
        if args.hybrid_weight is not None:
            raise ValueError("--hybrid-weight goes with RUN_DIR CLIPS_DIR: a caption index has no model embeddings "
                             "to mix with")
        from retrieval.captions_search import CaptionSearch

        captions = CaptionSearch.build(args.captions, args.out)
        for skipped in captions.skipped[:20]:
            print(f"skipped {skipped.item}: {skipped.reason}")
        for log_id, reason in list(captions.scenarios_missing.items())[:20]:
            print(f"note: no scenario features for log {log_id}: {reason}")
        print(f"wrote {args.out}: {len(captions)} captions, {len(captions.texts)} distinct texts "
              f"({len(captions.skipped)} skipped"
              + (f", {len(captions.scenarios_missing)} log(s) without scenario features" if captions.scenarios_missing
                 else "") + ")")
        return 1 if captions.skipped or captions.scenarios_missing else 0
    if args.run_dir is None or args.clips_dir is None:
        raise ValueError("give RUN_DIR and CLIPS_DIR (a trained model and its clips), or --captions CAPTIONS_DIR")
    if args.hybrid_weight is not None:
        from retrieval.hybrid import check_weight

        check_weight(args.hybrid_weight)  # before anything is embedded

    execution = Execution.from_args(args)
    if not execution.on_ray:
        if args.embeddings_dir is not None:
            raise ValueError("--embeddings-dir goes with --workers N or --ray-address ADDR")
        from retrieval.embedding import ModelEmbedder

        embedder = ModelEmbedder(args.run_dir, batch_size=args.batch_size, device=args.device,
                                 num_workers=args.num_workers)
        search = SceneSearch.build(args.run_dir, args.clips_dir, args.out, embedder=embedder,
                                   progress=lambda m: print(m, flush=True), hybrid_weight=args.hybrid_weight)
    else:
        search = _build_on_ray(args, execution)
    for item in search.manifest.skipped[:20]:
        print(f"skipped {item['item']}: {item['reason']}")
    if len(search.manifest.skipped) > 20:
        print(f"... and {len(search.manifest.skipped) - 20} more skipped (listed in {args.out}/manifest.json)")
    counts = ", ".join(f"{k} {v}" for k, v in search.manifest.counts.items())
    print(f"wrote {args.out}: {counts}")
    return 1 if search.manifest.skipped else 0


def _build_on_ray(args: argparse.Namespace, execution: Execution) -> SceneSearch:
    from retrieval.embedding import RayDataEmbedder
    from retrieval.scenesearch import SceneSearch
    from scenesearch_base.ray_cluster import held_runtime

    scratch = None if args.embeddings_dir else Path(tempfile.mkdtemp(prefix="scenesearch-embeddings-"))
    shards = args.embeddings_dir or str(scratch)
    try:
        with held_runtime(execution):
            embedder = RayDataEmbedder(args.run_dir, execution, shards, batch_size=args.batch_size)
            search = SceneSearch.build(args.run_dir, args.clips_dir, args.out, embedder=embedder,
                                       progress=lambda m: print(m, flush=True), hybrid_weight=args.hybrid_weight)
        run = embedder.last_run
        print(f"embedded {run.get('clips', 0):.0f} clips on {run.get('actors', 0):.0f} Ray actor(s) "
              f"({'one GPU each' if run.get('gpus_per_actor') else 'CPU'}) in {run.get('seconds', 0.0):.1f} s; "
              f"{run.get('shards', 0):.0f} shard file(s){'' if scratch else f' in {shards}'}")
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    return search


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
