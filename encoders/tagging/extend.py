"""New attributes for a trained model (continual learning): train new rows of A on new labels.

>>> add_attributes("run", ["causes_ego_braking"], ego_brake_cause_targets, "run_plus", clips_dir="clips",
...                log_dirs=logs)

The backbone stays frozen by default, so E (and every existing attribute) is unchanged and only the
new rows of A and b are learned; with ``finetune_backbone`` the backbone is trained on the new labels
too (the old rows are kept, but E moves under them). The new targets are written beside the built-in
ones as ``CLIPS_DIR/logs/<log_id>/<stem>.npy`` and the extended model is a new run folder whose
head holds the old rows followed by the new ones.

The example attribute, ``causes_ego_braking`` (:func:`ego_brake_cause_targets`), marks the vehicle the
ego brakes for: in frames where the ego's behaviour label ``braking_for`` is set, the footprint of
its ``leader_id``.
"""

from __future__ import annotations

import dataclasses
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from encoders.clips.layout import TARGETS_STEM, grid_from_manifest, read_manifest, rendered_log_dir
from encoders.tagging.attributes import BEHAVIOR_ATTRIBUTES, Attribute, TagError
from encoders.tagging.config import TagTrainConfig
from encoders.tagging.head import TagHead, TagHeadConfig
from encoders.tagging.inference import BACKBONE_FILE, load_tagger
from encoders.tagging.rasterize import behavior_grid, box_values
from encoders.tagging.targets import open_targets, targets_reusable, write_targets
from encoders.tagging.training import TagTrainResult, save_tagging, train_tags
from scenes.bev import BevGrid
from scenes.log import Log
from scenes.tracks import DenseTracks

#: Computes new targets of one log: (log, grid, dense tracks) → (F, A_new, H, W).
TargetsFn = Callable[[Log, BevGrid, DenseTracks], NDArray[np.float32]]
CAUSES_EGO_BRAKING = "causes_ego_braking"


def ego_brake_cause_targets(log: Log, grid: BevGrid, dense: DenseTracks) -> NDArray[np.float32]:
    """(F, 1, H, W): 1 on the box of the vehicle the ego brakes for (ego ``braking_for`` and its ``leader_id``)."""
    beh = behavior_grid(log.log_dir, dense)
    k, f = dense.valid.shape
    col = BEHAVIOR_ATTRIBUTES.index(Attribute.BRAKING_FOR)
    cause = np.zeros((k, f, 1), np.float32)
    frames = np.flatnonzero(beh.ego_flags[:, col] & (beh.ego_leader_index >= 0))
    cause[beh.ego_leader_index[frames], frames, 0] = 1.0
    return box_values(grid, dense, np.ones(k, bool), np.arange(f, dtype=np.int64), cause)


def write_new_targets(clips_dir: Path | str, log_dirs: Sequence[Path | str], names: Sequence[str],
                      targets_fn: TargetsFn, stem: str, overwrite: bool = False) -> list[str]:
    """Write the new attributes' targets of every rendered log; returns the log ids written or reused."""
    clips = Path(clips_dir)
    grid = grid_from_manifest(read_manifest(clips))
    done = []
    for log_dir in log_dirs:
        log_id = Path(log_dir).name
        folder = rendered_log_dir(clips, log_id)
        if not folder.is_dir():
            continue
        if overwrite or not targets_reusable(clips, log_id, stem):
            log = Log.open(log_dir)
            t = targets_fn(log, grid, log.dense_tracks())
            if t.shape[1] != len(names):
                raise TagError(f"targets_fn gave {t.shape[1]} attributes for {list(names)}")
            write_targets(folder, t, names, stem)
        done.append(log_id)
    return done


@dataclass
class ExtendResult:
    """What :func:`add_attributes` did."""

    run_dir: Path
    attributes: tuple[str, ...]
    train: TagTrainResult


def add_attributes(
    run_dir: Path | str,
    new_attribute_names: Sequence[str],
    targets_fn: TargetsFn,
    out_run_dir: Path | str,
    clips_dir: Path | str,
    log_dirs: Sequence[Path | str],
    finetune_backbone: bool = False,
    config: TagTrainConfig | None = None,
    stem: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> ExtendResult:
    """Add attributes to a trained tagging model.

    Args:
        run_dir: the trained run.
        new_attribute_names: names not yet in the model (discrete attributes).
        targets_fn: their ground truth per log.
        out_run_dir: the extended run (a new folder; ``run_dir`` is left unchanged).
        clips_dir: the clips folder the logs are rendered in.
        log_dirs: the logs (to compute the new targets).
        finetune_backbone: train the backbone as well as the new rows.
        config: training options (default: the run's, with its steps).
        stem: file stem of the new targets (default ``bev_attributes_<first name>``).

    Raises:
        TagError: a name is already an attribute of the model or is given twice.
    """
    base = load_tagger(run_dir)
    names = tuple(str(n) for n in new_attribute_names)
    clash = [n for n in names if n in base.names]
    if clash or len(set(names)) != len(names) or not names:
        raise TagError(f"new attributes must be new and distinct: {list(names)} (model has {list(base.names)})")
    stem = stem or f"{TARGETS_STEM}_{names[0]}"
    write_new_targets(clips_dir, log_dirs, names, targets_fn, stem)
    out = Path(out_run_dir)
    # train_tags keeps the base model's tower, inputs and frame spacing (``init``).
    result = train_tags(clips_dir, out, dataclasses.replace(config or base.config, mode="alone"),
                        targets=lambda lid: open_targets(clips_dir, lid, stem), init=base,
                        train_backbone=finetune_backbone, progress=progress)
    trained = load_tagger(out)
    new_head = trained.head
    merged = TagHead(TagHeadConfig(attributes=base.names + names, embed_channels=base.head.config.embed_channels,
                                   kinds={**base.head.config.kinds, **{n: "discrete" for n in names}},
                                   scales={**base.head.config.scales, **new_head.config.scales},
                                   footprints={**(base.head.config.footprints or {}),
                                               **(new_head.config.footprints or {})}))
    with torch.no_grad():
        merged.attributes.copy_(torch.cat([base.head.attributes.detach().cpu(), new_head.attributes.detach().cpu()]))
        merged.bias.copy_(torch.cat([base.head.bias.detach().cpu(), new_head.bias.detach().cpu()]))
    backbone = trained.bev.cpu() if finetune_backbone else base.bev.cpu()
    meta = read_manifest(clips_dir)
    save_tagging(out, merged, trained.config, meta, backbone=backbone,
                 extra={"clips_dir": str(Path(clips_dir).resolve()), "extended_from": str(Path(run_dir).resolve()),
                        "new_attributes": list(names), "new_targets_stem": stem,
                        "finetune_backbone": finetune_backbone})
    if not finetune_backbone and (Path(run_dir) / BACKBONE_FILE).is_file():
        shutil.copyfile(Path(run_dir) / BACKBONE_FILE, out / BACKBONE_FILE)
    return ExtendResult(out, merged.names, result)
