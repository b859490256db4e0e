"""``scenesearch train CLIPS_DIR --out RUN_DIR [--config train.yaml] [--resume [--force]] [--nproc N]``.

Trains the dual text/video encoder contrastively on the 'train' split of a clips folder, validating
text → clip retrieval on 'val' after every epoch. RUN_DIR receives config.json, metrics.jsonl,
checkpoints/last.pt (every epoch), model.safetensors, text_cache.npz and model_card.md. ``--resume``
continues from the last checkpoint exactly (tagging head included); with a different configuration it
stops unless ``--force``. The checkpoint is read as plain tensors and data only: one that is not (a
pickled object, a damaged file) is refused with an error naming it.

``--nproc N`` trains data-parallel on N processes of this machine, started by torch's elastic
launcher (gloo on CPU, NCCL on CUDA: one GPU each); ``--batch-size`` is then per process, and the
loss is that of the whole batch of N × batch size clips (:mod:`encoders.distributed`). Run under
``torchrun ... -m retrieval.cli train ...`` (one machine or several), the command joins the
launcher's process group instead. Data too small for N processes is refused before any starts.

Size-like flags are checked against the upper bounds of :class:`encoders.config.TrainConfig` (and of
the model's configs) before anything is loaded, and an error names the flag; ``--nproc`` is at most
:data:`MAX_PROCESSES`.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path
from typing import Any

from common.config import with_option
from encoders.config import DENSE_STREAMS, HardNegative

#: Processes ``--nproc`` may start on one machine, at most.
MAX_PROCESSES = 256

HELP = "train the dual text/video encoder on a clips folder (contrastive, multi-positive)"

#: Switches that turn one boolean of the model's config on: flag → (config part, field, what it does).
MODEL_SWITCHES: dict[str, tuple[str, str, str]] = {
    "--track-velocity": ("bev", "track_velocity", "give the track stream the object's velocity relative to the ego "
                         "and its range rates (what the dense heads read motion from)"),
    "--camera-mask-scale": ("camera", "mask_scale", "give the camera's temporal model the object's size in the "
                            "image on a log scale and its change"),
    "--camera-crop": ("camera", "object_crop", "give the camera tower the object's crop at full resolution and "
                      "where it lies in the image (needs clips rendered with crops)"),
    "--object-category": ("fusion", "object_category", "let the fused view read each clip's object category, "
                          "the track's label"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("clips_dir", type=Path, metavar="CLIPS_DIR", help="clips folder (scenesearch clips)")
    parser.add_argument("--out", type=Path, required=True, help="run folder to write")
    parser.add_argument("--config", type=Path, help="train.yaml (TrainConfig); flags below override it")
    parser.add_argument("--preset", choices=["default", "tiny"], help="start from a preset instead of the defaults")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its last checkpoint (with its config.json unless "
                        "--config or --preset is given)")
    parser.add_argument("--force", action="store_true", help="with --resume: accept a different configuration")
    parser.add_argument("--epochs", type=int)
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--lr", type=float)
    parser.add_argument("--seed", type=int)
    parser.add_argument("--device", help="auto, cpu or cuda[:i]")
    parser.add_argument("--num-workers", type=int)
    parser.add_argument("--max-steps-per-epoch", type=int, help="cap steps per epoch (smoke runs)")
    parser.add_argument("--text-model", help="sentence-transformers model name or local folder")
    parser.add_argument("--scratch-text", action="store_true", help="train a small text transformer from scratch")
    parser.add_argument("--time-reversal", type=float, metavar="P",
                        help="chance that a training clip plays backwards, captioned by its reversed tags")
    parser.add_argument("--camera-share", type=float, metavar="F",
                        help="when fewer training clips than F have a camera view, give every batch that share of "
                             "camera clips (drawn again as needed)")
    parser.add_argument("--time-slots", type=int, metavar="K",
                        help="K time slots in every embedding, read from the frames and from each sentence's steps "
                             "(model.time_slots with the slots text tower; 0: one pooled vector)")
    edits = [k.value for k in HardNegative]
    parser.add_argument("--hard-negatives", nargs="+", metavar="EDIT", choices=edits,
                        help=f"edits of each clip's steps whose captions join the batch as negatives "
                             f"({', '.join(edits)})")
    parser.add_argument("--order-weight", type=float, metavar="W",
                        help="weight of the pairwise order loss: each clip against its caption's steps reversed "
                             "(needs the reverse edit among the hard negatives)")
    parser.add_argument("--partial-weight", type=float, metavar="W",
                        help="weight of the partial-query loss: each clip's object sentence, and for some clips the "
                             "ego sentence, as queries of their own beside the whole captions (0: none)")
    parser.add_argument("--dense-weight", type=float, metavar="W",
                        help="weight of the per-frame rule-tag loss on the temporal streams' frame tokens (heads on "
                             "the track stream unless the config names model.dense_streams)")
    parser.add_argument("--dense-streams", nargs="+", metavar="STREAM", choices=list(DENSE_STREAMS),
                        help=f"temporal streams whose frame tokens carry the per-frame tag heads "
                             f"({', '.join(DENSE_STREAMS)}; model.dense_streams)")
    for flag, (part, field, what) in MODEL_SWITCHES.items():
        parser.add_argument(flag, action="store_true", help=f"{what} (model.{part}.{field})")
    parser.add_argument("--camera-ego", action="store_true",
                        help="give the camera's temporal model the ego's motion from the log's poses, as the BEV "
                             "tower reads it (model.camera.ego_features 6)")
    parser.add_argument("--camera-apart", action="store_true",
                        help="train the camera tower beside the shared space: its own view loss against captions "
                             "it does not move, no gradient through the fused view (camera_apart)")
    parser.add_argument("--track-rates", action=argparse.BooleanOptionalAction, default=None,
                        help="give the track stream the object's own speed, acceleration and yaw rate over ground "
                             "(model.bev.track_rates, on by default; what the rules read braking, standing and "
                             "turning from)")
    parser.add_argument("--shuffle-frames", action="store_true", help="bag-of-frames baseline: shuffle frames in time")
    parser.add_argument("--inputs", choices=["none", "map", "lidar", "both"],
                        help="BEV inputs the model sees (input ablation of the tagging evaluation; default both)")
    parser.add_argument("--tag-weight", type=float,
                        help="weight of the attribute-tagging loss joined to the contrastive loss (default 1). "
                             "Tagging trains when the clips hold tag targets (eval-tags --logs, or the demo)")
    parser.add_argument("--tag-presence-weight", type=float, metavar="W",
                        help="weight of the presence term of densities learned as presence (pedestrians) within "
                             "the tagging loss (TagTrainConfig.joint_presence_weight, default 5)")
    parser.add_argument("--save-config", type=Path, help="also write the effective config as YAML")
    parser.add_argument("--nproc", type=int, default=1, metavar="N",
                        help="train on N processes of this machine (data parallel; --batch-size is per process)")


def build_config(args: argparse.Namespace) -> Any:
    from encoders.config import DualEncoderConfig, TrainConfig

    if args.config is not None:
        if not args.config.is_file():
            raise FileNotFoundError(f"{args.config}: config file not found")
        config = TrainConfig.from_yaml(args.config)
    elif args.resume and args.preset is None and (args.out / "config.json").is_file():
        config = TrainConfig.from_json(args.out / "config.json")  # the run's own
    else:
        config = TrainConfig.preset(args.preset or "default")
    for name in ("epochs", "batch_size", "lr", "seed", "device", "num_workers", "max_steps_per_epoch",
                 "time_reversal", "camera_share"):
        value = getattr(args, name)
        if value is not None:
            config = with_option(config, "--" + name.replace("_", "-"), **{name: value})
    if args.shuffle_frames:
        config = dataclasses.replace(config, shuffle_frames=True)
    if args.camera_apart:
        config = dataclasses.replace(config, camera_apart=True)
    if args.hard_negatives is not None:
        config = dataclasses.replace(config, hard_negatives=tuple(args.hard_negatives))
    if args.order_weight is not None:
        config = dataclasses.replace(config, order_weight=args.order_weight)
    if args.partial_weight is not None:
        config = dataclasses.replace(config, partial_weight=args.partial_weight)
    if args.dense_streams is not None:
        config = dataclasses.replace(config, model=dataclasses.replace(config.model,
                                                                       dense_streams=tuple(args.dense_streams)))
    if args.dense_weight is not None:
        model = config.model
        if args.dense_weight > 0 and not model.dense_streams:
            model = dataclasses.replace(model, dense_streams=("track",) if model.bev.track_features else ("bev",))
        config = dataclasses.replace(config, model=model, dense_weight=args.dense_weight)
    text = config.model.text
    if args.text_model:
        text = dataclasses.replace(text, kind="pretrained", model=args.text_model)
    if args.scratch_text:
        text = dataclasses.replace(text, kind="scratch")
    model = dataclasses.replace(config.model, text=text)
    for flag, (part, field, _) in MODEL_SWITCHES.items():
        if getattr(args, flag[2:].replace("-", "_")):
            model = dataclasses.replace(model, **{part: dataclasses.replace(getattr(model, part), **{field: True})})
    if args.camera_ego:
        from encoders.camera import EGO_MOTION_SCALE

        model = dataclasses.replace(model, camera=dataclasses.replace(model.camera,
                                                                      ego_features=len(EGO_MOTION_SCALE)))
    if args.track_rates is not None:
        model = dataclasses.replace(model, bev=dataclasses.replace(model.bev, track_rates=args.track_rates))
    if args.time_slots is not None:
        check_flag_bound("--time-slots", args.time_slots, DualEncoderConfig.upper_bounds["time_slots"])
        # The slots live on both sides: the text tower lays each sentence's steps out in them.
        kind = "slots" if args.time_slots else ("pretrained" if text.kind == "slots" else text.kind)
        model = dataclasses.replace(model, time_slots=args.time_slots, text=dataclasses.replace(text, kind=kind))
    return dataclasses.replace(config, model=model)


def check_flag_bound(option: str, value: float, bound: float) -> None:
    """Refuse a flag's ``value`` above ``bound`` before anything is allocated for it, naming the flag."""
    if value > bound:
        raise ValueError(f"{option} {value}: above its upper bound {bound:g}")


