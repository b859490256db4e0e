"""Exact resume on a clips folder with tag targets: 2 epochs straight equal 1 epoch, a kill, and 1 resumed.

Every configuration: with and without the tagging head (its own optimiser, weights and window draws
live in the checkpoint), with a scratch and with a frozen pretrained text tower.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
import torch
from safetensors.torch import load_file

from encoders.checkpoints import read_checkpoint
from encoders.config import ConfigMismatchError, TextConfig
from encoders.presets import preset
from encoders.sentence import TextModelUnavailableError
from encoders.tagging.config import TagTrainConfig
from encoders.train import train
from encoders.train_config import TrainConfig
from tests.encoders.tagging_fixtures import build_tagging_fixture

TIMING = {"samples_per_s", "epoch_s"}
TAGS = TagTrainConfig(batch_size=2, window_frames=3)
NO_TAGS = TagTrainConfig(mode="alone")


class Killed(Exception):
    pass


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    # Five logs put two in the training split: 6 clips, so an epoch has 2 steps of 2 clips.
    fixture = build_tagging_fixture(tmp_path_factory.mktemp("resume"), num_logs=5, num_frames=8, steps=1)
    return Path(str(fixture["clips"]))


def config(text: str) -> TrainConfig:
    tiny = preset("tiny").train
    model = tiny.model
    if text == "frozen":  # the pretrained sentence encoder, frozen: its embeddings come from the text cache
        model = dataclasses.replace(model, text=TextConfig(kind="pretrained", freeze=True, cache=True))
    return dataclasses.replace(tiny, model=model, epochs=2, batch_size=2, max_steps_per_epoch=2, device="cpu")


def run(clips: Path, out: Path, cfg: TrainConfig, tagging: TagTrainConfig, **kwargs: Any) -> list[str]:
    torch.set_num_threads(1)
    lines: list[str] = []
    try:
        train(clips, out, cfg, tagging=tagging, log=lines.append, progress=False, **kwargs)
    except TextModelUnavailableError as exc:
        pytest.skip(f"the pretrained sentence encoder is not installed: {exc}")
    return lines


def kill_after_first_epoch(epoch: int) -> None:
    if epoch == 1:
        raise Killed


def metrics(run_dir: Path) -> list[dict[str, Any]]:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def assert_same_weights(a: Path, b: Path) -> None:
    x, y = load_file(str(a)), load_file(str(b))
    assert x.keys() == y.keys()
    differ = [k for k in x if not torch.equal(x[k], y[k])]
    assert not differ, f"{a.name}: {len(differ)} tensors differ, e.g. {differ[:3]}"


@pytest.mark.parametrize("text", ["scratch", "frozen"])
@pytest.mark.parametrize("tags", [True, False], ids=["tags", "no_tags"])
def test_resume_reproduces_the_straight_run(clips: Path, tmp_path: Path, tags: bool, text: str) -> None:
    cfg, tagging = config(text), (TAGS if tags else NO_TAGS)
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    lines = run(clips, straight, cfg, tagging)
    assert any(line.startswith("tagging on") for line in lines) == tags

    with pytest.raises(Killed):
        run(clips, resumed, cfg, tagging, on_epoch_end=kill_after_first_epoch)
    # A kill after the checkpoint but before the metrics row: the checkpoint's rows are restored.
    (resumed / "metrics.jsonl").write_text("")
    run(clips, resumed, cfg, tagging, resume=True)

    assert metrics(resumed) == metrics(straight)
    assert [(r["epoch"], r["step"]) for r in metrics(resumed)] == [(1, 2), (2, 4)]
    assert_same_weights(resumed / "model.safetensors", straight / "model.safetensors")
    assert (resumed / "tag_head.safetensors").exists() == tags
    if tags:
        assert_same_weights(resumed / "tag_head.safetensors", straight / "tag_head.safetensors")
        checkpoint = read_checkpoint(resumed / "checkpoints" / "last.pt")
        assert checkpoint.tagging is not None and checkpoint.tagging["state"]["batches_drawn"] == 4
        assert checkpoint.tagging["state"]["optimizer"]["state"]  # AdamW moments of the head


class WithEgoSentence(torch.utils.data.Dataset[dict[str, Any]]):
    """The training clips with captions of two sentences, as captioning writes them: the fixture's
    one-sentence captions after an ego sentence."""

    def __init__(self, clips: Path) -> None:
        from encoders.data import ClipDataset

        self.base = ClipDataset(clips, split="train", augment=True)

    def __len__(self) -> int:
        return len(self.base)

    def __getattr__(self, name: str) -> Any:  # set_epoch, camera_flags, …: the clips' own
        return getattr(self.__dict__["base"], name)

    @staticmethod
    def two_sentences(index: int, caption: str) -> str:
        ego = "The ego vehicle is cruising straight." if index % 2 else "The ego vehicle is stationary."
        return f"{ego} {caption.capitalize()}."

    def __getitem__(self, index: int) -> dict[str, Any]:
        item = self.base[index]
        return {**item, **{k: self.two_sentences(index, str(item[k])) for k in ("caption", "canonical_caption")}}

    def __getitems__(self, indices: list[int]) -> dict[str, Any]:  # what the DataLoader asks for
        batch = self.base.__getitems__(indices)
        for key in ("caption", "canonical_caption"):
            batch[key] = [self.two_sentences(i, str(c)) for i, c in zip(indices, batch[key])]
        return batch


def test_resume_with_partial_queries_reproduces_the_straight_run(clips: Path, tmp_path: Path) -> None:
    from encoders.partial_queries import batch_partials

    data = WithEgoSentence(clips)
    assert batch_partials(data.__getitems__([0, 1]), 0, 0, 1.0, 0.0).texts  # the captions have halves to ask
    cfg = dataclasses.replace(config("scratch"), partial_weight=0.5)
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    run(clips, straight, cfg, NO_TAGS, datasets={"train": data})
    with pytest.raises(Killed):
        run(clips, resumed, cfg, NO_TAGS, on_epoch_end=kill_after_first_epoch, datasets={"train": data})
    run(clips, resumed, cfg, NO_TAGS, resume=True, datasets={"train": data})
    assert metrics(resumed) == metrics(straight)
    assert_same_weights(resumed / "model.safetensors", straight / "model.safetensors")
    # The halves change the training: the same run without them ends elsewhere.
    without = tmp_path / "without"
    run(clips, without, config("scratch"), NO_TAGS, datasets={"train": data})
    assert metrics(without)[0]["train_loss"] != metrics(straight)[0]["train_loss"]


def test_resume_refuses_another_tagging_setup_unless_forced(clips: Path, tmp_path: Path) -> None:
    out, cfg = tmp_path / "run", config("scratch")
    with pytest.raises(Killed):
        run(clips, out, cfg, TAGS, on_epoch_end=kill_after_first_epoch)
    with pytest.raises(ConfigMismatchError, match=r"tagging\.batch_size: 2 -> 4"):
        run(clips, out, cfg, dataclasses.replace(TAGS, batch_size=4), resume=True)
    with pytest.raises(ConfigMismatchError, match="the checkpoint has a tagging head and this run has no"):
        run(clips, out, cfg, NO_TAGS, resume=True)
    run(clips, out, cfg, NO_TAGS, resume=True, force=True)
    assert [r["epoch"] for r in metrics(out)] == [1, 2]

    other = tmp_path / "other"
    with pytest.raises(Killed):
        run(clips, other, cfg, NO_TAGS, on_epoch_end=kill_after_first_epoch)
    with pytest.raises(ConfigMismatchError, match="the checkpoint has no tagging head and this run has a"):
        run(clips, other, cfg, TAGS, resume=True)
    lines = run(clips, other, cfg, TAGS, resume=True, force=True)
    assert any("tagging head starts afresh" in line for line in lines)


def test_validation_between_epochs_does_not_change_the_training(clips: Path, tmp_path: Path) -> None:
    # Validation encodes its captions with the frozen encoder; kept out of training's text cache, it
    # cannot change which strings a later step encodes together, and so their rounding.
    import numpy as np

    from encoders.text import TEXT_CACHE_FILE

    def cached(run_dir: Path) -> set[str]:
        with np.load(run_dir / TEXT_CACHE_FILE) as f:
            return set(f["keys"].tolist())

    runs = {every: tmp_path / f"every_{every}" for every in (1, 2)}
    for every, out in runs.items():
        with pytest.raises(Killed):
            run(clips, out, dataclasses.replace(config("frozen"), eval_every=every), NO_TAGS,
                on_epoch_end=kill_after_first_epoch)
    assert "val" in metrics(runs[1])[0] and "val" not in metrics(runs[2])[0]
    first_epoch = cached(runs[2])
    assert cached(runs[1]) == first_epoch  # what the second epoch starts from
    for every, out in runs.items():
        run(clips, out, dataclasses.replace(config("frozen"), eval_every=every), NO_TAGS, resume=True)
    assert metrics(runs[1])[1] == metrics(runs[2])[1]
    assert_same_weights(runs[1] / "model.safetensors", runs[2] / "model.safetensors")
    # Once training is done, the run's cache serves the validation captions too.
    assert cached(runs[1]) == cached(runs[2]) > first_epoch
