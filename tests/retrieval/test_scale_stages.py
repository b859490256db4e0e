"""The per-log stages and the batch embedding on Ray (``--workers``): the same files as the
serial path, file:// URIs for inputs and outputs, a worker dying mid-log, embeddings within 1e-4.

Tiny simulated logs (no sensors) plus one synthetic log with camera and LiDAR; one Ray runtime
for the session (``ray_local``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import scale_faults
from retrieval_fakes import HashTextEncoder

from retrieval.cli import main

pytestmark = pytest.mark.usefixtures("ray_local")


def _tree(root: Path, skip: tuple[str, ...] = ()) -> dict[str, bytes]:
    """Relative path → bytes of every file under ``root`` (links followed), but the ``skip`` names."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name not in skip and ".generations" not in p.parts}


def _without_timing(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _without_timing(v) for k, v in value.items() if k != "render_s"}
    if isinstance(value, list):
        return [_without_timing(v) for v in value]
    return value


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from tests.encoders.clip_fixtures import write_synthetic_log

    root = tmp_path_factory.mktemp("scale")
    sim = ["simulate", "--logs", "3", "--duration-s", "4", "--warmup-s", "20", "--egos", "2", "--seed", "1",
           "--no-sensors", "--emit-detections", "--cache-dir", str(root / "netcache")]
    assert main([*sim, "--out", str(root / "logs")]) == 0
    assert main([*sim, "--out", str(root / "logs_ray"), "--workers", "2"]) == 0
    write_synthetic_log(root / "logs", "synthetic_sensors", num_frames=20)
    return {"root": root, "logs": root / "logs"}


def _logs(data: dict[str, Path]) -> list[str]:
    return sorted(str(p) for p in data["logs"].iterdir())


def test_simulate_with_workers_writes_the_same_logs(data: dict[str, Path]) -> None:
    serial = _tree(data["logs"])
    ray = _tree(data["root"] / "logs_ray")
    assert len(ray) > 10 and any(k.endswith("detections.parquet") for k in ray)  # the hook ran on the workers
    assert {k: v for k, v in serial.items() if not k.startswith("synthetic_sensors")} == ray


def test_caption_clips_and_tag_targets_with_workers_give_the_same_bytes(data: dict[str, Path]) -> None:
    from encoders.tagging.targets import add_attribute_targets
    from scenesearch_base.ray_cluster import Execution

    root, logs = data["root"], _logs(data)
    for name, extra in (("serial", []), ("ray", ["--workers", "2"])):
        assert main(["caption", *logs, "--out", str(root / f"captions_{name}"), *extra]) == 0
        assert main(["clips", *logs, "--captions", str(root / "captions_serial"), "--out", str(root / f"clips_{name}"),
                     "--frames-per-clip", "4", "--previews", *extra]) == 0
    captions = _tree(root / "captions_serial")
    assert set(captions) == {".scenesearch.json", "captions.parquet", "frame_tags.parquet", "logs.json"}
    assert captions == _tree(root / "captions_ray")
    serial, ray = (_tree(root / f"clips_{n}", skip=("render.json", "manifest.json")) for n in ("serial", "ray"))
    assert "clips.parquet" in serial and any(k.startswith("previews/") for k in serial)
    assert any(k.endswith("camera.blocks") for k in serial) and serial == ray
    manifests = [json.loads((root / f"clips_{n}" / "manifest.json").read_text()) for n in ("serial", "ray")]
    assert _without_timing(manifests[0]) == _without_timing(manifests[1])
    assert manifests[0]["logs"]["synthetic_sensors"]["bev_source"] == "lidar"
    for name, execution in (("serial", None), ("ray", Execution(workers=2))):
        report = add_attribute_targets(root / f"clips_{name}", logs, execution=execution)
        assert len(report.written) == len(logs)
    targets = [{k: v for k, v in _tree(root / f"clips_{n}" / "logs").items() if "bev_attributes" in k}
               for n in ("serial", "ray")]
    assert len(targets[0]) == 2 * len(logs) and targets[0] == targets[1]


def test_uris_in_and_out(data: dict[str, Path]) -> None:
    root = data["root"]
    logs_uri = f"file://{data['logs']}/*"
    if not (root / "captions_serial" / "captions.parquet").exists():
        pytest.skip("needs the serial outputs of the test before")
    assert main(["caption", logs_uri, "--out", f"file://{root / 'captions_uri'}", "--workers", "2"]) == 0
    assert _tree(root / "captions_uri") == _tree(root / "captions_serial")
    assert main(["clips", logs_uri, "--captions", f"file://{root / 'captions_uri'}",
                 "--out", f"file://{root / 'clips_uri'}", "--frames-per-clip", "4", "--previews"]) == 0
    skip = ("render.json", "manifest.json", "bev_attributes.blocks", "bev_attributes.json")
    assert _tree(root / "clips_uri", skip) == _tree(root / "clips_serial", skip)