def tagging_config(args: argparse.Namespace) -> Any:
    """The tagging part of training, from ``--inputs``, ``--tag-weight`` and ``--tag-presence-weight`` (None:
    the defaults)."""
    from encoders.tagging.config import TagTrainConfig

    if args.inputs is None and args.tag_weight is None and args.tag_presence_weight is None:
        return None
    overrides: dict[str, Any] = {}
    if args.inputs is not None:
        overrides["inputs"] = args.inputs
    if args.tag_weight is not None:
        if args.tag_weight < 0:
            raise ValueError(f"--tag-weight must be >= 0, got {args.tag_weight}")
        overrides["joint_weight"] = args.tag_weight
    config = dataclasses.replace(TagTrainConfig(), **overrides)
    if args.tag_presence_weight is not None:  # TagTrainConfig checks it
        config = with_option(config, "--tag-presence-weight", joint_presence_weight=args.tag_presence_weight)
    return config


def run(args: argparse.Namespace) -> int:
    if args.nproc < 1:
        raise ValueError(f"--nproc must be >= 1, got {args.nproc}")
    check_flag_bound("--nproc", args.nproc, MAX_PROCESSES)
    if args.nproc == 1:
        return _train(args)
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        raise ValueError("--nproc starts its own processes; under torchrun leave it out (torchrun sets the number)")
    from encoders.distributed import check_processes, launch
    from encoders.inference import open_split

    config = build_config(args)  # a bad flag is reported before the clips are read
    if not args.clips_dir.is_dir():
        raise FileNotFoundError(f"{args.clips_dir}: clips folder not found")
    n_train = len(open_split(args.clips_dir, "train"))  # type: ignore[arg-type]
    check_processes(n_train, config.batch_size, args.nproc, args.clips_dir)
    return int(launch(args.nproc, _worker, args))


