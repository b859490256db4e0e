"""The demo's sizes and seeds: :class:`DemoConfig`, every field a flag of ``scenesearch demo``."""

from __future__ import annotations

from dataclasses import dataclass

from encoders.config import DENSE_STREAMS, hard_negative_kinds, ordered_names
from scenes.sim.config import NetworkKind

DEFAULT_QUERIES = (
    "a car in the left lane approaches, then moves into the ego lane",
    "a pedestrian crossing approaches the ego vehicle",
    "a stopped car in the ego lane",
    "a car in the oncoming lane approaches, then moves away",
)
#: Share of the demo's logs in the validation split.
VAL_FRACTION = 0.15
#: The camera's training options: each a :class:`DemoConfig` field, a ``demo`` switch and a ``train`` flag
#: of the same name.
CAMERA_OPTIONS = ("camera_ego", "camera_mask_scale", "camera_apart", "camera_crop")


def option_flag(name: str) -> str:
    """The command-line switch of a :class:`DemoConfig` field, the same for ``demo`` and ``train``:
    ``camera_ego`` → ``--camera-ego``."""
    return "--" + name.replace("_", "-")


@dataclass(frozen=True)
class DemoConfig:
    """Sizes and seeds of the demo; every field is a flag of ``scenesearch demo``.

    Attributes:
        logs: simulated logs.
        duration_s: length of each log, seconds.
        test_fraction: share of the logs held out for the test split (validation: 0.15, beside the
            ``val_logs``; the rest trains). A quarter, so that the test split spans several logs and so several
            appearances (time of day, weather): the clip → clip appearance bias needs them.
        seed: seed of the simulation (and so of everything after it).
        frames_per_clip: T frames per clip.
        camera_width_px: width of the camera view of clips (height: ``camera_height_px``).
        camera_height_px: height of the camera view of clips. 128 × 64 lifted the camera view alone on
            the demo's split but not on the quality benchmark, for 1.1-1.3× the training time, so
            64 × 32 (README, "The camera at 128 × 64").
        bev_resolution_m: cell size of the BEV view of clips (grid x ∈ [−20, 60] m, y ∈ [−20, 20] m).
        epochs: training epochs (None: the trainer's default).
        batch_size: training batch size (None: the trainer's default).
        tag_weight: weight of the attribute-tagging loss joined to the contrastive loss (None: the
            trainer's default). Small, because with a few minutes of training a larger weight
            crowds out the contrastive objective.
        camera_share: share of camera clips in every training batch when fewer clips than that have a
            camera (``train --camera-share``; None: the trainer's default). The extra logs have no
            camera, so without it a batch of 16 holds one or two camera clips and the camera view
            alone learns little.
        time_slots: K time slots in every embedding (``train --time-slots``, :mod:`encoders.timeline`):
            the clip's stretches in order, so that retrieval reads what happens first and what after
            (0 or None: one pooled vector).
        hard_negatives: edits of each clip's steps whose captions train as extra negatives
            (``train --hard-negatives``; empty: in-batch negatives only). With the slots, the caption
            with its steps reversed is what teaches them order.
        order_weight: weight of the pairwise order loss, each clip against its caption's steps reversed
            (``train --order-weight``; needs ``reverse`` among ``hard_negatives``; 0 or None: none).
            At 0.3 order rose at every training seed, on the demo's split and on the real logs, for a
            little R@1 and mAP (README, "Order loss").
        partial_weight: weight of the partial-query loss, each caption's halves (the object's sentence,
            the ego's) as queries of their own beside the whole captions (``train --partial-weight``; 0 or
            None: none). Typed queries are mostly one half ("a stopped car in the ego lane"): at 0.5 the
            clips of an object sentence alone were found with mAP 0.68 / 0.65 instead of 0.51 / 0.51 at
            training seeds 0 / 1, whole captions as well as before, for a little tagging skill (README,
            "Partial queries").
        dense_weight: weight of the per-frame rule-tag loss on the frame tokens of ``dense_streams``
            (``train --dense-weight``; 0 or None: no dense heads). The tags of every frame make the
            tokens that the slots pool carry the motion, not only the clip's one caption; at 1 the
            contrastive loss outweighs them and the track stream reads its frames' tags worse than its
            inputs allow; at 5 it reads its frames' motion as well as a model trained on the tags
            alone (README, "Dense weight and the rules' relative velocity"), hence 5.
        dense_streams: the temporal streams whose frame tokens carry those heads (``train
            --dense-streams``): on the camera stream too, the camera tower alone learns the motion
            that its one contrastive target hardly teaches it.
        track_velocity: give the track stream the object's velocity relative to the ego
            (``train --track-velocity``): what the dense heads read the motion from.
        camera_ego: give the camera's temporal model the ego's motion from the log's poses
            (``train --camera-ego``): every caption opens with it, and 64 × 32 pixels barely show it.
        camera_mask_scale: give the camera's temporal model the object's size in the image on a log
            scale and its change (``train --camera-mask-scale``).
        camera_apart: train the camera tower beside the shared space (``train --camera-apart``,
            :attr:`encoders.config.TrainConfig.camera_apart`). With the two inputs alone, camera-only
            R@5 passed 0.5 but the BEV view lost recall on the quality benchmark (0.816 → 0.781) and
            the real logs (0.533 → 0.511); apart, the BEV view keeps its recall (README, "The camera
            trained apart").
        camera_crop: give the camera tower each object's crop at full resolution
            (``train --camera-crop``, :mod:`encoders.clips.crops`): at 64 × 32 half the test objects
            cover under a pixel; with the crop, camera-only R@5 rose from 0.43-0.54 to 0.58-0.68 over
            eight trainings, and on the quality benchmark from 0.38 to 0.51 (README, "Object crops for the
            camera").
        object_category: let the fused view read each clip's object category, the track's label
            (``train --object-category``, :attr:`encoders.config.FusionConfig.object_category`): on the
            real logs the misses were mostly the object's category (a standing pedestrian against a
            bollard), and with it R@5 there rose from 0.564 to 0.618 (README, "The object's category").
        train_preset: the trainer's preset (``default``; ``tiny`` for smoke runs), None for the trainer's choice.
        sensors: render LiDAR and cameras (off: BEV clips from boxes, no camera).
        extra_logs: more simulated logs, from another seed, without sensors (BEV clips from boxes,
            no camera), that only ever train (``clips --train-only``): the cheapest data there is
            (24 logs: seconds to simulate, half a minute to cut into clips), and more data is what
            the model lacks most. They leave the validation and test splits as they were.
        val_logs: more simulated logs, from another seed, drawn as ``logs`` are (sensors, the same city),
            that only ever validate (``clips --val-only``). The hashed split gives the demo's logs one
            validation log; a tag that log never shows (a stopped vehicle behind, ``blocked_by``, a
            lane change) then takes its F1 threshold from training logs, where the model is sure of
            itself (27 of the 72 F1 cells at seed 0; 2 with the four logs, and the tagging head above
            the statistics on 12 of 14 attributes instead of 10: README, "Validation logs"). Four
            logs are one simulator run of its four egos. They leave the train and test splits as they
            were.
        map_less_share: share of the extra logs written without their map
            (:attr:`scenes.sim.SimulationConfig.map_less_share`), as track-only real logs come.
        jitter_share: share of the extra logs whose boxes scatter from frame to frame as real labels
            do (:attr:`scenes.sim.SimulationConfig.jitter_share`), so that a standing object whose
            boxes wobble still reads as standing.
        extra_networks: road networks of the extra logs (:class:`scenes.sim.NetworkKind` values), which
            share them evenly (the first ones take any remainder), each in a folder of its own under
            ``extra_logs/``. The grid alone by default: its roads meet at right angles, so that
            beside its egos almost no object heads 30-60 or 120-150 degrees off the ego, as on real
            streets many do; ``("grid", "random")`` adds those headings, which on the real logs bought
            mAP and cost temporal order (README, "Extra logs on two road networks"). A random log
            holds about 1.7 times the clips of a grid log.
        queries: example queries shown and put in the report.
        top_k: results shown per example query.
        workers: Ray workers of the per-log stages that take most of their time in one process: the
            simulation of the sensor logs and the clips (``--workers``; outputs are the same bytes as
            without). None: one per CPU core when Ray is installed and there is more than one core;
            0 or 1: serially. ``make bench`` (``scale``): clips 1.75× on 2 workers against 1 (README, "Time").
    """

    # Sized so that the whole demo runs in 9 to 15 minutes on 2 CPU cores: small clip views (the model
    # trains at about 32 clips/s on them), and the extra logs' clips with 6 epochs rather than 12
    # epochs of the 12 logs' clips alone: more data beat more passes over the same clips.
    logs: int = 12
    duration_s: float = 20.0
    test_fraction: float = 0.25
    seed: int = 0
    frames_per_clip: int = 12
    camera_width_px: int = 64
    camera_height_px: int = 32
    bev_resolution_m: float = 1.25
    epochs: int | None = 6
    batch_size: int | None = 16
    tag_weight: float | None = 1.0
    camera_share: float | None = 0.25
    time_slots: int | None = 4
    hard_negatives: tuple[str, ...] = ("reverse",)
    order_weight: float | None = 0.3
    partial_weight: float | None = 0.5
    dense_weight: float | None = 5.0
    dense_streams: tuple[str, ...] = ("camera", "track")
    track_velocity: bool = True
    camera_ego: bool = True
    camera_mask_scale: bool = True
    camera_apart: bool = True
    camera_crop: bool = True
    object_category: bool = True
    train_preset: str | None = None
    sensors: bool = True
    extra_logs: int = 24
    val_logs: int = 4
    map_less_share: float = 0.5
    jitter_share: float = 0.5
    extra_networks: tuple[str, ...] = ("grid",)
    queries: tuple[str, ...] = DEFAULT_QUERIES
    top_k: int = 3
    workers: int | None = None

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"DemoConfig.workers must be at least 0, got {self.workers}")
        for name in ("logs", "frames_per_clip", "top_k"):
            if getattr(self, name) < 1:
                raise ValueError(f"DemoConfig.{name} must be at least 1, got {getattr(self, name)}")
        if self.duration_s <= 0:
            raise ValueError(f"DemoConfig.duration_s must be positive, got {self.duration_s}")
        if not 0 < self.test_fraction < 1 - VAL_FRACTION:
            raise ValueError(
                f"DemoConfig.test_fraction must lie in (0, {1 - VAL_FRACTION:g}), got {self.test_fraction}")
        for name in ("extra_logs", "val_logs"):
            if getattr(self, name) < 0:
                raise ValueError(f"DemoConfig.{name} must be at least 0, got {getattr(self, name)}")
        for name, share in (("map_less_share", self.map_less_share), ("jitter_share", self.jitter_share)):
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"DemoConfig.{name} must lie in [0, 1], got {share}")
        if self.camera_share is not None and not 0.0 <= self.camera_share <= 1.0:
            raise ValueError(f"DemoConfig.camera_share must lie in [0, 1], got {self.camera_share}")
        if self.epochs is not None and self.epochs < 1:
            raise ValueError(f"DemoConfig.epochs must be at least 1, got {self.epochs}")
        if self.time_slots is not None and self.time_slots < 0:
            raise ValueError(f"DemoConfig.time_slots must be at least 0, got {self.time_slots}")
        for name in ("dense_weight", "order_weight", "partial_weight"):
            if (getattr(self, name) or 0.0) < 0:
                raise ValueError(f"DemoConfig.{name} must be at least 0, got {getattr(self, name)}")
        if not self.extra_networks or len(set(self.extra_networks)) != len(self.extra_networks):
            raise ValueError(f"DemoConfig.extra_networks must name one or more distinct layouts, got "
                             f"{list(self.extra_networks)}")
        try:
            for network in self.extra_networks:
                NetworkKind.parse(network)
        except ValueError as exc:
            raise ValueError(f"DemoConfig.extra_networks: {exc}") from None
        # Refused here, before the stages run, rather than by `train` half way through the demo.
        hard_negative_kinds(self.hard_negatives, "DemoConfig.hard_negatives")
        if self.order_weight and "reverse" not in self.hard_negatives:
            raise ValueError("DemoConfig.order_weight needs 'reverse' among hard_negatives")
        ordered_names(self.dense_streams, "DemoConfig.dense_streams", DENSE_STREAMS)

    @staticmethod
    def quick() -> DemoConfig:
        """Smallest sizes that still run every stage (a smoke run, not a measurement)."""
        # The tiny model's 32 dimensions hold no time slots, and its scratch text tower no steps.
        return DemoConfig(logs=3, duration_s=12.0, frames_per_clip=8, epochs=1, train_preset="tiny", batch_size=None,
                          extra_logs=2, val_logs=0, time_slots=None, hard_negatives=(), order_weight=None,
                          partial_weight=None, dense_weight=None, track_velocity=False)
