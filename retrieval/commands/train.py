"""``scenesearch train CLIPS_DIR --out RUN_DIR [--preset NAME | --config FILE] [--set KEY=VALUE ...]``.

Trains the dual text/video encoder contrastively on the 'train' split of a clips folder, validating
text → clip retrieval on 'val' after every epoch. What it trains is a recipe (:mod:`encoders.presets`):
``--preset recommended`` (the default, the model the documentation measures), ``--preset tiny``, or a
recipe file (``--config``); ``--set key=value`` overrides any key of it (``--set model.time_slots=0
--set model.text.kind=pretrained``, ``--set tagging.joint_weight=2``). The options below are the run's
own: data, output, schedule, seed, device, processes.

RUN_DIR receives recipe.yaml (the recipe resolved), config.json, metrics.jsonl, checkpoints/last.pt
(every epoch), model.safetensors, text_cache.npz and model_card.md. ``--resume`` continues from the
last checkpoint exactly (tagging head included), with the run's own recipe unless another is given; a
different configuration stops it unless ``--force``. The checkpoint is read as plain tensors and data
only: one that is not (a pickled object, a damaged file) is refused with an error naming it.

``--nproc N`` trains data-parallel on N processes of this machine, started by torch's elastic
launcher (gloo on CPU, NCCL on CUDA: one GPU each); ``--batch-size`` is then per process, and the
loss is that of the whole batch of N × batch size clips (:mod:`encoders.distributed`). Run under
``torchrun ... -m retrieval.cli train ...`` (one machine or several), the command joins the
launcher's process group instead. Data too small for N processes is refused before any starts.

Size-like values are checked against the upper bounds of the configs before anything is loaded, and
an error names the option or key; ``--nproc`` is at most :data:`MAX_PROCESSES`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from scenesearch_base.config import check_flag_bound, with_option

if TYPE_CHECKING:
    from encoders.presets import Recipe

#: Processes ``--nproc`` may start on one machine, at most.
MAX_PROCESSES = 256

HELP = "train the dual text/video encoder on a clips folder (a recipe: --preset, --config, --set)"

#: Run-level options: ``args`` attribute → the TrainConfig field it sets.
RUN_OPTIONS = ("epochs", "batch_size", "lr", "seed", "device", "num_workers")


def configure(parser: argparse.ArgumentParser) -> None:
    from encoders.presets import preset_names

    parser.add_argument("clips_dir", type=Path, metavar="CLIPS_DIR", help="clips folder (scenesearch clips)")
    parser.add_argument("--out", type=Path, required=True, help="run folder to write")
    recipe = parser.add_mutually_exclusive_group()
    recipe.add_argument("--preset", choices=preset_names(),
                        help="the recipe to train (default recommended: the model the documentation measures)")
    recipe.add_argument("--config", type=Path, metavar="FILE", help="a recipe file (the layout of a preset)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="settings",
                        help="override a key of the recipe (repeatable): epochs=3, model.time_slots=0, "
                             "tagging.joint_weight=2")
    parser.add_argument("--epochs", type=int)
    parser.add_argument("--batch-size", type=int, help="clips per step (per process with --nproc)")
    parser.add_argument("--lr", type=float, help="peak learning rate")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--device", help="auto, cpu or cuda[:i]")
    parser.add_argument("--num-workers", type=int, help="processes loading the clips beside the model's")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its last checkpoint (with its own recipe unless "
                             "--preset or --config is given)")
    parser.add_argument("--force", action="store_true", help="with --resume: accept a different configuration")
    parser.add_argument("--nproc", type=int, default=1, metavar="N",
                        help="train on N processes of this machine (data parallel; --batch-size is per process)")


def build_recipe(args: argparse.Namespace) -> Recipe:
    """The recipe the command trains: the preset, file or run's own, with ``--set`` and the run options."""
    import dataclasses

    from encoders.presets import preset, read_recipe, run_recipe, with_settings

    own = run_recipe(args.out) if args.resume and args.preset is None and args.config is None else None
    if args.config is not None:
        recipe = read_recipe(args.config)
    elif own is not None:
        recipe = own  # a resume continues the run's own recipe
    else:
        recipe = preset(args.preset or "recommended")
    recipe = with_settings(recipe, args.settings)
    train = recipe.train
    for name in RUN_OPTIONS:
        value = getattr(args, name)
        if value is not None:
            train = with_option(train, "--" + name.replace("_", "-"), **{name: value})
    return dataclasses.replace(recipe, train=train)


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

    config = build_recipe(args).train  # a bad option or setting is reported before the clips are read
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
    from encoders.presets import RECIPE_FILE
    from encoders.train import TrainingError, train

    recipe = build_recipe(args)
    try:
        # An error leaves the group at once: the other processes' collectives then fail instead of waiting.
        with process_group(recipe.train.device) as dp:
            # Recorded once the run has checked its configuration (and after every epoch): what a resume
            # of a killed run reads back.
            record = (lambda _epoch: recipe.to_yaml(args.out / RECIPE_FILE)) if dp.is_main else None
            result = train(args.clips_dir, args.out, recipe.train, resume=args.resume, force=args.force,
                           tagging=recipe.tagging, distributed=dp, on_epoch_end=record)
    except TrainingError as exc:
        if os.environ.get("RANK", "0") == "0":
            print(f"scenesearch train: error: {exc}", file=sys.stderr)
        return 2
    if not dp.is_main:
        return 0
    val = ", ".join(f"{k} {v:.3f}" for k, v in result.val.items() if k != "queries")
    print(f"trained {result.epochs} epochs ({result.steps} steps) → {result.run_dir}" + (f"; val {val}" if val else ""))
    return 0
