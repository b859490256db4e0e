"""Training runs of a tiny model on synthetic clips: outputs, exact resume, NaN stop, bad input."""

from __future__ import annotations

import dataclasses
import json
import random
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from encoders.calibration import CAMERA_WEIGHTS
from encoders.checkpoints import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    check_resume_config,
    read_checkpoint,
    restore_rng,
    rng_state,
)
from encoders.config import ConfigMismatchError
from encoders.inference import load_model, shuffle_time
from encoders.presets import preset
from encoders.train import NonFiniteLossError, NoTrainingSplitError, evaluate, learning_rate, train
from encoders.train_config import TrainConfig
from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec

SPEC = SyntheticSpec(frames=6, camera_hw=(24, 32), bev_hw=(24, 12), distractors=1)
TIMING = {"samples_per_s", "epoch_s"}


class Killed(Exception):
    pass


def datasets() -> dict[str, Any]:
    return {
        "train": SyntheticClipDataset(16, "train", SPEC, seed=1, augment=True),
        "val": SyntheticClipDataset(8, "val", SPEC, seed=1),
    }


def config(**changes: Any) -> TrainConfig:
    return dataclasses.replace(preset("tiny").train, batch_size=8, epochs=2, **changes)


def run(out: Path, cfg: TrainConfig, **kwargs: Any) -> Any:
    torch.set_num_threads(1)
    return train("unused", out, cfg, datasets=datasets(), progress=False, log=lambda _m: None, **kwargs)


def metrics(run_dir: Path) -> list[dict[str, Any]]:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


@pytest.fixture(scope="module")
def straight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("straight") / "run"
    run(out, config())
    return out


