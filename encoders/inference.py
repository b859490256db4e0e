"""Query-time use of a trained :class:`~encoders.model.DualEncoder`: load a run, embed clips and texts.

``load_model(run_dir)`` reads what :func:`encoders.train.train` wrote in a run folder (``config.json``,
``model.safetensors`` and, for a frozen pretrained text tower, ``text_cache.npz``). The ``embed_*``
functions return float32 L2-normalised embeddings, one (D,) row per clip or text, and leave the model
in the mode (train or eval) they found it in, so training validation can call them between steps.
:func:`resolve_device` turns a device name of the configs (``auto``, ``cpu``, ``cuda[:i]``) into a
torch device, for training and inference alike.

A model reads clips of one shape: the frames per clip, camera image and BEV raster of the clips it
was trained on. :func:`record_trained_clips` writes that shape into the run folder
(``trained_clips.json``, the :data:`CLIP_SHAPE_FIELDS` of the training clips' ``manifest.json``), and
:func:`check_clips_fit` refuses clips of another shape before any is embedded, naming the clips
manifest's field, its value and the model's; a run without that file is checked against what its
``config.json`` fixes (channel counts, the longest clip its temporal models take).
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset

from encoders.clips.layout import MANIFEST_FILE, read_manifest
from encoders.config import EMBED_BATCH_CLIPS, ConfigError, check_device_name
from encoders.data import AugmentConfig, ClipDataset, collate_clips
from encoders.dense import frame_tag_report
from encoders.metrics import caption_queries, text_to_clip_metrics
from encoders.model import DualEncoder
from encoders.sentence import evaluating, native_bfloat16
from encoders.text import TEXT_CACHE_FILE
from encoders.train_config import TrainConfig
from scenesearch_base.atomic import atomic_write_text

#: The run folder's record of the clips it was trained on (:func:`record_trained_clips`).
TRAINED_CLIPS_FILE = "trained_clips.json"
#: The fields of ``CLIPS_DIR/manifest.json`` that fix what a model reads (dotted: ``bev.height_px`` is
#: the ``height_px`` of its ``bev``): frames per clip, the camera image, the BEV raster's extent, cell,
#: size and channels.
CLIP_SHAPE_FIELDS = ("frames_per_clip", "camera.height_px", "camera.width_px", "camera.channels",
                     "bev.x_min_m", "bev.x_max_m", "bev.y_min_m", "bev.y_max_m", "bev.resolution_m",
                     "bev.height_px", "bev.width_px", "bev.lidar_channels", "bev.map_channels")


class ClipShapeError(ConfigError):
    """Clips of another shape than the clips a model was trained on."""


def clip_shape(manifest: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`CLIP_SHAPE_FIELDS` of a clips manifest, by dotted name (those it lacks are left out)."""
    shape: dict[str, Any] = {}
    for name in CLIP_SHAPE_FIELDS:
        value: Any = manifest
        for key in name.split("."):
            value = value.get(key) if isinstance(value, Mapping) else None
        if value is not None:
            shape[name] = value
    return shape


def record_trained_clips(run_dir: Path | str, clips_dir: Path | str) -> None:
    """Write ``RUN_DIR/trained_clips.json``: the training clips' folder and :func:`clip_shape`.

    Training calls it beside the model it writes, so that :func:`check_clips_fit` holds other clips
    to that shape. Clips without a manifest (datasets built in memory) record nothing.
    """
    if not (Path(clips_dir) / MANIFEST_FILE).is_file():
        return
    record = {"clips_dir": str(clips_dir), "shape": clip_shape(read_manifest(clips_dir))}
    atomic_write_text(Path(run_dir) / TRAINED_CLIPS_FILE, json.dumps(record, indent=2, sort_keys=True))


