"""Data-parallel training (encoders.distributed): 2 processes with batch b give the loss and gradients of
1 process with batch 2b, a distributed run resumes exactly (``--nproc`` and torchrun), bad input is refused.

The equivalence runs every per-batch part at once: batch norms, the fusion's modality dropout with one
process's share holding no camera clip, frames shuffled in time, hard negatives counted differently per
process, and the tagging objective (a clips folder with tag targets).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import load_file

from encoders.distributed import (
    Distributed,
    GlobalBatchNorm,
    TooFewClipsError,
    check_processes,
    launch,
    sync_batch_norms,
)
from encoders.loss import contrastive_loss, positives_matrix
from encoders.presets import preset
from encoders.tagging.config import TagTrainConfig
from encoders.train_config import HardNegative, TrainConfig
from retrieval.cli import main
from tests.encoders.synthetic import CaptionedClips
from tests.encoders.tagging_fixtures import build_tagging_fixture

ROOT = Path(__file__).resolve().parents[2]
TIMING = {"samples_per_s", "epoch_s"}
B = 4  # clips per process and step (synthetic clips)


def Clips(size: int = 16) -> CaptionedClips:
    """Synthetic clips captioned as a clips folder's; camera on a few clips only, so that in the first step
    one process's share has none and the other's has some (the camera view's own loss, ``view_weight``,
    then has kept clips on one process only); frame tags on some frames only, so that the processes hold
    unequal shares of the dense targets."""
    first = np.random.default_rng([0, 0]).permutation(size)  # EpochSampler's order of epoch 0 (seed 0)
    camera = {int(i) for i in first[B : B + 2]} | {int(first[-1])}
    return CaptionedClips(size, camera.__contains__, augment=True)


def setup(name: str, clips: Path, processes: int) -> tuple[TrainConfig, dict[str, Any]]:
    """The config and keyword arguments of run ``name`` with ``processes`` (batch sizes per process).

    ``tagged`` keeps the tag windows few and short: float32 sums over many BEV cells differ by ~1e-5
    between two summation orders already (one process on 1 and on 2 threads), whatever the processes.
    ``resumable`` is what the command line trains (the default tagging), to be resumed by it.
    """
    tiny = dataclasses.replace(preset("tiny").train, device="cpu", max_steps_per_epoch=1)
    scale = 2 // processes  # one process takes the whole batch
    if name == "synthetic":
        model = dataclasses.replace(tiny.model, dense_streams=("camera", "track"),
                                    bev=dataclasses.replace(tiny.model.bev, track_velocity=True))
        cfg = dataclasses.replace(tiny, model=model, batch_size=B * scale, epochs=3, shuffle_frames=True,
                                  hard_negatives=tuple(HardNegative), view_weight=0.5, dense_weight=0.5,
                                  order_weight=0.5, partial_weight=0.5)
        return cfg, {"clips_dir": "unused", "datasets": {"train": Clips()}}
    cfg = dataclasses.replace(tiny, batch_size=2 * scale, epochs=2)
    if name == "resumable":
        return cfg, {"clips_dir": clips}
    return cfg, {"clips_dir": clips, "tagging": TagTrainConfig(batch_size=2 * scale, window_frames=3)}


def recording(records: list[dict[str, np.ndarray]]) -> Callable[..., torch.optim.Optimizer]:
    """encoders.train.build_optimizer that records every step's gradients (as the optimiser sees them)."""
    from encoders import train as training

    real = training.build_optimizer

    def build(model: torch.nn.Module, config: TrainConfig) -> torch.optim.Optimizer:
        opt = real(model, config)  # type: ignore[arg-type]
        names = {id(p): n for n, p in model.named_parameters()}
        step = opt.step

        def recorded(*args: Any, **kwargs: Any) -> Any:
            records.append({names[id(p)]: p.grad.detach().numpy().copy() for group in opt.param_groups
                            for p in group["params"] if p.grad is not None})
            return step(*args, **kwargs)

        opt.step = recorded  # type: ignore[method-assign]
        return opt

    return build


def run(name: str, clips: Path, out: Path, distributed: Distributed | None = None,
        on_epoch_end: Callable[[int], None] | None = None) -> list[dict[str, np.ndarray]]:
    from encoders import train as training

    records: list[dict[str, np.ndarray]] = []
    real = training.build_optimizer
    training.build_optimizer = recording(records)  # type: ignore[assignment]
    try:
        cfg, kwargs = setup(name, clips, distributed.processes if distributed else 1)
        clips_dir = kwargs.pop("clips_dir")
        training.train(clips_dir, out / name, cfg, progress=False, log=lambda _m: None, distributed=distributed,
                       on_epoch_end=on_epoch_end, **kwargs)
    finally:
        training.build_optimizer = real
    return records


