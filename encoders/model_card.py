"""The ``model_card.md`` of a training run: the model, the data it saw, its validation metrics and its limits;
``scenesearch eval --model-card`` adds a section of test figures beside their baselines (:func:`with_section`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from torch.utils.data import Dataset

from encoders.calibration import CameraWeightChoice
from encoders.clips.views import EGO_MOTION_COLUMNS
from encoders.train_config import TrainConfig


def model_card(config: TrainConfig, history: list[dict[str, Any]], n_train: int,
               val_set: Dataset[dict[str, Any]] | None, clips_dir: Path | str,
               camera_weight: CameraWeightChoice) -> str:
    """Markdown for ``run_dir/model_card.md``; ``history`` holds the rows of ``metrics.jsonl``;
    ``camera_weight``: the fusion's camera weight and how it was chosen."""
    last_val: dict[str, float] = next((r["val"] for r in reversed(history) if "val" in r), {})
    m = config.model
    metric_lines = "\n".join(f"| {k} | {v:.4g} |" for k, v in last_val.items()) or "| (no validation split) | |"
    text = {"pretrained": m.text.model,
            "slots": f"{m.text.model} over each sentence's steps in {m.time_slots} time slots of {m.slot_dim} dims"
                     + (", the whole text as the mean of its sentences" if m.text.whole_text == "sentences" else ""),
            }.get(m.text.kind, f"scratch transformer ({m.text.scratch_layers} layers)")
    frozen = ""
    if m.text.kind != "scratch" and m.text.freeze:
        from encoders.sentence import text_encoder_dtype

        dtype = str(text_encoder_dtype(m.text)).removeprefix("torch.")
        frozen = (f" (frozen below its top {m.text.finetune_top_layers} layers, {dtype})" if m.text.finetune_top_layers
                  else f" (frozen, cached; precision {m.text.precision}: {dtype} on the machine that trained it)")
    n_val = len(val_set) if val_set is not None else 0  # type: ignore[arg-type]
    track = ""
    if m.bev.track_features:
        extra = [name for name, on in (("velocity relative to the ego", m.bev.track_velocity),
                                       ("own speed, acceleration and yaw rate", m.bev.track_rates)) if on]
        track = (f";\n  the object's own track ({m.bev.track_features} features per frame"
                 f"{' + ' + ' and '.join(extra) if extra else ''}) through its own temporal transformer")
    ego = f"ego motion ({', '.join(EGO_MOTION_COLUMNS[: m.bev.ego_features]) or 'none'})"
    camera_reads = []
    if m.camera.ego_features:
        camera_reads.append(f"the ego motion ({', '.join(EGO_MOTION_COLUMNS[: m.camera.ego_features])})")
    if m.camera.mask_scale:
        camera_reads.append("the object's size on a log scale")
    if m.camera.object_crop:
        camera_reads.append("the object's crop at full resolution (a CNN of its own) with where it lies in the image")
    camera = (f"strided CNN {list(m.camera.widths)} over RGB + object mask, temporal transformer over frames"
              + (f" that also reads {' and '.join(camera_reads)}" if camera_reads else ""))
    slots = (f"\n- Video time slots: each temporal stream pools its frame tokens into {m.time_slots} stretches of the "
             f"clip, in order ({m.slot_dim} dims each)." if m.time_slots else "")
    dense = (f";\n  per-frame rule tags ({', '.join(m.dense_tasks)}) on the {', '.join(m.dense_streams)} "
             f"stream's frame tokens, weight {config.dense_weight:g}" if config.dense_weight > 0 else "")
    apart = ("\n- The camera tower trained apart: its own view loss against the captions' vectors, which it does not "
             "move, and no gradient through the fusion." if config.camera_apart else "")
    category = ""
    if m.fusion.object_category:
        withheld = f", withheld in training with p {m.fusion.category_drop_p:g}" if m.fusion.category_drop_p else ""
        category = f" that also reads the object's category (the track's label{withheld})"
    return f"""# DualEncoder model card

Text → clip and clip → clip retrieval of object behaviour in driving logs.

## Model
- Text tower: {text}{frozen}, projection to D = {m.embed_dim}.
- Camera tower: {camera}.
- BEV tower: LiDAR and map backbones {list(m.bev.widths)}, universal embedding E with D_e = {m.bev.embed_channels} at
  1/{m.bev.downsample} resolution, object-masked pooling, temporal transformer with {ego}{track}.{slots}
- Fusion: mean of normalised views + MLP{category}; modality dropout camera {m.fusion.drop_camera_p}, BEV
  {m.fusion.drop_bev_p}; {camera_weight.describe()}.{apart}

## Data
- Clips: `{clips_dir}`; {n_train} training clips, {n_val} validation clips.
- Supervision: rule-based canonical captions{" (paraphrases as augmentation)" if config.augment else ""};
  positives: equal canonical captions; loss: multi-positive InfoNCE;
  hard negatives (edited steps): {", ".join(config.hard_negatives) or "none"}{dense}.

## Training
- {len(history)} epochs, batch {config.batch_size}, AdamW lr {config.lr}, seed {config.seed}.

## Validation (text → clip, last evaluated epoch)
| metric | value |
|---|---|
{metric_lines}

## Limits
- Captions come from rules over LiDAR tracks: the model knows only the behaviours those rules name, and
  inherits their errors (tracking noise, lane assignment near junctions).
- Trained on the clips above only; simulated clips do not cover the look of real cameras.
- Clips without camera are embedded from BEV alone; camera-only queries are weaker where the object is small.
- Rare actions (lane changes, turns) are where the model is weakest: `scenesearch eval` reports them per facet
  (`by_facet`), and its temporal order, free-form queries and each half of a caption asked alone beside
  rule-caption search (`scenesearch search INDEX … --captions`), the reference where the model falls short;
  `scenesearch eval --model-card` writes those figures below.
"""


#: The file of a run that holds its model card.
MODEL_CARD_FILE = "model_card.md"


def with_section(card: str, heading: str, body: str) -> str:
    """``card`` (Markdown) with the level-2 section ``heading`` holding ``body``: in place of a section of
    that heading (up to the next level-2 heading), else at the end, so that evaluating again on the same
    clips and split replaces the figures rather than piling them up."""
    title = f"## {heading}"
    lines = card.rstrip("\n").split("\n")
    section = [title, "", *body.rstrip("\n").split("\n")]
    if title in lines:
        start = lines.index(title)
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        tail = ["", *lines[end:]] if end < len(lines) else []
        lines = [*lines[:start], *section, *tail]
    else:
        lines = [*lines, "", *section]
    return "\n".join(lines) + "\n"
