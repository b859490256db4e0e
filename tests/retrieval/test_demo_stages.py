"""Demo orchestration (stages, resuming, arguments) and the report, without running the heavy stages."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from retrieval_fakes import FakeEmbedder, HashTextEncoder

from encoders.clips.config import BevClipConfig, CameraClipConfig, ClipsConfig, SplitConfig
from retrieval.commands import demo as demo_command
from retrieval.demo import EXTRA_SEED_OFFSET, STAGES, VAL_SEED_OFFSET, Demo, DemoStageError, config_from_args
from retrieval.demo_config import DemoConfig
from retrieval.embedding import model_hash
from retrieval.evaluation import evaluate
from retrieval.report import Example, write_report
from retrieval.scenesearch import SceneSearch


class RecordingDemo(Demo):
    """Records the commands instead of running them; makes the outputs the next stages look for."""

    def command(self, args: Any) -> None:
        self.calls.append([str(a) for a in args])
        if args[0] == "simulate":
            out = Path(args[args.index("--out") + 1])
            for i in range(int(args[args.index("--logs") + 1])):
                log = out / f"{out.name}{i}"
                log.mkdir(parents=True, exist_ok=True)
                (log / "annotations.feather").write_bytes(b"")

    def stage_report(self) -> str:
        self.calls.append(["report"])
        return ""

    calls: list[list[str]]


def _demo(tmp_path: Path, config: DemoConfig) -> RecordingDemo:
    demo = RecordingDemo(tmp_path / "demo", config, say=lambda _m: None)
    demo.calls = []
    return demo


def test_stages_run_in_order_with_sizes(tmp_path: Path) -> None:
    demo = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=3, frames_per_clip=8, batch_size=4,
                                      camera_width_px=40, bev_resolution_m=2.0, extra_logs=3, map_less_share=0.25,
                                      jitter_share=0.75, val_logs=2,
                                      extra_networks=("grid", "spider")))
    results = demo.run()
    assert [r.name for r in results] == list(STAGES)
    names = [c[0] for c in demo.calls]
    assert names == ["simulate"] * 4 + ["caption", "clips", "train", "index", "eval", "report"]
    sim, val, grid, spider = demo.calls[:4]
    assert sim[sim.index("--logs") + 1] == "2" and sim[sim.index("--duration-s") + 1] == "10"
    assert "--map-less-share" not in sim and "--network" not in sim  # the logs to evaluate on: a grid, with maps
    # The validation logs: drawn as those (sensors, the same city), from another seed, into a folder of their own.
    assert val[val.index("--out") + 1] == str(demo.val_logs_dir) and val[val.index("--logs") + 1] == "2"
    assert val[val.index("--seed") + 1] == str(DemoConfig().seed + VAL_SEED_OFFSET)
    assert [a for i, a in enumerate(val) if val[i - 1] not in ("--out", "--logs", "--seed")] == [
        a for i, a in enumerate(sim) if sim[i - 1] not in ("--out", "--logs", "--seed")]
    # The extra logs: another seed, no sensors, a quarter without a map, training only, shared by the networks
    # (the first takes the remainder), each in its own folder.
    for extra, network, count in ((grid, "grid", "2"), (spider, "spider", "1")):
        assert extra[extra.index("--out") + 1] == str(demo.extra_logs_dir / network)
        assert extra[extra.index("--network") + 1] == network and extra[extra.index("--logs") + 1] == count
        assert extra[extra.index("--seed") + 1] == str(DemoConfig().seed + EXTRA_SEED_OFFSET)
        assert "--no-sensors" in extra and extra[extra.index("--map-less-share") + 1] == "0.25"
        assert extra[extra.index("--jitter-share") + 1] == "0.75" and "--jitter-share" not in sim
    main_logs = [str(demo.logs_dir / f"logs{i}") for i in range(2)]
    extra_logs = [str(demo.extra_logs_dir / net / f"{net}{i}") for net, i in (("grid", 0), ("grid", 1), ("spider", 0))]
    val_logs = [str(demo.val_logs_dir / f"val_logs{i}") for i in range(2)]
    assert demo.calls[4][1:8] == [*main_logs, *val_logs, *extra_logs]
    clips = demo.calls[5]
    assert clips[1:3] == main_logs and clips[clips.index("--train-only") + 1:][:3] == extra_logs
    assert clips[clips.index("--val-only") + 1:][:3] == [*val_logs, "--captions"]
    assert clips[clips.index("--frames-per-clip") + 1] == "8"
    assert clips[clips.index("--config") + 1] == str(demo.out_dir / "clips.yaml")
    # The test split takes the default quarter, validation 0.15, training the rest.
    assert ClipsConfig.from_yaml(demo.out_dir / "clips.yaml") == ClipsConfig(
        frames_per_clip=8, camera=CameraClipConfig(width_px=40, height_px=DemoConfig().camera_height_px),
        bev=BevClipConfig(resolution_m=2.0), split=SplitConfig(train_fraction=0.6, val_fraction=0.15))
    train = demo.calls[6]
    assert train[train.index("--epochs") + 1] == "3" and train[train.index("--batch-size") + 1] == "4"
    # The demo's model is the recommended recipe (encoders/presets/recommended.yaml), named, not spelt in flags.
    assert train[train.index("--preset") + 1] == "recommended" and len(train) == 10
    # The test split's figures, with their baselines, go into the model card too.
    assert "--model-card" in demo.calls[8] and demo.calls[8][demo.calls[8].index("--split") + 1] == "test"


def test_workers_run_the_sensor_logs_and_the_clips_on_ray(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    def commands(config: DemoConfig) -> dict[str, list[list[str]]]:
        demo = _demo(tmp_path / str(len(list(tmp_path.iterdir()))), config)
        demo.run(("simulate", "caption", "clips"))
        out: dict[str, list[list[str]]] = {}
        for call in demo.calls:
            out.setdefault(call[0], []).append(call)
        return out

    two = commands(DemoConfig(logs=2, duration_s=10, extra_logs=1, workers=2))
    sensor_logs, val_logs, extra_logs = two["simulate"]
    assert sensor_logs[sensor_logs.index("--workers") + 1] == "2" and "--workers" not in extra_logs  # seconds
    assert val_logs[val_logs.index("--workers") + 1] == "2"  # rendered with sensors: minutes
    assert two["clips"][0][two["clips"][0].index("--workers") + 1] == "2" and "--workers" not in two["caption"][0]
    for serial in (0, 1):
        calls = commands(DemoConfig(logs=2, duration_s=10, extra_logs=1, workers=serial))
        assert not any("--workers" in c for cs in calls.values() for c in cs)
    # By default one worker per core, where Ray is installed and there is more than one core.
    monkeypatch.setattr("retrieval.demo.usable_cpus", lambda: 4)
    assert Demo(tmp_path, DemoConfig()).workers() == (4 if importlib.util.find_spec("ray") else 1)
    monkeypatch.setattr("importlib.util.find_spec", lambda _name: None)
    assert Demo(tmp_path, DemoConfig()).workers() == 1
    monkeypatch.undo()
    monkeypatch.setattr("retrieval.demo.usable_cpus", lambda: 1)
    assert Demo(tmp_path, DemoConfig()).workers() == 1
    # Where the work runs does not change what it makes: a demo resumed with other workers skips what is done.
    demo = _demo(tmp_path / "resume", DemoConfig(logs=2, duration_s=10, workers=2))
    demo.run(("simulate",))
    again = _demo(tmp_path / "resume", DemoConfig(logs=2, duration_s=10, workers=0))
    assert again.run(("simulate",))[0].skipped


def test_a_stage_that_fails_on_ray_runs_again_serially(tmp_path: Path) -> None:
    class NoRay(RecordingDemo):
        def command(self, args: Any) -> None:
            if "--workers" in [str(a) for a in args]:
                self.calls.append(["failed", *map(str, args)])
                raise DemoStageError("exit status 1")
            super().command(args)

    demo = NoRay(tmp_path / "demo", DemoConfig(logs=2, duration_s=10, extra_logs=0, workers=2), say=lambda _m: None)
    demo.calls = []
    demo.run(("simulate", "caption", "clips"))
    assert [c[0] for c in demo.calls] == ["failed", "simulate", "failed", "simulate", "caption", "failed", "clips"]
    assert demo.calls[0][1:-2] == demo.calls[1]  # the same command, without the workers
    assert demo.calls[2][1:-2] == demo.calls[3]  # the validation logs' too


def test_resume_skips_complete_stages_and_reruns_after_a_change(tmp_path: Path) -> None:
    demo = _demo(tmp_path, DemoConfig(logs=2, duration_s=10))
    demo.run()
    again = _demo(tmp_path, DemoConfig(logs=2, duration_s=10))
    results = again.run()
    assert all(r.skipped for r in results) and again.calls == []
    # A new epoch count keeps the data and retrains, then redoes everything after training.
    changed = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5))
    changed.run_dir.mkdir(parents=True, exist_ok=True)
    (changed.run_dir / "model.safetensors").write_bytes(b"a run of the old settings")
    changed.run()
    assert [c[0] for c in changed.calls] == ["train", "index", "eval", "report"]
    # The old run is cleared, so `scenesearch train` does not refuse an occupied folder.
    assert not (changed.run_dir / "model.safetensors").exists()
    # A new share of map-less extra logs is new data: everything reruns.
    fewer_maps = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0))
    fewer_maps.run()
    assert [c[0] for c in fewer_maps.calls] == ["simulate", "simulate", *STAGES]  # with the validation logs
    # Another recipe retrains on the same clips, and names it.
    tiny = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, train_preset="tiny"))
    tiny.run()
    assert [c[0] for c in tiny.calls] == ["train", "index", "eval", "report"]
    assert tiny.calls[0][tiny.calls[0].index("--preset") + 1] == "tiny"
    assert tiny.settings("train")["train_preset"] == "tiny"
    # Without extra logs, none is simulated, and those of the settings before are gone.
    assert fewer_maps.extra_logs_dir.is_dir()
    alone = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, extra_logs=0))
    alone.run()
    assert [c[0] for c in alone.calls] == ["simulate", *STAGES] and not alone.extra_logs_dir.exists()
    assert "--train-only" not in alone.calls[3]
    # Without validation logs likewise; and then they are not among the settings, so a demo folder made
    # before them resumes as it was.
    assert alone.val_logs_dir.is_dir()
    no_val = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, extra_logs=0, val_logs=0))
    no_val.run()
    assert [c[0] for c in no_val.calls] == list(STAGES) and not no_val.val_logs_dir.exists()
    assert "--val-only" not in no_val.calls[2]
    assert "val_logs" not in no_val.settings("simulate") and DemoConfig().val_logs > 0


def test_config_from_flags() -> None:
    args = argparse.Namespace(quick=True, logs=None, duration_s=None, seed=None, frames_per_clip=None, epochs=4,
                              no_sensors=True, query=["a bus stops"], map_less_share=0.25, extra_logs=5,
                              jitter_share=0.2, extra_networks=["random"], train_preset=None)
    config = config_from_args(args)
    assert config.logs == DemoConfig.quick().logs and config.epochs == 4 and config.map_less_share == 0.25
    assert config.extra_logs == 5 and config.jitter_share == 0.2 and config.extra_networks == ("random",)
    assert config.train_preset == "tiny"  # --quick trains the tiny recipe
    assert config.sensors is False and config.queries == ("a bus stops",)
    parser = argparse.ArgumentParser()
    demo_command.configure(parser)
    assert config_from_args(parser.parse_args(["--out", "x"])) == DemoConfig()
    assert DemoConfig().train_preset == "recommended" and DemoConfig().epochs is None
    assert config_from_args(parser.parse_args(["--out", "x", "--preset", "tiny"])).train_preset == "tiny"
    assert config_from_args(parser.parse_args(["--out", "x", "--val-logs", "0"])).val_logs == 0
    with pytest.raises(SystemExit):
        parser.parse_args(["--out", "x", "--time-slots", "4"])  # a model setting: it lives in the recipe


def test_report(built: dict[str, Any], tmp_path: Path) -> None:
    run = built["run"]
    rows = [{"epoch": e, "train_loss": 2.0 / (e + 1), "val": {"R@1": 0.1 * e, "mAP": 0.2 * e}} for e in range(5)]
    (run / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows))
    search = SceneSearch.open(built["index"], embedder=built["embedder"], text_encoder=HashTextEncoder())
    results = search.search_text("a car in the left lane approaches", k=3)
    preview = Path(results[0].preview_path or "")
    preview.parent.mkdir(parents=True, exist_ok=True)
    preview.write_bytes(b"GIF89a")
    metrics = evaluate(run, built["clips"], embedder=FakeEmbedder(model_hash(run)))
    meta, x = search.embeddings("fused")
    actions = ["|".join(t) for t in meta.column("tags").to_pylist()]
    out = tmp_path / "report"
    path = write_report(out, metrics, [Example("a car in the left lane approaches", results)], run_dir=run,
                        embedding_map=(x, actions), stage_timings_s={"train": 12.0})
    page = path.read_text()
    for png in ("training_curves.png", "embedding_map.png", "recall_at_k.png"):
        assert (out / "plots" / png).stat().st_size > 1000
        assert f"plots/{png}" in page
    # The same rows as `scenesearch eval` prints, rule-caption search among the baselines.
    assert "text→clip R@1" in page and "bag of frames" in page and "rule captions" in page
    assert "object sentence alone mAP" in page
    ceiling = metrics["clip_to_clip"]["action_precision@5_ceiling"]
    assert f"<td>clip→clip action_precision@5 ceiling</td><td>{ceiling:.3f}</td>" in page
    # Previews are linked relative to the page.
    assert "../" in page and preview.name in page
    assert np.isfinite(x).all()
