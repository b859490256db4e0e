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
                                      jitter_share=0.75, camera_share=0.5, val_logs=2,
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
    assert train[train.index("--camera-share") + 1] == "0.5"
    # The demo's model: time slots, trained with the reversed-step captions as negatives.
    assert train[train.index("--time-slots") + 1] == "4"
    assert train[train.index("--hard-negatives") + 1:][:1] == ["reverse"]
    # ... and each clip against its own reversed steps in the pairwise order loss.
    assert train[train.index("--order-weight") + 1] == "0.3"
    # ... and each caption's halves, the object's sentence and the ego's, as queries of their own.
    assert train[train.index("--partial-weight") + 1] == "0.5"
    # ... with per-frame tag heads on the camera and track streams; the track stream reads the velocity.
    assert train[train.index("--dense-weight") + 1] == "5.0" and "--track-velocity" in train
    # ... and the camera reads the ego's motion and the object's size, trained beside the shared space.
    assert {"--camera-ego", "--camera-mask-scale", "--camera-apart"} <= set(train)
    assert train[train.index("--dense-streams") + 1:][:2] == ["camera", "track"]
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
    # Another camera share retrains on the same clips.
    more_camera = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5))
    more_camera.run()
    assert [c[0] for c in more_camera.calls] == ["train", "index", "eval", "report"]
    # So does one pooled vector instead of time slots, with in-batch negatives only.
    one_vector = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5,
                                            time_slots=0, hard_negatives=(), order_weight=None))
    one_vector.run()
    assert [c[0] for c in one_vector.calls] == ["train", "index", "eval", "report"]
    train = one_vector.calls[0]
    assert train[train.index("--time-slots") + 1] == "0" and "--hard-negatives" not in train
    assert "--order-weight" not in train
    assert "--object-category" in one_vector.calls[0]
    # Without the dense heads, the velocity features and the category: retrained, and no flag reaches `train`.
    sparse = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5,
                                        time_slots=0, hard_negatives=(), order_weight=None, dense_weight=None,
                                        track_velocity=False, object_category=False))
    sparse.run()
    assert [c[0] for c in sparse.calls] == ["train", "index", "eval", "report"]
    assert "--dense-weight" not in sparse.calls[0] and "--track-velocity" not in sparse.calls[0]
    assert "--object-category" not in sparse.calls[0]
    assert "--dense-streams" not in sparse.calls[0]
    # Heads on the track stream alone: another model, retrained.
    track_only = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5,
                                            time_slots=0, hard_negatives=(), order_weight=None,
                                            dense_streams=("track",)))
    track_only.run()
    assert [c[0] for c in track_only.calls] == ["train", "index", "eval", "report"]
    train = track_only.calls[0]
    assert train[train.index("--dense-streams") + 1:][:2] == ["track", "--track-velocity"]
    # Another weight of the pairwise order loss: another model, retrained, the weight passed to `train`.
    ordered = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5,
                                         time_slots=0, dense_streams=("track",), order_weight=0.5))
    ordered.run()
    assert [c[0] for c in ordered.calls] == ["train", "index", "eval", "report"]
    assert ordered.calls[0][ordered.calls[0].index("--order-weight") + 1] == "0.5"
    # Without the partial queries: another model, retrained, and no flag reaches `train`.
    whole = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5,
                                       time_slots=0, dense_streams=("track",), order_weight=0.5, partial_weight=None))
    whole.run()
    assert [c[0] for c in whole.calls] == ["train", "index", "eval", "report"]
    assert "--partial-weight" not in whole.calls[0]
    assert "partial_weight" not in whole.settings("train") and "partial_weight" in ordered.settings("train")
    # The camera on its pixels alone: another model, retrained, none of the camera's flags passed to `train`.
    camera = _demo(tmp_path, DemoConfig(logs=2, duration_s=10, epochs=5, map_less_share=1.0, camera_share=0.5,
                                        time_slots=0, dense_streams=("track",), order_weight=0.5, camera_ego=False,
                                        camera_mask_scale=False, camera_apart=False, camera_crop=False))
    camera.run()
    assert [c[0] for c in camera.calls] == ["train", "index", "eval", "report"]
    assert not {"--camera-ego", "--camera-mask-scale", "--camera-apart", "--camera-crop"} & set(camera.calls[0])
    # Off, they are not among the settings: a demo folder made before them resumes as it was.
    off = DemoConfig(camera_ego=False, camera_mask_scale=False, camera_apart=False, camera_crop=False,
                     object_category=False)
    names = {"camera_ego", "camera_mask_scale", "camera_apart", "camera_crop", "object_category"}
    assert not names & set(Demo(tmp_path, off).settings("train"))
    assert names <= set(Demo(tmp_path, DemoConfig()).settings("train"))
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
                              jitter_share=0.2, extra_networks=["random"], camera_share=0.4, time_slots=None,
                              hard_negatives=None, dense_weight=None, track_velocity=None, dense_streams=None)
    config = config_from_args(args)
    assert config.logs == DemoConfig.quick().logs and config.epochs == 4 and config.map_less_share == 0.25
    assert config.extra_logs == 5 and config.camera_share == 0.4 and config.jitter_share == 0.2
    assert config.extra_networks == ("random",)
    # --quick trains the tiny model: one vector, no step edits.
    assert config.time_slots is None and config.hard_negatives == ()
    assert config.dense_weight is None and config.track_velocity is False
    dense = config_from_args(argparse.Namespace(**{**vars(args), "dense_weight": 0.5, "track_velocity": True}))
    assert dense.dense_weight == 0.5 and dense.track_velocity is True
    plain = config_from_args(argparse.Namespace(**{**vars(args), "quick": False, "track_velocity": False}))
    assert plain.track_velocity is False and plain.dense_weight == DemoConfig().dense_weight
    parser = argparse.ArgumentParser()
    demo_command.configure(parser)
    parsed = config_from_args(parser.parse_args(["--out", "x", "--dense-weight", "0", "--no-track-velocity",
                                                 "--camera-ego", "--camera-mask-scale", "--camera-apart",
                                                 "--camera-crop"]))
    assert parsed.dense_weight == 0.0 and parsed.track_velocity is False
    assert parsed.camera_ego is True and parsed.camera_mask_scale is True and parsed.camera_apart is True
    assert parsed.camera_crop is True
    bare = config_from_args(parser.parse_args(["--out", "x", "--no-camera-ego", "--no-camera-mask-scale",
                                               "--no-camera-apart", "--no-camera-crop", "--no-object-category"]))
    assert not (bare.camera_ego or bare.camera_mask_scale or bare.camera_apart or bare.camera_crop)
    assert bare.object_category is False and DemoConfig().object_category is True
    assert config_from_args(parser.parse_args(["--out", "x", "--dense-streams", "track"])).dense_streams == ("track",)
    assert config_from_args(parser.parse_args(["--out", "x"])) == DemoConfig()
    assert config_from_args(parser.parse_args(["--out", "x", "--val-logs", "0"])).val_logs == 0
    assert config_from_args(parser.parse_args(["--out", "x", "--order-weight", "0.5"])).order_weight == 0.5
    # Without the reversed steps the order loss has no pairs: off unless asked for (then refused).
    assert config_from_args(parser.parse_args(["--out", "x", "--hard-negatives", "none"])).order_weight is None
    assert config_from_args(parser.parse_args(["--out", "x", "--hard-negatives", "mirror", "reverse"])
                            ).order_weight == DemoConfig().order_weight
    with pytest.raises(ValueError, match="order_weight needs 'reverse'"):
        config_from_args(parser.parse_args(["--out", "x", "--hard-negatives", "none", "--order-weight", "1"]))
    flags = argparse.Namespace(**{**vars(args), "quick": False, "time_slots": 6, "hard_negatives": ["none"]})
    assert config_from_args(flags).time_slots == 6 and config_from_args(flags).hard_negatives == ()
    assert config_from_args(argparse.Namespace(**{**vars(flags), "hard_negatives": None})).hard_negatives == (
        "reverse",)
    assert config.sensors is False and config.queries == ("a bus stops",)
    with pytest.raises(ValueError, match=r"hard_negatives: unknown \['backwards'\]"):
        DemoConfig(hard_negatives=("backwards",))
    with pytest.raises(ValueError, match="unknown stage 'deploy'"):
        _demo(Path("/nonexistent"), DemoConfig()).run(["deploy"])


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
