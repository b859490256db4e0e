from pathlib import Path

import pytest

from retrieval.cli import main
from scenes.log import Log
from scenes.sim import NetworkKind, SimulationConfig


def _args(out: Path, cache: Path, *extra: str) -> list[str]:
    return ["simulate", "--out", str(out), "--logs", "2", "--duration-s", "2", "--warmup-s", "20", "--seed", "4",
            "--cache-dir", str(cache), *extra]


def test_simulate_writes_valid_logs_and_refuses_to_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, cache = tmp_path / "logs", tmp_path / "cache"
    assert main(_args(out, cache)) == 0
    printed = capsys.readouterr().out
    assert "wrote 2 logs" in printed and "real time" in printed
    logs = sorted(p for p in out.iterdir())
    assert len(logs) == 2
    assert main(["validate", *map(str, logs)]) == 0
    capsys.readouterr()
    assert main(_args(out, cache)) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(_args(out, cache, "--overwrite", "--tracker-noise")) == 0
    assert Log.open(logs[0]).metadata.extra["tracker_noise"] is True


@pytest.mark.parametrize(
    ("flags", "message"),
    [(["--network", "hexagon"], "unknown network kind"), (["--duration-s", "0"], "duration_s"),
     (["--logs", "-1"], "logs"), (["--furniture-per-km", "-1"], "furniture_per_km"),
     (["--standing-pedestrians-per-km", "-0.5"], "standing_pedestrians_per_km"),
     (["--jitter-share", "2"], "jitter_share")],
)
def test_bad_input_exits_2_with_a_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], message: str
) -> None:
    assert main([*_args(tmp_path / "o", tmp_path / "c"), *flags]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_flags_override_the_config_file(tmp_path: Path) -> None:
    from retrieval.cli import build_parser
    from retrieval.commands.simulate import build_config

    path = tmp_path / "sim.yaml"
    SimulationConfig(logs=5, seed=9, network=NetworkKind.SPIDER).to_yaml(path)
    args = build_parser().parse_args(["simulate", "--out", "x", "--config", str(path), "--seed", "2"])
    config = build_config(args)
    assert (config.logs, config.seed, config.network.value) == (5, 2, "spider")


def test_street_furniture_standing_people_and_jitter_are_flags(tmp_path: Path) -> None:
    from retrieval.cli import build_parser
    from retrieval.commands.simulate import build_config

    args = build_parser().parse_args(["simulate", "--out", "x", "--furniture-per-km", "0",
                                      "--standing-pedestrians-per-km", "3.5", "--jitter-share", "0.5"])
    config = build_config(args)
    assert (config.furniture_per_km, config.standing_pedestrians_per_km, config.jitter_share) == (0.0, 3.5, 0.5)
    defaults = build_config(build_parser().parse_args(["simulate", "--out", "x"]))
    assert (defaults.furniture_per_km, defaults.standing_pedestrians_per_km, defaults.jitter_share) == (1.5, 1.0, 0.0)