def check_clips_fit(run_dir: Path | str, clips_dir: Path | str) -> None:
    """Refuse clips whose shape the model of ``run_dir`` was not trained on, before any is embedded.

    The clips' :func:`clip_shape` is compared with the run's ``trained_clips.json`` field by field;
    whether or not the run has that file, the BEV and camera channel counts must be those of its
    ``config.json`` and ``frames_per_clip`` at most the longest clip its temporal models take.

    Raises:
        ClipShapeError: one line naming the clips manifest and each field that differs, with the
            clips' value and the model's (``clips/manifest.json, field 'frames_per_clip': 8, the
            model was trained on 12``).
        FileNotFoundError: the clips folder has no manifest.
    """
    run_dir, manifest_path = Path(run_dir), Path(clips_dir) / MANIFEST_FILE
    shape = clip_shape(read_manifest(clips_dir))
    problems: dict[str, str] = {}  # field → what differs, one entry per field
    record_path = run_dir / TRAINED_CLIPS_FILE
    if record_path.is_file():
        try:
            trained = dict(json.loads(record_path.read_text(encoding="utf-8"))["shape"])
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ClipShapeError(f"{record_path}: unreadable record of the training clips ({exc!r})") from None
        problems.update({name: f"{shape.get(name)!r}, the model was trained on {trained[name]!r}"
                         for name in CLIP_SHAPE_FIELDS if name in trained and shape.get(name) != trained[name]})
    config_path = run_dir / "config.json"
    if config_path.is_file():
        model = TrainConfig.from_json(config_path).model
        counts = {"bev.lidar_channels": ("bev.lidar_channels", model.bev.lidar_channels),
                  "bev.map_channels": ("bev.map_channels", model.bev.map_channels),
                  "camera.channels": ("camera.in_channels", model.camera.in_channels)}
        for name, (key, expected) in counts.items():
            value = shape.get(name)
            got = len(value) if isinstance(value, list) else value
            if got is not None and got != expected:
                problems.setdefault(name, f"{got} channels, the model reads {expected} ({config_path}, "
                                          f"field 'model.{key}')")
        tower, longest = min((("bev", model.bev.temporal.max_frames), ("camera", model.camera.temporal.max_frames)),
                             key=lambda pair: pair[1])
        frames = shape.get("frames_per_clip")
        if isinstance(frames, int) and frames > longest:
            problems.setdefault("frames_per_clip", f"{frames}, the model reads at most {longest} frames "
                                                   f"({config_path}, field 'model.{tower}.temporal.max_frames')")
    if problems:
        order = {name: i for i, name in enumerate(CLIP_SHAPE_FIELDS)}
        fields = "; ".join(f"field {name!r}: {problems[name]}" for name in sorted(problems, key=order.__getitem__))
        raise ClipShapeError(f"{manifest_path}, {fields} (make the clips as the run's training clips were, or "
                             "train a model on these)")


def resolve_device(name: str) -> torch.device:
    """``auto`` → ``cuda`` when available, else ``cpu``; ``cpu`` and ``cuda[:i]`` as named.

    Raises:
        ConfigError: ``name`` is none of those, or names a CUDA device that torch cannot use.
    """
    check_device_name(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"device {name!r} requested but torch.cuda.is_available() is False")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ConfigError(f"device {name!r} requested but only {torch.cuda.device_count()} CUDA devices exist")
    return device


def collate(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Items → a batch, by the dataset's :func:`encoders.data.collate_clips`."""
    return collate_clips(items)


def open_split(clips_dir: Path | str, split: str | None, augment: bool = False,
               seed: int = 0, augment_config: AugmentConfig | None = None) -> Dataset[dict[str, Any]]:
    """The clips of ``split`` (all when None) in ``clips_dir`` (an :class:`encoders.data.ClipDataset`)."""
    # uint8 views: a quarter of the bytes through the workers; the model converts them on its device.
    return ClipDataset(clips_dir, split=split, augment=augment, seed=seed, augment_config=augment_config,
                       as_uint8=True)


def shuffle_time(batch: dict[str, Any], generator: torch.Generator | None = None) -> dict[str, Any]:
    """The batch with each clip's frames in a random order (the same order across its tensors)."""
    out = dict(batch)
    b, t = batch["bev_lidar"].shape[:2]
    perms = torch.stack([torch.randperm(t, generator=generator) for _ in range(b)])  # (B, T)
    for key, value in batch.items():
        if isinstance(value, torch.Tensor) and value.ndim >= 2 and value.shape[:2] == (b, t):
            idx = perms.reshape(b, t, *([1] * (value.ndim - 2))).expand_as(value)
            out[key] = torch.gather(value, 1, idx)
    return out


def batches(dataset: Dataset[dict[str, Any]], batch_size: int, num_workers: int = 0,
            pin_memory: bool = False) -> Iterator[dict[str, Any]]:
    """The dataset's items in order, collated in batches of ``batch_size`` (in page-locked memory with
    ``pin_memory``, so that copies to a GPU overlap the next batch's loading)."""
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, num_workers=num_workers, collate_fn=collate,
                        pin_memory=pin_memory)
    yield from loader