def test_camera_share_gives_every_batch_its_camera_clips(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import encoders.train as train_module

    seen: list[list[bool]] = []

    class Spy(train_module.DataLoader):  # type: ignore[misc,type-arg]
        def __iter__(self) -> Any:
            for batch in super().__iter__():
                seen.append(batch["has_camera"].tolist())
                yield batch

    monkeypatch.setattr(train_module, "DataLoader", Spy)
    sparse = dataclasses.replace(SPEC, camera_fraction=0.15)
    data = {"train": SyntheticClipDataset(24, "train", sparse, seed=1, augment=True),
            "val": SyntheticClipDataset(8, "val", sparse, seed=1)}
    flags = train_module.camera_flags(data["train"])
    assert 0 < flags.sum() < 0.5 * len(flags)  # fewer camera clips than the share asks for
    assert flags.tolist() == [data["train"][i]["has_camera"] for i in range(len(flags))]
    with pytest.raises(train_module.TrainingError, match="camera_flags, which list lacks"):
        train_module.camera_flags([data["train"][0]])  # type: ignore[arg-type]
    torch.set_num_threads(1)
    train("unused", tmp_path / "run", config(camera_share=0.5), datasets=data, progress=False, log=lambda _m: None)
    assert len(seen) == 6 and all(len(b) == 8 and sum(b) == 4 for b in seen)  # 3 steps × 2 epochs


def test_run_writes_its_files_and_loads(straight: Path) -> None:
    for name in ("config.json", "model.safetensors", "metrics.jsonl", "checkpoints/last.pt", "model_card.md"):
        assert (straight / name).is_file(), name
    rows = metrics(straight)
    assert [r["epoch"] for r in rows] == [1, 2] and [r["step"] for r in rows] == [2, 4]
    assert {"R@1", "R@5", "R@10", "median_rank", "mAP"} <= set(rows[-1]["val"])
    assert "R@1" in (straight / "model_card.md").read_text()
    model = load_model(straight)
    assert float(model.fusion.camera_weight) in CAMERA_WEIGHTS  # chosen after the last epoch
    model.fusion.set_camera_weight(1.0)  # the equal mean that the epochs trained and validated
    again = evaluate(model, datasets()["val"])
    assert again == pytest.approx(rows[-1]["val"])


def test_resume_after_kill_reproduces_the_straight_run(straight: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"

    def kill(epoch: int) -> None:
        if epoch == 1:
            raise Killed

    with pytest.raises(Killed):
        run(out, config(), on_epoch_end=kill)
    assert not (out / "model.safetensors").exists()
    with pytest.raises(FileExistsError):
        run(out, config())
    run(out, config(), resume=True)
    assert metrics(out) == metrics(straight)
    a, b = load_file(str(out / "model.safetensors")), load_file(str(straight / "model.safetensors"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_resume_with_another_config_needs_force(tmp_path: Path) -> None:
    out = tmp_path / "run"
    with pytest.raises(Killed):
        run(out, config(), on_epoch_end=lambda e: (_ for _ in ()).throw(Killed()))
    with pytest.raises(ConfigMismatchError, match=r"lr: 0\.001 -> 0\.01"):
        run(out, config(lr=0.01), resume=True)
    run(out, config(lr=0.01), resume=True, force=True)
    assert [r["epoch"] for r in metrics(out)] == [1, 2]


def test_resume_check_reads_the_saved_config_dict() -> None:
    saved = json.loads(json.dumps(config().to_dict(), sort_keys=True))  # as a checkpoint or config.json keeps it
    check_resume_config(dataclasses.replace(config(), epochs=5, device="cpu", num_workers=2), saved, done_epochs=2)
    with pytest.raises(ConfigMismatchError, match=r"model\.bev\.widths: \[8, 16\] -> \[8, 32\]"):
        tiny = config().model
        check_resume_config(config(model=dataclasses.replace(tiny, bev=dataclasses.replace(tiny.bev, widths=(8, 32)))),
                            saved, done_epochs=2)
    with pytest.raises(ConfigMismatchError, match="epochs=1 is fewer"):
        check_resume_config(dataclasses.replace(config(), epochs=1), saved, done_epochs=2)


def test_nan_loss_stops_with_step_and_clips_and_keeps_the_checkpoint(tmp_path: Path) -> None:
    class Poisoned(SyntheticClipDataset):
        poisoned = False

        def __getitem__(self, index: int) -> dict[str, Any]:
            item = super().__getitem__(index)
            if self.poisoned:
                item["bev_lidar"] = torch.full_like(item["bev_lidar"], float("nan"))
            return item

    data = {"train": Poisoned(16, "train", SPEC), "val": SyntheticClipDataset(8, "val", SPEC)}

    def poison(epoch: int) -> None:
        data["train"].poisoned = True  # type: ignore[attr-defined]

    out = tmp_path / "run"
    with pytest.raises(NonFiniteLossError, match=r"at step 2 \(epoch 2\), batch clips: synthetic-train:") as info:
        train("unused", out, config(), datasets=data, on_epoch_end=poison, progress=False, log=lambda _m: None)
    assert info.value.step == 2 and len(info.value.clip_ids) == 8
    state = read_checkpoint(out / "checkpoints" / "last.pt")
    assert state.epoch == 1 and state.step == 2 and [r["epoch"] for r in state.history] == [1]


def test_checkpoint_is_plain_tensors_and_json(straight: Path) -> None:
    path = straight / "checkpoints" / "last.pt"
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == CHECKPOINT_FORMAT and isinstance(raw["meta"], str) and raw["tagging"] is None
    meta = json.loads(raw["meta"])
    assert meta["epoch"] == 2 and meta["step"] == 4 and meta["config"]["batch_size"] == 8
    assert all(isinstance(v, torch.Tensor) for k, v in raw["rng"].items() if k != "cuda")
    state = read_checkpoint(path)
    assert [r["epoch"] for r in state.history] == [1, 2] and state.optimizer["state"]


def test_random_states_round_trip_through_a_weights_only_file(tmp_path: Path) -> None:
    random.gauss(0, 1)  # a cached Gaussian in Python's state
    np.random.standard_normal(3)
    torch.save(rng_state(), tmp_path / "rng.pt")
    draws = (random.random(), random.gauss(0, 1), np.random.standard_normal(2).tolist(), torch.rand(2).tolist())
    restore_rng(torch.load(tmp_path / "rng.pt", weights_only=True))
    assert (random.random(), random.gauss(0, 1), np.random.standard_normal(2).tolist(), torch.rand(2).tolist()) == draws


class Planted:
    """Unpickling it would create ``marker``: what loading an untrusted run folder must never do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (Path.touch, (self.marker,))


def killed_run(out: Path) -> Path:
    with pytest.raises(Killed):
        run(out, config(), on_epoch_end=lambda e: (_ for _ in ()).throw(Killed()))
    return out / "checkpoints" / "last.pt"


def test_a_checkpoint_with_a_pickled_object_is_refused(tmp_path: Path) -> None:
    path = killed_run(tmp_path / "run")
    raw = torch.load(path, weights_only=True)
    marker = tmp_path / "unpickled"
    torch.save({**raw, "extra": Planted(marker)}, path)
    with pytest.raises(CheckpointError, match=r"last\.pt: not a checkpoint that loads as plain tensors") as info:
        run(tmp_path / "run", config(), resume=True)
    assert str(path) in str(info.value)
    assert not marker.exists()


@pytest.mark.parametrize("damage", ["bytes", "old_format", "no_meta", "bad_meta", "not_dict"])
def test_damaged_checkpoints_name_the_file_and_part(tmp_path: Path, damage: str) -> None:
    path = killed_run(tmp_path / "run")
    raw = torch.load(path, weights_only=True)
    if damage == "bytes":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "old_format":
        torch.save({**raw, "format": 1}, path)
    elif damage == "no_meta":
        torch.save({k: v for k, v in raw.items() if k != "meta"}, path)
    elif damage == "bad_meta":
        torch.save({**raw, "meta": json.dumps({**json.loads(raw["meta"]), "step": "two"})}, path)
    else:
        torch.save([1, 2], path)
    expected = {"bytes": "not a checkpoint that loads", "old_format": "checkpoint format 1, this version reads 2",
                "no_meta": "checkpoint part 'meta' is missing",
                "bad_meta": "checkpoint part 'meta.step' is missing or not int",
                "not_dict": "not a checkpoint"}[damage]
    with pytest.raises(CheckpointError, match=re.escape(f"{path}: {expected}")):
        run(tmp_path / "run", config(), resume=True)


def test_no_training_split(tmp_path: Path) -> None:
    with pytest.raises(NoTrainingSplitError, match="'train' split"):
        train("clips", tmp_path / "run", config(), datasets={"train": SyntheticClipDataset(0)}, progress=False)
    with pytest.raises(FileNotFoundError):
        train(tmp_path / "missing", tmp_path / "run", config(), progress=False)


def test_warmup_then_cosine() -> None:
    cfg = config(lr=1.0, warmup_steps=4)
    lrs = [learning_rate(cfg, s, 20) for s in range(21)]
    assert lrs[:4] == [0.25, 0.5, 0.75, 1.0]
    assert lrs[4] == 1.0 and lrs[12] == pytest.approx(0.5) and lrs[20] == pytest.approx(0.0)
    assert all(a >= b for a, b in zip(lrs[4:], lrs[5:]))


def test_shuffle_time_permutes_every_view_alike() -> None:
    b, t = 3, 5
    frame = torch.arange(t, dtype=torch.float32)
    batch = {
        "bev_lidar": frame.reshape(1, t, 1, 1, 1).expand(b, t, 2, 2, 2).clone(),
        "camera": frame.reshape(1, t, 1, 1, 1).expand(b, t, 4, 3, 3).clone(),
        "ego_motion": frame.reshape(1, t, 1).expand(b, t, 4).clone(),
        "clip_id": ["a", "b", "c"],
    }
    out = shuffle_time(batch, torch.Generator().manual_seed(0))
    order = out["bev_lidar"][:, :, 0, 0, 0]
    assert torch.equal(out["camera"][:, :, 0, 0, 0], order) and torch.equal(out["ego_motion"][:, :, 0], order)
    assert torch.equal(order.sort(dim=1).values, frame.expand(b, t)) and not torch.equal(order, frame.expand(b, t))
    assert out["clip_id"] == batch["clip_id"]


class DimmedCamera(torch.utils.data.Dataset):  # type: ignore[type-arg]
    """A dataset's clips with their camera pixels halved: the same draws, other camera inputs."""

    def __init__(self, base: SyntheticClipDataset) -> None:
        self.base = base

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, i: int) -> dict[str, Any]:
        item = dict(self.base[i])
        item["camera"] = item["camera"] * 0.5
        return item

    def __getattr__(self, name: str) -> Any:  # camera_flags and the rest of the dataset's attributes
        return getattr(self.base, name)


@pytest.mark.parametrize("apart", [True, False])
def test_camera_apart_leaves_the_shared_towers_to_the_captions_and_bev(tmp_path: Path, apart: bool) -> None:
    # The fused view never sees the camera here (dropped whenever both views are present), so only the
    # camera view's own loss could carry the camera's pixels into the text and BEV towers; no gradient
    # clipping, whose global norm would mix the towers' gradients.
    model = preset("tiny").train.model
    model = dataclasses.replace(model, fusion=dataclasses.replace(model.fusion, drop_camera_p=1.0, drop_bev_p=0.0))
    cfg = config(model=model, camera_apart=apart, grad_clip=0.0, calibrate_camera=False)
    shared = ("text.", "bev.", "fusion.mlp.")
    weights = []
    for name, dim in (("plain", False), ("dimmed", True)):
        data = datasets()
        if dim:
            data = {split: DimmedCamera(d) for split, d in data.items()}
        torch.set_num_threads(1)
        train("unused", tmp_path / name, cfg, datasets=data, progress=False, log=lambda _m: None)
        weights.append(load_file(str(tmp_path / name / "model.safetensors")))
    plain, dimmed = weights
    same = [k for k in plain if k.startswith(shared) and torch.equal(plain[k], dimmed[k])]
    assert any(k.startswith(shared) for k in plain)
    if apart:  # the camera's pixels reach its own tower only
        assert same == [k for k in plain if k.startswith(shared)]
        assert not all(torch.equal(plain[k], dimmed[k]) for k in plain if k.startswith("camera."))
    else:  # its view loss moves the captions' vectors towards what it sees
        assert not all(torch.equal(plain[k], dimmed[k]) for k in plain if k.startswith("text."))
