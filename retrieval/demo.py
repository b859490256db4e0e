"""The end-to-end demo: simulate → caption → clips → train → index → evaluate → report.

Each stage runs one ``scenesearch`` command (in a child process, so memory is returned between
stages) and prints its progress. A stage whose output is complete — it finished before with the same
settings, which a marker in ``DIR/.demo/`` records — is skipped, so an interrupted demo resumes
where it stopped. ``DIR`` then holds ``logs/``, ``val_logs/`` (validation only), ``extra_logs/``
(training only), ``captions/``, ``clips/``, ``run/``, ``index/``, ``metrics.json`` and ``report.html``, and
every later command can be pointed at them::

    scenesearch search DIR/index "a car in the left lane approaches, then moves into the ego lane"
    scenesearch serve DIR/index
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from retrieval.demo_config import VAL_FRACTION, DemoConfig
from scenesearch_base.atomic import atomic_write_text
from scenesearch_base.folders import FolderKind, claim_folder, mark_folder
from scenesearch_base.ray_cluster import usable_cpus

#: The extra training logs' seed is the demo's plus this: other drives through another city.
EXTRA_SEED_OFFSET = 1000
#: The validation-only logs' seed is the demo's plus this: other drives, rendered as the logs to evaluate on.
VAL_SEED_OFFSET = 2000
STAGES = ("simulate", "caption", "clips", "train", "index", "eval", "report")
MARKERS = ".demo"
#: The demo's folder (:mod:`scenesearch_base.folders`): one folder or file per stage's output, and the report.
DEMO_FOLDER = FolderKind("demo", signature=MARKERS, entries=(
    MARKERS, "logs", "extra_logs", "val_logs", "captions", "clips", "clips.yaml", "run", "index", "metrics.json",
    "report.html", "plots", "previews", "tags"))


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

    def __post_init__(self) -> None:
        # One folder (or file) per stage's output; every later command can be pointed at them.
        out = self.out_dir
        self.logs_dir, self.captions_dir, self.clips_dir = out / "logs", out / "captions", out / "clips"
        self.extra_logs_dir, self.val_logs_dir = out / "extra_logs", out / "val_logs"
        self.run_dir, self.index_dir, self.metrics_path = out / "run", out / "index", out / "metrics.json"

    def log_dirs(self, folder: Path | None = None) -> list[Path]:
        """The logs in ``folder`` (default: the logs to train and evaluate on)."""
        folder = self.logs_dir if folder is None else folder
        if not folder.is_dir():
            return []
        return sorted(p for p in folder.iterdir() if p.is_dir() and (p / "annotations.feather").is_file())

    def workers(self) -> int:
        """Ray workers of the per-log stages (:attr:`DemoConfig.workers`); 1: serially, in the command's process."""
        if self.config.workers is not None:
            return max(self.config.workers, 1)
        cores = usable_cpus()
        return cores if cores > 1 and importlib.util.find_spec("ray") is not None else 1

    def per_log_command(self, args: Sequence[object]) -> None:
        """:meth:`command` on :meth:`workers` Ray workers; serially when there is one, or when the
        command fails there (a Ray runtime that cannot start on this machine does not stop the demo;
        the outputs are the same either way)."""
        workers = self.workers()
        if workers <= 1:
            self.command(args)
            return
        try:
            self.command([*args, "--workers", workers])
        except DemoStageError:
            self.say(f"  `scenesearch {args[0]}` failed on {workers} Ray workers; running it serially")
            self.command(args)

    def extra_logs_per_network(self) -> dict[str, int]:
        """How many of the ``extra_logs`` each network simulates: an even share, the first networks one
        more while a remainder lasts; networks left with none are not listed."""
        share, remainder = divmod(self.config.extra_logs, len(self.config.extra_networks))
        counts = {net: share + int(i < remainder) for i, net in enumerate(self.config.extra_networks)}
        return {net: count for net, count in counts.items() if count}

    def extra_log_dirs(self) -> list[Path]:
        """The extra logs, which only train (network by network)."""
        return [log for net in self.extra_logs_per_network() for log in self.log_dirs(self.extra_logs_dir / net)]

    def val_log_dirs(self) -> list[Path]:
        """The validation-only logs (:attr:`DemoConfig.val_logs`)."""
        return self.log_dirs(self.val_logs_dir)

    # ------------------------------------------------------------------ stages

    def settings(self, stage: str) -> dict[str, Any]:
        """The settings a stage's output depends on (a changed setting reruns the stage and those after)."""
        from encoders.clips.layout import CLIPS_FORMAT_VERSION
        from retrieval.index_manifest import FORMAT_VERSION as INDEX_FORMAT_VERSION
        from scenarios.cache import CACHE_VERSION

        c = self.config
        sim = {"logs": c.logs, "duration_s": c.duration_s, "seed": c.seed, "sensors": c.sensors,
               "extra_logs": c.extra_logs, "map_less_share": c.map_less_share,
               "jitter_share": c.jitter_share, "extra_networks": list(c.extra_networks)}
        if c.val_logs:  # named only when there are some, so that a demo folder made before resumes
            sim["val_logs"] = c.val_logs
        upto: dict[str, dict[str, Any]] = {"simulate": sim}
        upto["caption"] = upto["simulate"]
        # A folder made by a release that wrote another format is made again, not resumed.
        upto["clips"] = {**upto["caption"], "frames_per_clip": c.frames_per_clip, "camera": [c.camera_width_px,
                         c.camera_height_px], "bev_resolution_m": c.bev_resolution_m,
                         "test_fraction": c.test_fraction, "clips_format": CLIPS_FORMAT_VERSION}
        upto["train"] = {**upto["clips"], "epochs": c.epochs, "train_preset": c.train_preset,
                         "batch_size": c.batch_size}
        upto["index"] = {**upto["train"], "index_format": INDEX_FORMAT_VERSION, "scenario_features": CACHE_VERSION}
        upto["eval"] = upto["train"]
        upto["report"] = {**upto["train"], "queries": list(c.queries), "scenario_query": c.scenario_query,
                          "top_k": c.top_k}
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
        claim_folder(self.out_dir, DEMO_FOLDER)  # its stages replace folders inside it
        self.out_dir.mkdir(parents=True, exist_ok=True)
        mark_folder(self.out_dir, DEMO_FOLDER, DEMO_FOLDER.entries)
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

        def sensor_logs(out: Path, logs: int, seed: int) -> list[object]:
            args: list[object] = ["simulate", "--out", out, "--logs", logs, "--duration-s", c.duration_s,
                                  "--seed", seed, "--overwrite"]
            return args if c.sensors else [*args, "--no-sensors"]

        self.per_log_command(sensor_logs(self.logs_dir, c.logs, c.seed))
        shutil.rmtree(self.val_logs_dir, ignore_errors=True)  # the validation logs of other settings
        if c.val_logs:
            # Drawn as the logs to evaluate on (same city, sensors), from another seed: only their split differs.
            self.per_log_command(sensor_logs(self.val_logs_dir, c.val_logs, c.seed + VAL_SEED_OFFSET))
        shutil.rmtree(self.extra_logs_dir, ignore_errors=True)  # the extra logs of other settings
        for network, count in self.extra_logs_per_network().items():
            self.command(["simulate", "--out", self.extra_logs_dir / network, "--logs", count, "--duration-s",
                          c.duration_s, "--seed", c.seed + EXTRA_SEED_OFFSET, "--no-sensors", "--map-less-share",
                          c.map_less_share, "--jitter-share", c.jitter_share, "--network", network])
        return (f"{len(self.log_dirs())} logs, {len(self.val_log_dirs())} validation logs, "
                f"{len(self.extra_log_dirs())} extra training logs")

    def stage_caption(self) -> str:
        logs = self.log_dirs()
        if not logs:
            raise DemoStageError(f"{self.logs_dir}: no logs to caption (the simulation wrote none)")
        self.command(["caption", *logs, *self.val_log_dirs(), *self.extra_log_dirs(), "--out", self.captions_dir])
        return ""

    def stage_clips(self) -> str:
        from encoders.clips.config import BevClipConfig, CameraClipConfig, ClipsConfig, SplitConfig

        c = self.config
        config_path = self.out_dir / "clips.yaml"
        ClipsConfig(
            frames_per_clip=c.frames_per_clip,
            camera=CameraClipConfig(width_px=c.camera_width_px, height_px=c.camera_height_px),
            bev=BevClipConfig(resolution_m=c.bev_resolution_m),
            split=SplitConfig(train_fraction=round(1.0 - VAL_FRACTION - c.test_fraction, 6), val_fraction=VAL_FRACTION),
        ).to_yaml(config_path)
        # --tag-targets: attribute targets from the simulator's behaviour labels; with them, training also
        # learns the spatio-temporal tags on the BEV embedding, so the trained model answers tag queries.
        extra, val = self.extra_log_dirs(), self.val_log_dirs()
        self.per_log_command(["clips", *self.log_dirs(), *(["--train-only", *extra] if extra else []),
                              *(["--val-only", *val] if val else []), "--captions", self.captions_dir, "--out",
                              self.clips_dir, "--frames-per-clip", c.frames_per_clip, "--config", config_path,
                              "--tag-targets"])
        return ""

    def stage_train(self) -> str:
        # The stage runs only when it has no complete output for the current settings: a run folder
        # left here belongs to other settings (or was cut short), so training starts afresh.
        if self.run_dir.exists():
            shutil.rmtree(self.run_dir)
        args: list[object] = ["train", self.clips_dir, "--out", self.run_dir, "--preset", self.config.train_preset]
        if self.config.epochs is not None:
            args += ["--epochs", self.config.epochs]
        if self.config.batch_size is not None:
            args += ["--batch-size", self.config.batch_size]
        self.command(args)
        return ""

    def stage_index(self) -> str:
        self.command(["index", self.run_dir, self.clips_dir, "--out", self.index_dir])
        return ""

    def stage_eval(self) -> str:
        self.command(["eval", self.run_dir, self.clips_dir, "--split", "test", "--out", self.metrics_path,
                      "--index", self.index_dir, "--model-card"])
        return ""

    def stage_report(self) -> str:
        from retrieval.metrics_tables import metrics_table
        from retrieval.report import Example, write_report
        from retrieval.result_table import format_table
        from retrieval.scenario_report import scenario_section
        from retrieval.scenesearch import SceneSearch
        from retrieval.tag_report import tag_sections

        metrics = json.loads(self.metrics_path.read_text()) if self.metrics_path.is_file() else None
        if metrics is not None:
            self.say(metrics_table(metrics))
        shutil.rmtree(self.out_dir / "previews", ignore_errors=True)  # the previews the report draws, anew
        search = SceneSearch.open(self.index_dir)
        examples = []
        k = min(self.config.top_k, len(search))
        for query in self.config.queries:
            results = search.search_text(query, k=k)
            examples.append(Example(query, results))
            self.say(f'\ntext → clip: "{query}"\n{format_table(results)}')
        scenario_html, scenario_results, match = scenario_section(search, self.config.scenario_query, k, self.out_dir)
        self.say(f'\nscenario query: "{self.config.scenario_query}" → '
                 f'{match.compiled.text if match.compiled else match.fallback}\n{format_table(scenario_results)}')
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
                            sections=[scenario_html, *tag_sections(self.run_dir, self.clips_dir, [*self.log_dirs(),
                                                                                 *self.val_log_dirs()], meta,
                                                  self.out_dir, self.say,
                                                  (metrics or {}).get("tagging"))],
                            clips_dir=self.clips_dir)
        self.say(f"\nwrote {path}")
        return str(path)


def config_from_args(args: argparse.Namespace) -> DemoConfig:
    """``--quick`` sizes, then any size flag given."""
    base = DemoConfig.quick() if args.quick else DemoConfig()
    overrides: dict[str, Any] = {}
    for name in ("logs", "duration_s", "test_fraction", "seed", "frames_per_clip", "camera_width_px",
                 "camera_height_px", "bev_resolution_m", "train_preset", "epochs", "batch_size", "extra_logs",
                 "val_logs", "map_less_share", "jitter_share", "workers"):
        value = getattr(args, name, None)
        if value is not None:
            overrides[name] = value
    if args.no_sensors:
        overrides["sensors"] = False
    if args.query:
        overrides["queries"] = tuple(args.query)
    if getattr(args, "extra_networks", None) is not None:
        overrides["extra_networks"] = tuple(args.extra_networks)
    return replace(base, **overrides)