def _worker(args: argparse.Namespace) -> int:
    """One of the ``--nproc`` processes: errors the command line would report are reported by rank 0."""
    from scenes.errors import ScenesError

    try:
        return _train(args)
    except (ScenesError, FileNotFoundError, FileExistsError, ValueError) as exc:
        if os.environ.get("RANK", "0") == "0":
            print(f"scenesearch train: error: {exc}", file=sys.stderr)
        return 2


def _train(args: argparse.Namespace) -> int:
    """Train in this process: alone, or as one of the processes of a launcher (``--nproc``, torchrun)."""
    from encoders.distributed import process_group
    from encoders.train import TrainingError, train

    config = build_config(args)
    try:
        # An error leaves the group at once: the other processes' collectives then fail instead of waiting.
        with process_group(config.device) as dp:
            if args.save_config and dp.is_main:
                config.to_yaml(args.save_config)
            result = train(args.clips_dir, args.out, config, resume=args.resume, force=args.force,
                           tagging=tagging_config(args), distributed=dp)
    except TrainingError as exc:
        if os.environ.get("RANK", "0") == "0":
            print(f"scenesearch train: error: {exc}", file=sys.stderr)
        return 2
    if not dp.is_main:
        return 0
    val = ", ".join(f"{k} {v:.3f}" for k, v in result.val.items() if k != "queries")
    print(f"trained {result.epochs} epochs ({result.steps} steps) → {result.run_dir}" + (f"; val {val}" if val else ""))
    return 0
