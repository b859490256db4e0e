"""The demo's sizes and seeds: :class:`DemoConfig`, every field a flag of ``scenesearch demo``."""

from __future__ import annotations

from dataclasses import dataclass

from scenes.sim.config import NetworkKind

DEFAULT_QUERIES = (
    "a car in the left lane approaches, then moves into the ego lane",
    "a pedestrian crossing approaches the ego vehicle",
    "a stopped car in the ego lane",
    "a car in the oncoming lane approaches, then moves away",
)
#: The report's scenario query: a relation between objects, answered by its program over tracks.
DEFAULT_SCENARIO_QUERY = "a bus with a car behind it"
#: Share of the demo's logs in the validation split.
VAL_FRACTION = 0.15
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
            the demo's split but not on the quality benchmark, for more training time, so 64 × 32
            (``docs/research/camera-resolution.md``).
        bev_resolution_m: cell size of the BEV view of clips (grid x ∈ [−20, 60] m, y ∈ [−20, 20] m).
        train_preset: the training recipe (:mod:`encoders.presets`): ``recommended``, the model the
            documentation measures; ``tiny`` for smoke runs.
        epochs: training epochs (None: the recipe's).
        batch_size: training batch size (None: the recipe's).
        sensors: render LiDAR and cameras (off: BEV clips from boxes, no camera).
        extra_logs: more simulated logs, from another seed, without sensors (BEV clips from boxes,
            no camera), that only ever train (``clips --train-only``): the cheapest data there is
            (quick to simulate and to cut into clips), and more data is what the model lacks most.
            They leave the validation and test splits as they were.
        val_logs: more simulated logs, from another seed, drawn as ``logs`` are (sensors, the same city),
            that only ever validate (``clips --val-only``). The hashed split gives the demo's logs one
            validation log; a tag that log never shows (a stopped vehicle behind, ``blocked_by``, a
            lane change) then takes its F1 threshold from training logs, where the model is sure of
            itself; four more logs leave few such cells and put the tagging head above the statistics
            on more attributes (``docs/research/validation-logs.md``). Four logs are one simulator run
            of its four egos. They leave the train and test splits as they were.
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
            mAP and cost temporal order (``docs/research/extra-networks.md``). A random log holds more
            clips than a grid log.
        queries: example queries shown and put in the report.
        scenario_query: the report's scenario query, shown with its program and the objects it selects.
        top_k: results shown per example query.
        workers: Ray workers of the per-log stages that take most of their time in one process: the
            simulation of the sensor logs and the clips (``--workers``; outputs are the same bytes as
            without). None: one per CPU core when Ray is installed and there is more than one core;
            0 or 1: serially. ``make bench`` (``scale``) times the clips on 2 workers against 1
            (``docs/research/demo-time.md``).
    """

    # Sized so that the whole demo runs in 9 to 15 minutes on 2 CPU cores: small clip views (quick to
    # train on), and the extra logs' clips with 6 epochs rather than 12 epochs of the 12 logs' clips
    # alone: more data beat more passes over the same clips (``docs/research/demo-config-history.md``).
    logs: int = 12
    duration_s: float = 20.0
    test_fraction: float = 0.25
    seed: int = 0
    frames_per_clip: int = 12
    camera_width_px: int = 64
    camera_height_px: int = 32
    bev_resolution_m: float = 1.25
    train_preset: str = "recommended"
    epochs: int | None = None
    batch_size: int | None = None
    sensors: bool = True
    extra_logs: int = 24
    val_logs: int = 4
    map_less_share: float = 0.5
    jitter_share: float = 0.5
    extra_networks: tuple[str, ...] = ("grid",)
    queries: tuple[str, ...] = DEFAULT_QUERIES
    scenario_query: str = DEFAULT_SCENARIO_QUERY
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
        if self.epochs is not None and self.epochs < 1:
            raise ValueError(f"DemoConfig.epochs must be at least 1, got {self.epochs}")
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

    @staticmethod
    def quick() -> DemoConfig:
        """Smallest sizes that still run every stage (a smoke run, not a measurement)."""
        return DemoConfig(logs=3, duration_s=12.0, frames_per_clip=8, epochs=1, train_preset="tiny", extra_logs=2,
                          val_logs=0)
