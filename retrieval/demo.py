"""The end-to-end demo: simulate → caption → clips → train → index → evaluate → report.

Each stage runs one ``scenesearch`` command (in a child process, so memory is returned between
stages) and prints its progress. A stage whose output is complete — it finished before with the same
settings, which a marker in ``DIR/.demo/`` records — is skipped, so an interrupted demo resumes
where it stopped. ``DIR`` then holds ``logs/``, ``captions/``, ``clips/``, ``run/``, ``index/``,
``metrics.json`` and ``report.html``, and every later command can be pointed at them::

    scenesearch search DIR/index "a car in the left lane approaches, then moves into the ego lane"
    scenesearch serve DIR/index
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.atomic import atomic_write_text

DEFAULT_QUERIES = (
    "a car in the left lane approaches, then moves into the ego lane",
    "a pedestrian crossing approaches the ego vehicle",
    "a stopped car in the ego lane",
    "a car in the oncoming lane approaches, then moves away",
)
#: Share of the demo's logs in the validation split.
VAL_FRACTION = 0.15
STAGES = ("simulate", "caption", "clips", "train", "index", "eval", "report")
MARKERS = ".demo"


@dataclass(frozen=True)
class DemoConfig:
    """Sizes and seeds of the demo; every field is a flag of ``scenesearch demo``.

    Attributes:
        logs: simulated logs.
        duration_s: length of each log, seconds.
        test_fraction: share of the logs held out for the test split (validation: 0.15, the rest
            trains). A quarter, so that the test split spans several logs and so several
            appearances (time of day, weather): the clip → clip appearance bias needs them.
        seed: seed of the simulation (and so of everything after it).
        frames_per_clip: T frames per clip.
        camera_width_px: width of the camera view of clips (height: ``camera_height_px``).
        camera_height_px: height of the camera view of clips.
        bev_resolution_m: cell size of the BEV view of clips (grid x ∈ [−20, 60] m, y ∈ [−20, 20] m).
        epochs: training epochs (None: the trainer's default).
        batch_size: training batch size (None: the trainer's default).
        tag_weight: weight of the attribute-tagging loss joined to the contrastive loss (None: the
            trainer's default). Small, because with a few minutes of training a larger weight
            crowds out the contrastive objective.
        train_preset: the trainer's preset (``default``; ``tiny`` for smoke runs), None for the trainer's choice.
        sensors: render LiDAR and cameras (off: BEV clips from boxes, no camera).
        queries: example queries shown and put in the report.
        top_k: results shown per example query.
    """

    # Sized so that the whole demo runs in about 6 minutes on 2 CPU cores: small clip views (the model
    # trains at about 40 clips/s on them) and enough epochs for it to beat the baselines.
    logs: int = 12
    duration_s: float = 20.0
    test_fraction: float = 0.25
    seed: int = 0
    frames_per_clip: int = 12
    camera_width_px: int = 64
    camera_height_px: int = 32
    bev_resolution_m: float = 1.25
    epochs: int | None = 12
    batch_size: int | None = 16
    tag_weight: float | None = 0.2
    train_preset: str | None = None
    sensors: bool = True
    queries: tuple[str, ...] = DEFAULT_QUERIES
    top_k: int = 3

    def __post_init__(self) -> None:
        for name in ("logs", "frames_per_clip", "top_k"):
            if getattr(self, name) < 1:
                raise ValueError(f"DemoConfig.{name} must be at least 1, got {getattr(self, name)}")
        if self.duration_s <= 0:
            raise ValueError(f"DemoConfig.duration_s must be positive, got {self.duration_s}")
        if not 0 < self.test_fraction < 1 - VAL_FRACTION:
            raise ValueError(
                f"DemoConfig.test_fraction must lie in (0, {1 - VAL_FRACTION:g}), got {self.test_fraction}")
        if self.epochs is not None and self.epochs < 1:
            raise ValueError(f"DemoConfig.epochs must be at least 1, got {self.epochs}")

    @staticmethod
    def quick() -> DemoConfig:
        """Smallest sizes that still run every stage (a smoke run, not a measurement)."""
        return DemoConfig(logs=3, duration_s=12.0, frames_per_clip=8, epochs=1, train_preset="tiny", batch_size=None)


class DemoStageError(RuntimeError):
    """A stage's command failed; the demo can be resumed from that stage."""


@dataclass
class StageResult:
    name: str
    seconds: float
    skipped: bool
    detail: str = ""


@dataclass
class Demo:
    """Runs the stages into ``out_dir``."""

    out_dir: Path
    config: DemoConfig = field(default_factory=DemoConfig)
    python: str = sys.executable
    say: Callable[[str], None] = print
    results: list[StageResult] = field(default_factory=list)

    # ------------------------------------------------------------------ paths

    @property
    def logs_dir(self) -> Path:
        return self.out_dir / "logs"

    @property
    def captions_dir(self) -> Path:
        return self.out_dir / "captions"

    @property
    def clips_dir(self) -> Path:
        return self.out_dir / "clips"

    @property
    def run_dir(self) -> Path:
        return self.out_dir / "run"

    @property
    def index_dir(self) -> Path:
        return self.out_dir / "index"

    @property
    def metrics_path(self) -> Path:
        return self.out_dir / "metrics.json"

    def log_dirs(self) -> list[Path]:
        if not self.logs_dir.is_dir():
            return []
        return sorted(p for p in self.logs_dir.iterdir() if p.is_dir() and (p / "annotations.feather").is_file())

    # ------------------------------------------------------------------ stages

    def settings(self, stage: str) -> dict[str, Any]:
        """The settings a stage's output depends on (a changed setting reruns the stage and those after)."""
        c = self.config
        sim = {"logs": c.logs, "duration_s": c.duration_s, "seed": c.seed, "sensors": c.sensors}
        upto: dict[str, dict[str, Any]] = {"simulate": sim}
        upto["caption"] = upto["simulate"]
        upto["clips"] = {**upto["caption"], "frames_per_clip": c.frames_per_clip, "camera": [c.camera_width_px,
                         c.camera_height_px], "bev_resolution_m": c.bev_resolution_m,
                         "test_fraction": c.test_fraction}
        upto["train"] = {**upto["clips"], "epochs": c.epochs, "train_preset": c.train_preset,
                         "batch_size": c.batch_size, "tag_weight": c.tag_weight}
        upto["index"] = upto["train"]
        upto["eval"] = upto["train"]
        upto["report"] = {**upto["train"], "queries": list(c.queries), "top_k": c.top_k}
        return upto[stage]

    def _marker(self, stage: str) -> Path:
        return self.out_dir / MARKERS / f"{stage}.json"

    def is_done(self, stage: str) -> bool:
        marker = self._marker(stage)
        if not marker.is_file():
            return False
        try:
            return bool(json.loads(marker.read_text()).get("settings") == self.settings(stage))
        except json.JSONDecodeError:
            return False

    def _mark(self, stage: str, seconds: float) -> None:
        atomic_write_text(self._marker(stage), json.dumps({"settings": self.settings(stage), "seconds": seconds}))

    def command(self, args: Sequence[object]) -> None:
        """Run ``scenesearch ARGS`` in a child process; its output streams through."""
        argv = [self.python, "-m", "retrieval.cli", *map(str, args)]
        self.say("  $ scenesearch " + " ".join(map(str, args)))
        completed = subprocess.run(argv, check=False)
        if completed.returncode != 0:
            raise DemoStageError(f"`scenesearch {args[0]}` failed with exit status {completed.returncode}; "
                               f"rerun `scenesearch demo --out {self.out_dir}` to resume from this stage")

    def run(self, stages: Sequence[str] = STAGES) -> list[StageResult]:
        """Run (or skip, when complete) each stage in order; returns what happened to each."""
        unknown = [s for s in stages if s not in STAGES]
        if unknown:
            raise ValueError(f"unknown stage {unknown[0]!r}; stages: {', '.join(STAGES)}")
        self.out_dir.mkdir(parents=True, exist_ok=True)
        started = time.perf_counter()
        rerun = False
        for i, stage in enumerate(stages, start=1):
            head = f"[demo {i}/{len(stages)}] {stage}"
            if not rerun and self.is_done(stage):
                self.say(f"{head}: complete, skipped")
                self.results.append(StageResult(stage, 0.0, True))
                continue
            rerun = True  # every stage after a rerun one reads new inputs
            self.say(f"{head} ...")
            t0 = time.perf_counter()
            detail = getattr(self, f"stage_{stage}")()
            seconds = time.perf_counter() - t0
            self._mark(stage, seconds)
            self.results.append(StageResult(stage, seconds, False, detail or ""))
            self.say(f"{head}: done in {seconds:.0f} s{f' ({detail})' if detail else ''}")
        total = time.perf_counter() - started
        self.say("stage timings: " + ", ".join(f"{r.name} {'skipped' if r.skipped else f'{r.seconds:.0f} s'}"
                                               for r in self.results) + f"; total {total / 60:.1f} min")
        return self.results

    def stage_simulate(self) -> str:
        c = self.config
        args: list[object] = ["simulate", "--out", self.logs_dir, "--logs", c.logs, "--duration-s", c.duration_s,
                "--seed", c.seed, "--overwrite"]
        if not c.sensors:
            args.append("--no-sensors")
        self.command(args)
        return f"{len(self.log_dirs())} logs"

    def stage_caption(self) -> str:
        logs = self.log_dirs()
        if not logs:
            raise DemoStageError(f"{self.logs_dir}: no logs to caption (the simulation wrote none)")
        self.command(["caption", *logs, "--out", self.captions_dir])
        return ""

    def stage_clips(self) -> str:
        c = self.config
        config_path = self.out_dir / "clips.yaml"
        train_fraction = round(1.0 - VAL_FRACTION - c.test_fraction, 6)
        config_path.write_text(f"camera: {{width_px: {c.camera_width_px}, height_px: {c.camera_height_px}}}\n"
                               f"bev: {{resolution_m: {c.bev_resolution_m}}}\n"
                               f"split: {{train_fraction: {train_fraction}, val_fraction: {VAL_FRACTION}}}\n")
        # --tag-targets: attribute targets from the simulator's behaviour labels; with them, training also
        # learns the spatio-temporal tags on the BEV embedding, so the trained model answers tag queries.
        self.command(["clips", *self.log_dirs(), "--captions", self.captions_dir, "--out", self.clips_dir,
                      "--frames-per-clip", c.frames_per_clip, "--config", config_path, "--tag-targets"])
        return ""

    def stage_train(self) -> str:
        # The stage runs only when it has no complete output for the current settings: a run folder
        # left here belongs to other settings (or was cut short), so training starts afresh.
        if self.run_dir.exists():
            shutil.rmtree(self.run_dir)
        args: list[object] = ["train", self.clips_dir, "--out", self.run_dir]
        if self.config.train_preset is not None:
            args += ["--preset", self.config.train_preset]
        if self.config.epochs is not None:
            args += ["--epochs", self.config.epochs]
        if self.config.batch_size is not None:
            args += ["--batch-size", self.config.batch_size]
        if self.config.tag_weight is not None:
            args += ["--tag-weight", self.config.tag_weight]
        self.command(args)
        return ""

    def stage_index(self) -> str:
        self.command(["index", self.run_dir, self.clips_dir, "--out", self.index_dir])
        return ""

    def stage_eval(self) -> str:
        self.command(["eval", self.run_dir, self.clips_dir, "--split", "test", "--out", self.metrics_path,
                      "--index", self.index_dir])
        return ""

    def stage_report(self) -> str:
        from retrieval.evaluation import metrics_table
        from retrieval.records import format_table
        from retrieval.report import Example, write_report
        from retrieval.scenesearch import SceneSearch

        metrics = json.loads(self.metrics_path.read_text()) if self.metrics_path.is_file() else None
        if metrics is not None:
            self.say(metrics_table(metrics))
        search = SceneSearch.open(self.index_dir)
        examples = []
        k = min(self.config.top_k, len(search))
        for query in self.config.queries:
            results = search.search_text(query, k=k)
            examples.append(Example(query, results))
            self.say(f'\ntext → clip: "{query}"\n{format_table(results)}')
        caption_query = self.config.queries[-1]
        caption_results = search.search_captions(caption_query, k=k)
        examples.append(Example(caption_query, caption_results, mode="rule-caption search"))
        meta, x = search.embeddings("fused")
        actions = [" → ".join(tags) for tags in meta.column("tags").to_pylist()]
        timings = {r.name: r.seconds for r in self.results if not r.skipped}
        settings = ", ".join(f"{k}={v}" for k, v in asdict(self.config).items() if k != "queries")
        path = write_report(self.out_dir, metrics, examples, run_dir=self.run_dir, embedding_map=(x, actions),
                            stage_timings_s=timings, notes=[f"settings: {settings}",
                                                            f"index: {self.index_dir} ({len(search)} clips)"],
                            sections=self.tag_sections(meta))
        self.say(f"\nwrote {path}")
        return str(path)

    def tag_sections(self, meta: Any) -> list[str]:
        """A spatio-temporal tag example for the report: pooled tags over a test log, and found spans."""
        import html

        if not (self.run_dir / "tagging.json").is_file():
            return []
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from retrieval.tagging import TagSearch

        test_logs = sorted({str(r["log_id"]) for r in meta.to_pylist() if r.get("split") == "test"})
        logs = [d for d in self.log_dirs() if d.name in test_logs] or self.log_dirs()[:1]
        tags = TagSearch(self.run_dir, clips_dir=self.clips_dir)
        queries = [("vehicle_density", "front"), ("pedestrian_density", "around"), ("stopped", "front"),
                   ("braking", "front")]
        fig, axes = plt.subplots(len(queries), 1, figsize=(9, 1.8 * len(queries)), sharex=True)
        for ax, (tag, region) in zip(axes, queries):
            ts, values = tags.series(logs[0], tag, region)
            ax.plot((ts - ts[0]) * 1e-9, values)
            ax.set_ylabel(f"{tag}\n{region}", fontsize=8)
        axes[-1].set_xlabel(f"time in log {logs[0].name[:8]} (s)")
        fig.tight_layout()
        (self.out_dir / "plots").mkdir(parents=True, exist_ok=True)
        fig.savefig(self.out_dir / "plots" / "tags_over_time.png", dpi=90)
        plt.close(fig)
        split_of = {str(r["log_id"]): str(r.get("split")) for r in meta.to_pylist()}
        held = {s: [d for d in self.log_dirs() if split_of.get(d.name) == s] for s in ("val", "train")}
        threshold, truth, source = self._tag_threshold(tags, "stopped", "front", held, logs)
        spans = tags.find(logs, "stopped", "front", threshold=threshold, min_duration_s=1.0, k=5)
        first_ns = {d.name: int(tags.frames(d).timestamps_ns[0]) for d in logs}
        confirmed = []
        for s in spans:
            ts = tags.frames(next(d for d in logs if d.name == s.log_id)).timestamps_ns
            inside = (ts >= s.start_ns) & (ts <= s.end_ns)
            hit = truth.get(s.log_id)
            confirmed.append(None if hit is None else float(hit[inside].mean()) if inside.any() else 0.0)
        rows = "".join(f"<tr><td>{html.escape(s.log_id[:8])}</td><td>{(s.start_ns - first_ns[s.log_id]) * 1e-9:.1f}"
                       f"</td><td>{s.duration_s:.1f}</td><td>{s.score:.2f}</td>"
                       f"<td>{'–' if c is None else f'{c:.0%}'}</td></tr>" for s, c in zip(spans, confirmed))
        known = [c for c in confirmed if c is not None]
        precision = (f"; the labels confirm {sum(c > 0.5 for c in known)} of {len(known)} (most of a span's frames)"
                     if known else "")
        self.say(f"tags: {len(spans)} spans where a vehicle is stopped in front, in {len(logs)} test log(s) "
                 f"(threshold {threshold:.2f} from the {source}{precision})")
        return ["<h2>Spatio-temporal tags from the universal BEV embedding</h2>",
                "<p>Pooled attribute values over a held-out log (densities in m², probabilities otherwise):</p>",
                "<img src='plots/tags_over_time.png' alt='tags over time'>",
                "<h3>scenesearch find RUN LOG... --tag stopped --region front</h3>",
                f"<p>Test logs; threshold {threshold:.2f}, the best frame F1 against the behaviour labels on the "
                f"{source}. <i>labelled</i>: share of the span's frames whose labels put a stopped vehicle "
                f"in front{html.escape(precision)}.</p>",
                "<table><tr><th>log</th><th>start (s into the log)</th><th>duration (s)</th><th>score</th>"
                f"<th>labelled</th></tr>{rows}</table>" if spans else f"<p>no span above {threshold:.2f}</p>"]

    def _tag_threshold(self, tags: Any, attribute: str, region: str, held: dict[str, list[Path]],
                       test_logs: list[Path]) -> tuple[float, dict[str, NDArray[np.bool_]], str]:
        """The span threshold with the best frame F1 on the validation logs — on the training logs
        when no validation frame is positive — (0.5 without labels), the per-frame truth of the test
        logs (empty without tag targets), and which logs chose the threshold."""
        from encoders.tagging.evaluate import held_out_threshold, pooled_truth_and_pred
        from encoders.tagging.targets import has_targets

        factor = tags.tagger.downsample

        def truth_of(d: Path) -> NDArray[np.bool_] | None:
            if not has_targets(self.clips_dir, d.name):
                return None
            pooled = pooled_truth_and_pred(self.clips_dir, d.name, None, factor, (attribute,))[0]
            return np.asarray(pooled[attribute][region] > 0)

        def pooled(logs: list[Path]) -> tuple[NDArray[np.float32] | None, NDArray[np.bool_] | None]:
            labelled = [(d, t) for d, t in ((d, truth_of(d)) for d in logs) if t is not None]
            if not any(t.any() for _, t in labelled):
                return None, None  # skipped without running the model
            return (np.concatenate([tags.series(d, attribute, region)[1] for d, _ in labelled]),
                    np.concatenate([t for _, t in labelled]))

        threshold, source = held_out_threshold((split, *pooled(logs)) for split, logs in held.items())
        names = {"val": "validation logs", "train": "training logs", "default": "default (no labelled logs)"}
        test = {d.name: truth_of(d) for d in test_logs}
        return threshold, {k: v for k, v in test.items() if v is not None}, names[source]


def config_from_args(args: argparse.Namespace) -> DemoConfig:
    """``--quick`` sizes, then any size flag given."""
    base = DemoConfig.quick() if args.quick else DemoConfig()
    overrides: dict[str, Any] = {}
    for name in ("logs", "duration_s", "test_fraction", "seed", "frames_per_clip", "camera_width_px",
                 "camera_height_px", "bev_resolution_m", "epochs", "batch_size", "tag_weight"):
        value = getattr(args, name, None)
        if value is not None:
            overrides[name] = value
    if args.no_sensors:
        overrides["sensors"] = False
    if args.query:
        overrides["queries"] = tuple(args.query)
    return replace(base, **overrides)