def clip_autocast(device: torch.device) -> contextlib.AbstractContextManager[Any]:
    """Mixed precision for embedding batches of clips on ``device``: bfloat16 autocast on a GPU (float16
    where it has no bfloat16) and on a CPU that multiplies bfloat16 in hardware; float32 elsewhere.
    Embeddings stay within 1e-4 cosine of float32's (docs/research/ingest-profile.md). One clip at query
    time stays in float32: bfloat16's kernels are built on their first call in a process."""
    if device.type == "cuda":
        return torch.autocast("cuda", dtype=torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16)
    if device.type == "cpu" and native_bfloat16():
        return torch.autocast("cpu", dtype=torch.bfloat16)
    return contextlib.nullcontext()


@torch.no_grad()
def embed_dataset(
    model: DualEncoder,
    dataset: Dataset[dict[str, Any]],
    view: str = "fused",
    shuffle_frames: bool = False,
    batch_size: int = EMBED_BATCH_CLIPS,
    seed: int = 0,
) -> tuple[list[str], np.ndarray, list[str]]:
    """→ clip ids, (N, D) float32 normalised clip embeddings, canonical captions."""
    gen = torch.Generator().manual_seed(seed)
    ids: list[str] = []
    captions: list[str] = []
    chunks = []
    device = model.device
    with evaluating(model):
        for batch in batches(dataset, batch_size, pin_memory=device.type == "cuda"):
            if shuffle_frames:
                batch = shuffle_time(batch, gen)
            with clip_autocast(device):
                x = model.encode_video(batch, view=view, normalize=False)
            chunks.append(F.normalize(x.float(), dim=-1).cpu().numpy())  # normalised in float32
            ids += list(batch["clip_id"])
            captions += list(batch["canonical_caption"])
    d = model.config.embed_dim
    return ids, (np.concatenate(chunks) if chunks else np.zeros((0, d), np.float32)), captions


@torch.no_grad()
def embed_dataset_views(
    model: DualEncoder, dataset: Dataset[dict[str, Any]], batch_size: int = EMBED_BATCH_CLIPS, num_workers: int = 0
) -> tuple[list[str], dict[str, np.ndarray]]:
    """→ clip ids and, per view (camera, bev, fused), (N, D) float32 normalised embeddings, in one pass
    (the clips loaded in ``num_workers`` processes, 0: this one)."""
    ids: list[str] = []
    chunks: dict[str, list[np.ndarray]] = {}
    device = model.device
    with evaluating(model):
        for batch in batches(dataset, batch_size, num_workers, pin_memory=device.type == "cuda"):
            with clip_autocast(device):
                views = model.encode_views(batch, normalize=False)
            for view, x in views.items():  # normalised in float32: in bfloat16 the norm is off by about 1e-3
                chunks.setdefault(view, []).append(F.normalize(x.float(), dim=-1).cpu().numpy())
            ids += list(batch["clip_id"])
    d = model.config.embed_dim
    return ids, {v: np.concatenate(c) if c else np.zeros((0, d), np.float32) for v, c in chunks.items()}


@torch.no_grad()
def embed_texts(model: DualEncoder, texts: Sequence[str], batch_size: int = 256) -> np.ndarray:
    """texts: N strings → (N, D) float32 normalised embeddings."""
    with evaluating(model):
        out = [model.encode_text(list(texts[i : i + batch_size])).float().cpu().numpy()
               for i in range(0, len(texts), batch_size)]
    return np.concatenate(out) if out else np.zeros((0, model.config.embed_dim), np.float32)