def two_processes(clips: Path, out: Path) -> dict[str, list[dict[str, np.ndarray]]]:
    """The runs on 2 processes (one of the launched processes); ``resumable`` is copied after epoch 1."""
    from encoders.distributed import process_group

    with process_group("cpu") as dp:
        def snapshot(epoch: int) -> None:
            if epoch == 1 and dp.is_main:
                for copy in ("cli", "torchrun"):
                    shutil.copytree(out / "resumable", out / f"resumable_epoch1_{copy}")

        return {name: run(name, clips, out, dp, snapshot if name == "resumable" else None)
                for name in ("synthetic", "tagged", "resumable")}


def metrics(run_dir: Path) -> list[dict[str, Any]]:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    # Five logs of 12 frames: 6 training clips (3 steps of 2 on one process), and windows for the tag head.
    fixture = build_tagging_fixture(tmp_path_factory.mktemp("clips"), num_logs=5, num_frames=12, steps=1)
    return Path(str(fixture["clips"]))


@pytest.fixture(scope="module")
def runs(clips: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The runs on 2 processes (elastic launcher) and on 1 process with the whole batch."""
    torch.set_num_threads(1)
    two, one = tmp_path_factory.mktemp("two"), tmp_path_factory.mktemp("one")
    grads_two = launch(2, two_processes, clips, two)
    grads_one = {name: run(name, clips, one) for name in ("synthetic", "tagged")}
    return {"two": two, "one": one, "grads_two": grads_two, "grads_one": grads_one}


# --- the equivalence -------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("name", ["synthetic", "tagged"])
def test_two_processes_give_the_loss_and_gradients_of_one_with_the_whole_batch(runs: dict[str, Any],
                                                                                name: str) -> None:
    two, one = metrics(runs["two"] / name), metrics(runs["one"] / name)
    assert [r["processes"] for r in two] == [2] * len(two) and "processes" not in one[0]
    assert len(two) == len(one) >= 2
    for a, b in zip(two, one):
        assert abs(a["train_loss"] - b["train_loss"]) < 1e-5, (a, b)
    steps_two, steps_one = runs["grads_two"][name], runs["grads_one"][name]
    assert len(steps_two) == len(steps_one) == len(one)
    for step, (g2, g1) in enumerate(zip(steps_two, steps_one)):
        assert g2.keys() == g1.keys(), step
        # Within float32 noise (summation order over every BEV cell of every window, and the near-tied hard
        # negatives it can reorder), which grows with the loss's scale: worst 2.5e-6 with the presence term
        # at weight 1, 1.2e-5 at 5, on gradients up to 0.017. A wrong reduction would be off by a factor.
        bound = {k: 1e-5 + 1e-3 * float(np.abs(g1[k]).max()) for k in g1}
        diff = {k: float(np.abs(g2[k] - g1[k]).max()) for k in g1}
        where = max(g1, key=lambda k: diff[k] - bound[k])
        assert diff[where] < bound[where], f"step {step}: gradients of {where} differ by {diff[where]}"
    # The gradients are not trivially equal: the camera tower, the batch norms and the tag head train.
    assert any(float(np.abs(g).max()) > 1e-3 for k, g in steps_one[0].items() if ".1.weight" in k)
    if name == "synthetic":  # the camera tower and both dense heads (camera clips on one process only) train
        assert all(any(k.startswith(p) for k in steps_one[0]) for p in ("camera.", "dense.camera.", "dense.track."))
    weights = [load_file(str(runs[d] / name / "model.safetensors")) for d in ("two", "one")]
    assert max(float((weights[0][k] - weights[1][k]).abs().max()) for k in weights[1]) < 1e-4


@pytest.mark.slow
def test_only_rank_0_writes_and_tagging_trains(runs: dict[str, Any]) -> None:
    run_dir = runs["two"] / "tagged"
    for f in ("config.json", "metrics.jsonl", "checkpoints/last.pt", "model.safetensors", "model_card.md",
              "tagging.json", "tag_head.safetensors"):
        assert (run_dir / f).is_file(), f
    assert len((run_dir / "metrics.jsonl").read_text().splitlines()) == 2  # one writer, one row per epoch
    head = [load_file(str(runs[d] / "tagged" / "tag_head.safetensors")) for d in ("two", "one")]
    assert max(float((head[0][k] - head[1][k]).abs().max()) for k in head[1]) < 1e-4


# --- resume ----------------------------------------------------------------------------------------------
def assert_same_run(a: Path, b: Path) -> None:
    assert metrics(a) == metrics(b)
    for f in ("model.safetensors", "tag_head.safetensors"):
        x, y = load_file(str(a / f)), load_file(str(b / f))
        differ = [k for k in x if not torch.equal(x[k], y[k])]
        assert not differ, f"{f}: {differ[:3]}"


@pytest.mark.slow
def test_nproc_resumes_a_two_process_run_exactly(runs: dict[str, Any], clips: Path) -> None:
    resumed = runs["two"] / "resumable_epoch1_cli"
    assert len(metrics(resumed)) == 1
    assert main(["train", str(clips), "--out", str(resumed), "--resume", "--nproc", "2"]) == 0
    assert_same_run(resumed, runs["two"] / "resumable")


@pytest.mark.slow
def test_torchrun_resumes_a_two_process_run_exactly(runs: dict[str, Any], clips: Path) -> None:
    resumed = runs["two"] / "resumable_epoch1_torchrun"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
               "-m", "retrieval.cli", "train", str(clips), "--out", str(resumed), "--resume"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("trained 2 epochs") == 1  # rank 0 reports
    assert_same_run(resumed, runs["two"] / "resumable")


@pytest.mark.slow
def test_resuming_on_another_number_of_processes_is_refused(runs: dict[str, Any], clips: Path, tmp_path: Path,
                                                           capfd: pytest.CaptureFixture[str]) -> None:
    # A 2-process run on 1 process; a 1-process run on 2 (rank 0 of the launched processes reports).
    assert main(["train", str(clips), "--out", str(runs["two"] / "resumable"), "--resume", "--epochs", "3"]) == 2
    assert "trained on 2 process(es) and this run has 1" in capfd.readouterr().err
    one = ["train", str(clips), "--out", str(tmp_path / "one"), "--preset", "tiny", "--batch-size", "2",
           "--set", "max_steps_per_epoch=1"]
    assert main([*one, "--epochs", "1"]) == 0
    capfd.readouterr()
    assert main([*one, "--epochs", "2", "--resume", "--nproc", "2"]) == 2
    err = capfd.readouterr().err
    assert err.count("scenesearch train: error: the checkpoint was trained on 1 process(es) and this run has 2") == 1
    assert "Traceback" not in err
    from encoders.config import ConfigMismatchError
    from encoders.train import train

    cfg, kwargs = setup("tagged", clips, 1)
    with pytest.raises(ConfigMismatchError, match="trained on 1 process"):
        train(kwargs.pop("clips_dir"), runs["one"] / "tagged", cfg, resume=True, progress=False,
              log=lambda _m: None, distributed=Distributed(rank=0, processes=2), **kwargs)


# --- bad input, before any process starts -----------------------------------------------------------------
def test_more_processes_than_the_data_fills_is_refused_before_launching(clips: Path, tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    base = ["train", str(clips), "--out", str(out), "--preset", "tiny", "--epochs", "1"]
    assert main([*base, "--batch-size", "2", "--nproc", "4"]) == 2
    err = capsys.readouterr().err
    assert "6 training clips cannot fill one step of 4 processes × batch size 2 = 8 clips" in err
    assert main([*base, "--batch-size", "1", "--nproc", "7"]) == 2  # more processes than clips
    assert "6 training clips" in capsys.readouterr().err
    assert main([*base, "--nproc", "0"]) == 2
    assert "--nproc must be >= 1" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(TooFewClipsError, match="train: 3 training clips"):
        check_processes(3, 1, 4, "train")
    check_processes(3, 8, 1, "train")  # one process takes what there is


# --- the parts --------------------------------------------------------------------------------------------
def test_loss_over_each_process_rows_averages_to_the_whole_batch_loss() -> None:
    g = torch.Generator().manual_seed(0)
    video = F.normalize(torch.randn(8, 16, generator=g), dim=-1).requires_grad_()
    text = F.normalize(torch.randn(8, 16, generator=g), dim=-1).requires_grad_()
    negatives = F.normalize(torch.randn(5, 16, generator=g), dim=-1)
    own = torch.rand(8, 5, generator=g) < 0.2
    positives = positives_matrix([0, 1, 0, 2, 3, 1, 4, 4])
    scale = torch.tensor(10.0)
    whole = contrastive_loss(video, text, scale, positives, negatives, own)
    parts = [contrastive_loss(video, text, scale, positives, negatives, own, rows=rows)
             for rows in (slice(0, 4), slice(4, 8))]
    assert torch.allclose(whole, sum(parts) / 2, atol=1e-6)
    grads = [torch.autograd.grad(loss, (video, text)) for loss in (whole, sum(parts) / 2)]
    assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(*grads))
    assert not torch.allclose(parts[0], parts[1], atol=1e-3)


def test_global_batch_norm_keeps_the_model_and_is_batch_norm_on_one_process() -> None:
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4), torch.nn.Sequential(
        torch.nn.BatchNorm2d(4)))
    plain = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    keys, weight = list(net.state_dict()), plain[0].weight
    x = torch.randn(5, 3, 8, 8)
    before = net(x)
    for m in plain:  # the same statistics again for the second pass
        m.reset_running_stats()
    sync_batch_norms(net)
    assert sum(isinstance(m, GlobalBatchNorm) for m in net.modules()) == 2
    assert list(net.state_dict()) == keys and net[1].weight is weight
    assert torch.allclose(net(x), before)
    assert Distributed().rows(4) is None and Distributed(rank=1, processes=3).rows(4) == slice(4, 8)