def test_a_worker_dying_mid_log_is_retried_then_reported(data: dict[str, Path], tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    import ray

    import captioning.batch as batch

    ray.cloudpickle.register_pickle_by_value(scale_faults)
    logs = _logs(data)
    once, always = Path(logs[0]).name, Path(logs[1]).name
    monkeypatch.setattr(batch, "caption_log_dir",
                        scale_faults.dying_on(batch.caption_log_dir, str(tmp_path), once, always))
    code = main(["caption", *logs, "--out", str(tmp_path / "captions"), "--workers", "2"])
    out = capsys.readouterr().out
    assert code == 1
    assert f"failed log {logs[1]}: the worker died on each of 3 attempt(s)" in out
    assert f"captioned {len(logs) - 1} of {len(logs)} logs" in out and f"1 log(s) failed: {logs[1]}" in out
    import pyarrow.parquet as pq

    written = set(pq.read_table(tmp_path / "captions" / "captions.parquet").column("log_id").to_pylist())
    assert once in written and always not in written and len(written) == len(logs) - 1


def test_index_embeddings_on_ray_data_equal_the_serial_ones(data: dict[str, Path], tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    from retrieval.embedding import ModelEmbedder, RayDataEmbedder
    from retrieval.scenesearch import SceneSearch
    from scenesearch_base.ray_cluster import Execution

    clips = data["root"] / "clips_serial"
    if not (clips / "clips.parquet").exists():
        pytest.skip("needs the clips of the test before")
    run = tmp_path / "run"
    assert main(["train", str(clips), "--out", str(run), "--preset", "tiny", "--epochs", "1"]) == 0
    shards = tmp_path / "shards"
    shards.mkdir()
    (shards / "part-0000009999.parquet").write_bytes(b"a shard of an earlier run")  # replaced
    (shards / "notes.txt").write_text("the user's")  # kept
    serial = SceneSearch.build(run, clips, tmp_path / "index_serial", embedder=ModelEmbedder(run),
                               text_encoder=HashTextEncoder())
    embedder = RayDataEmbedder(run, Execution(workers=2), shards, batch_size=8)
    on_ray = SceneSearch.build(run, clips, tmp_path / "index_ray", embedder=embedder, text_encoder=HashTextEncoder())
    # Both CPUs of this one node, on one model (see cpu_actors).
    assert embedder.last_run["actors"] * embedder.last_run["threads_per_actor"] == 2
    # One shard per block of whole batches, named by its first row, written by the actors.
    n = int(embedder.last_run["clips"])
    names = sorted(p.name for p in shards.glob("part-*.parquet"))
    assert len(names) == embedder.last_run["shards"] == min(-(-n // 8), 64)
    assert all(int(name[5:15]) % 8 == 0 for name in names) and names[0] == "part-0000000000.parquet"
    assert (shards / "notes.txt").read_text() == "the user's"
    for view in ("fused", "camera", "bev"):
        meta_a, a = serial.embeddings(view)
        meta_b, b = on_ray.embeddings(view)
        assert meta_a.column("clip_id").to_pylist() == meta_b.column("clip_id").to_pylist()
        assert a.shape == b.shape and a.shape[0] > 10
        np.testing.assert_allclose(a, b, atol=1e-4)

    # An actor dying mid-block: started anew, it embeds the block again and writes its shard whole.
    import ray

    import retrieval.embedding as embedding

    ray.cloudpickle.register_pickle_by_value(scale_faults)
    monkeypatch.setattr(embedding, "ClipEmbedActor", scale_faults.dying_actor(embedding.ClipEmbedActor, str(tmp_path)))
    again = RayDataEmbedder(run, Execution(workers=2), shards, batch_size=8)
    for view in ("fused", "camera", "bev"):
        ids_a, a = embedder.embed_clips(clips, view=view)
        ids_b, b = again.embed_clips(clips, view=view)
        assert ids_a == ids_b
        np.testing.assert_allclose(a, b, atol=1e-6)
    assert (tmp_path / "embed.tried").exists()  # the actor did die
    assert sorted(p.name for p in shards.glob("part-*.parquet")) == names


def test_cpu_actors_take_a_node_each_on_its_cpus() -> None:
    from retrieval.embedding import cpu_actors

    assert cpu_actors(2, [2]) == (1, 2)  # this machine, --workers 2: one model on 2 threads
    assert cpu_actors(1, [2]) == (1, 1)  # --workers 1
    assert cpu_actors(64, [16, 16, 16, 16]) == (4, 16)  # a cluster: an actor per node
    assert cpu_actors(48, [16, 8, 32]) == (6, 8)  # the smallest node fits an actor everywhere
    assert cpu_actors(4, []) == (4, 1)  # nodes unknown: one thread per actor
