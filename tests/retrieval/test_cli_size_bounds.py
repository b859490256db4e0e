"""Size flags of the commands: a value above its upper bound stops the command at once, naming the flag."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from encoders.train_config import TrainConfig
from retrieval.cli import main
from retrieval.commands import demo, index
from retrieval.demo_config import DemoConfig


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "{tmp}/clips", "--out", "{tmp}/run", "--epochs", "1000000000"],
         "--epochs 1000000000: key 'epochs': 1000000000 is above its upper bound 10000"),
        (["train", "{tmp}/clips", "--out", "{tmp}/run", "--set", "model.time_slots=100000"],
         "--set: key 'model.time_slots': 100000 is above its upper bound 256"),
        (["train", "{tmp}/clips", "--out", "{tmp}/run", "--nproc", "100000"],
         "--nproc 100000: above its upper bound 256"),
        (["simulate", "--out", "{tmp}/logs", "--logs", "1000000000"],
         "--logs 1000000000: key 'logs': 1000000000 is above its upper bound 100000"),
        (["simulate", "--out", "{tmp}/logs", "--duration-s", "86400"],
         "--duration-s 86400.0: key 'duration_s': 86400.0 is above its upper bound 3600"),
        (["render-sensors", "{tmp}/log", "--width", "100000"],
         "--width 100000: key 'width_px': 100000 is above its upper bound 4096"),
        (["render-sensors", "{tmp}/log", "--beams", "1000"],
         "--beams 1000: key 'beams': 1000 is above its upper bound 256"),
        (["index", "{tmp}/run", "{tmp}/clips", "--out", "{tmp}/index", "--batch-size", "100000"],
         "--batch-size 100000: above its upper bound 4096"),
        (["index", "{tmp}/run", "{tmp}/clips", "--out", "{tmp}/index", "--num-workers", "100000"],
         "--num-workers 100000: above its upper bound 256"),
        (["demo", "--out", "{tmp}/demo", "--logs", "1000000000"], "--logs 1000000000: above its upper bound 100000"),
        (["demo", "--out", "{tmp}/demo", "--camera-width-px", "100000"],
         "--camera-width-px 100000: above its upper bound 4096"),
    ],
)
def test_a_size_flag_above_its_bound_exits_2_naming_the_flag(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert f"scenesearch {argv[0]}: error: {message}" in err
    assert list(tmp_path.iterdir()) == []  # refused before anything is read or written


def test_index_bounds_are_the_training_bounds_and_refuse_nonsense_below() -> None:
    bounds = TrainConfig.upper_bounds
    assert (bounds["eval_batch_size"], bounds["num_workers"]) == (index.MAX_BATCH_SIZE, index.MAX_NUM_WORKERS)
    index.check_sizes(argparse.Namespace(batch_size=index.MAX_BATCH_SIZE, num_workers=index.MAX_NUM_WORKERS))
    with pytest.raises(ValueError, match="^--batch-size 0: must be at least 1$"):
        index.check_sizes(argparse.Namespace(batch_size=0, num_workers=0))


@pytest.mark.parametrize("config", [DemoConfig(), DemoConfig.quick()], ids=["default", "quick"])
def test_the_demo_sizes_lie_within_the_bounds(config: DemoConfig) -> None:
    demo.check_sizes(argparse.Namespace(**{name: getattr(config, name) for name in demo.size_bounds()}))
    at_bounds = {name: bound for name, (_, bound) in demo.size_bounds().items()}
    demo.check_sizes(argparse.Namespace(**at_bounds))