def embed_clips(
    model: DualEncoder,
    clips_dir: Path | str | Dataset[dict[str, Any]],
    split: str | None = None,
    view: str = "fused",
    shuffle_frames: bool = False,
    batch_size: int = EMBED_BATCH_CLIPS,
) -> tuple[list[str], np.ndarray]:
    """Embed the clips of ``split`` (all when None) of a clips folder (or a dataset): → (ids, (N, D) float32)."""
    dataset = open_split(clips_dir, split) if isinstance(clips_dir, str | Path) else clips_dir
    ids, vectors, _ = embed_dataset(model, dataset, view=view, shuffle_frames=shuffle_frames, batch_size=batch_size)
    return ids, vectors


def evaluate(
    model: DualEncoder,
    dataset: Dataset[dict[str, Any]],
    view: str = "fused",
    shuffle_frames: bool = False,
    batch_size: int = EMBED_BATCH_CLIPS,
    min_steps: int = 1,
) -> dict[str, float]:
    """Text → clip retrieval on ``dataset``: queries are the unique canonical captions, relevant clips share it.

    ``min_steps`` keeps only queries whose tag sequence has at least that many steps.
    """
    _, vectors, captions = embed_dataset(model, dataset, view, shuffle_frames, batch_size)
    queries, relevant = caption_queries(captions)
    if min_steps > 1:
        tags_of: dict[str, int] = {}
        for i in range(len(dataset)):  # type: ignore[arg-type]
            item = dataset[i]
            tags_of[item["canonical_caption"]] = len(item["tags"])
        keep = [q for q, c in enumerate(queries) if tags_of.get(c, 0) >= min_steps]
        queries, relevant = [queries[q] for q in keep], relevant[keep]
    if not queries:
        return {"queries": 0.0}
    text = embed_texts(model, queries)  # (Q, D)
    return text_to_clip_metrics(text @ vectors.T, relevant)


@torch.no_grad()
def frame_tag_figures(model: DualEncoder, dataset: Dataset[dict[str, Any]],
                      batch_size: int = EMBED_BATCH_CLIPS) -> dict[str, Any]:
    """How well the dense heads read each frame's rule tags on ``dataset``: the figures of
    :func:`encoders.dense.frame_tag_report`. Empty without dense heads."""
    if not model.dense:
        return {}
    logits: dict[str, list[torch.Tensor]] = {}
    targets, has_camera = [], []
    with evaluating(model):
        for batch in batches(dataset, batch_size):
            frames: dict[str, torch.Tensor] = {}
            model.encode_views(batch, frames=frames)
            for name, x in model.dense_logits(frames).items():
                logits.setdefault(name, []).append(x.float().cpu())
            targets.append(torch.as_tensor(batch["frame_targets"]))
            has_camera.append(torch.as_tensor(batch["has_camera"], dtype=torch.bool).reshape(-1))
    if not targets:
        return {}
    return frame_tag_report({name: torch.cat(chunks) for name, chunks in logits.items()}, torch.cat(targets),
                            torch.cat(has_camera), model.config.dense_tasks)


def load_model(run_dir: Path | str, device: str = "cpu", text: bool = True) -> DualEncoder:
    """The trained DualEncoder of ``run_dir`` (config.json + model.safetensors), in eval mode, its 4-D
    weights (the convolutions') laid out channels-last for inference: call ``.contiguous()`` on its
    state before saving or broadcasting it.

    ``text=False``: without its text tower (:class:`encoders.text.UnloadedText`), for processes that
    embed clips only: the sentence encoder, most of the load's time, is not read.
    """
    from safetensors.torch import load_file

    run_dir = Path(run_dir)
    config_path, weights_path = run_dir / "config.json", run_dir / "model.safetensors"
    for path in (config_path, weights_path):
        if not path.exists():
            raise FileNotFoundError(f"{path}: not found (is {run_dir} a finished training run?)")
    model = DualEncoder(TrainConfig.from_json(config_path).model, text=text)
    model.load_saved_state_dict(load_file(str(weights_path)))
    if model.text.cache is not None:
        model.text.cache.load(run_dir / TEXT_CACHE_FILE)
    # Every 4-D weight (the convolutions') channels-last: oneDNN's bfloat16 kernels (and a GPU's
    # tensor cores) read that layout natively and reorder the default one on every call; the
    # convolutions' outputs come out channels-last too (docs/research/ingest-profile.md,
    # "Channels-last weights").
    model = model.to(resolve_device(device))
    model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # an overload torch's stubs omit
    return model.eval()
