"""The one config reader: round trips, unknown keys listed, type errors naming file and key."""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Literal

import pytest

from scenesearch_base.config import (
    ConfigError,
    YamlConfig,
    check_at_least,
    check_fraction,
    check_positive,
    from_dict,
    from_yaml,
    from_yaml_text,
    parse_choice,
    to_dict,
    to_yaml,
    with_option,
)


class Mode(str, enum.Enum):
    FAST = "fast"
    EXACT = "exact"


@dataclass(frozen=True)
class Inner:
    widths: tuple[int, ...] = (8, 16)
    scale_m: float = 0.5
    name: str | None = None

    def __post_init__(self) -> None:
        if self.scale_m <= 0:
            raise ValueError(f"scale_m must be > 0, got {self.scale_m}")


@dataclass(frozen=True)
class Outer:
    epochs: int = 3
    amp: bool = False
    mode: Mode = Mode.FAST
    kind: Literal["a", "b"] = "a"
    inner: Inner = field(default_factory=Inner)
    weights: dict[str, float] = field(default_factory=dict)
    out: Path = Path("run")


class StageConfigError(ConfigError):
    pass


def test_round_trip_through_a_file(tmp_path: Path) -> None:
    config = Outer(epochs=5, amp=True, mode=Mode.EXACT, kind="b", inner=Inner((1, 2, 3), 2.0, "x"), weights={"a": 1.0})
    to_yaml(config, tmp_path / "c.yaml")
    assert from_yaml(Outer, tmp_path / "c.yaml") == config
    assert to_dict(config)["mode"] == "exact" and to_dict(config)["inner"]["widths"] == [1, 2, 3]


def test_missing_keys_keep_defaults_and_ints_become_floats() -> None:
    config = from_dict(Outer, {"inner": {"scale_m": 2}})
    assert config == Outer(inner=Inner(scale_m=2.0))
    assert isinstance(config.inner.scale_m, float)
    assert from_dict(Outer, None) == Outer()


def test_every_unknown_key_is_listed_with_its_dotted_path() -> None:
    with pytest.raises(ConfigError) as info:
        from_dict(Outer, {"epoch": 1, "inner": {"widht": 3}}, source="train.yaml")
    message = str(info.value)
    assert message.startswith("train.yaml: unknown keys epoch, inner.widht")
    assert "known at inner: widths, scale_m, name" in message


@pytest.mark.parametrize(
    ("data", "key", "expected"),
    [
        ({"epochs": "two"}, "epochs", "an integer"),
        ({"epochs": True}, "epochs", "an integer"),
        ({"amp": 1}, "amp", "true or false"),
        ({"mode": "slow"}, "mode", "one of 'fast', 'exact'"),
        ({"kind": "c"}, "kind", "one of 'a', 'b'"),
        ({"inner": {"widths": [1, "x"]}}, "inner.widths[1]", "an integer"),
        ({"inner": 3}, "inner", "a mapping"),
        ({"weights": {"a": "heavy"}}, "weights.a", "a number"),
    ],
)
def test_wrong_types_name_file_key_and_expected_type(data: dict, key: str, expected: str) -> None:
    with pytest.raises(StageConfigError) as info:
        from_dict(Outer, data, source="c.yaml", error=StageConfigError)
    assert str(info.value).startswith(f"c.yaml: key '{key}': expected {expected}, got ")


def test_checks_of_the_dataclass_are_reported_with_the_file() -> None:
    with pytest.raises(ConfigError, match=r"^c.yaml: key 'inner': scale_m must be > 0, got -1.0$"):
        from_dict(Outer, {"inner": {"scale_m": -1}}, source="c.yaml")


def test_yaml_syntax_and_top_level_errors_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("epochs: [1\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: not valid YAML \(line 2, column 1\)"):
        from_yaml(Outer, path)
    with pytest.raises(ConfigError, match="expected a mapping at the top level, got list"):
        from_yaml_text(Outer, "- 1\n", source="x.yaml")
    with pytest.raises(ConfigError, match="cannot read config"):
        from_yaml(Outer, tmp_path / "missing.yaml")


def test_a_key_given_twice_is_refused_naming_it_and_its_line(tmp_path: Path) -> None:
    """PyYAML would keep the last value silently; which one the person meant is not known."""
    path = tmp_path / "twice.yaml"
    path.write_text("epochs: 3\nname: a\nepochs: 50\n")
    with pytest.raises(ConfigError, match=r"twice.yaml: not valid YAML \(line 3, column 1\): key 'epochs' "
                                          r"appears twice in one mapping"):
        from_yaml(Outer, path)


class StageConfig(YamlConfig):
    config_error = StageConfigError


@dataclass(frozen=True)
class Small(StageConfig):
    epochs: int = 3


def test_the_base_class_offers_the_functions_with_the_stage_error(tmp_path: Path) -> None:
    Small(epochs=4).to_yaml(tmp_path / "s.yaml")
    assert Small.from_yaml(tmp_path / "s.yaml") == Small(epochs=4)
    assert Small.from_yaml_text(Small(epochs=5).to_yaml_text()) == Small(epochs=5)
    assert Small.from_dict({"epochs": 6}).to_dict() == {"epochs": 6}
    with pytest.raises(StageConfigError, match="unknown keys epoch "):
        Small.from_dict({"epoch": 1})


@dataclass(frozen=True)
class Bounded(StageConfig):
    upper_bounds: ClassVar[Mapping[str, float]] = {"frames": 256, "widths": 4096, "rate": 10}

    frames: int = 16
    widths: tuple[int, ...] = (8, 16)
    rate: float = 0.5


@dataclass(frozen=True)
class HoldsBounded(StageConfig):
    part: Bounded = field(default_factory=Bounded)


@pytest.mark.parametrize(
    ("data", "message"),
    [({"frames": 257}, "key 'frames': 257 is above its upper bound 256"),
     ({"widths": [8, 5000]}, "key 'widths': (8, 5000) is above its upper bound 4096"),  # each element
     ({"rate": 10.5}, "key 'rate': 10.5 is above its upper bound 10")],
)
def test_a_value_above_its_upper_bound_is_refused_naming_key_and_bound(data: dict, message: str) -> None:
    with pytest.raises(StageConfigError) as info:
        Bounded.from_dict(data, source="b.yaml")
    assert str(info.value) == f"b.yaml: {message}"
    with pytest.raises(StageConfigError, match=r"^b\.yaml: key 'part\.frames': 257 is above"):
        HoldsBounded.from_dict({"part": data | {"frames": 257}}, source="b.yaml")  # named from the top


def test_values_at_their_upper_bounds_are_accepted() -> None:
    assert Bounded.from_dict({"frames": 256, "widths": [4096], "rate": 10}) == Bounded(256, (4096,), 10.0)


def test_with_option_names_the_flag_of_a_refused_value() -> None:
    assert with_option(Bounded(), "--frames", frames=32) == Bounded(frames=32)
    with pytest.raises(StageConfigError, match=r"^--frames 1000000000: key 'frames': 1000000000 is above its "
                                               r"upper bound 256$"):
        with_option(Bounded(), "--frames", frames=1_000_000_000)


def test_field_checks_name_the_first_bad_field_and_raise_the_stage_error() -> None:
    check_positive("Lens", focal_m=0.05, aperture_m=1e-9)
    check_at_least("Lens", 1, blades=1, elements=7)
    check_fraction("Lens", vignetting=0.0, transmission=1.0)
    with pytest.raises(ValueError, match=r"^Lens\.aperture_m must be > 0, got 0\.0$"):
        check_positive("Lens", focal_m=0.05, aperture_m=0.0, shutter_s=-1.0)
    with pytest.raises(ValueError, match=r"^Lens\.focal_m must be > 0, got nan$"):
        check_positive("Lens", focal_m=float("nan"))
    with pytest.raises(StageConfigError, match=r"^Lens\.elements must be >= 1, got 0$"):
        check_at_least("Lens", 1, error=StageConfigError, blades=3, elements=0)
    with pytest.raises(ValueError, match=r"^Lens\.transmission must be in \[0, 1\], got 1\.5$"):
        check_fraction("Lens", vignetting=0.5, transmission=1.5)
    with pytest.raises(ValueError, match=r"^Lens\.vignetting must be in \[0, 1\], got -0\.1$"):
        check_fraction("Lens", vignetting=-0.1)


def test_a_choice_is_read_by_its_value_and_an_unknown_one_lists_the_valid_values() -> None:
    assert parse_choice(Mode, "exact", "mode", "valid modes") is Mode.EXACT
    assert parse_choice(Mode, Mode.FAST, "mode", "valid modes") is Mode.FAST
    with pytest.raises(ValueError, match=r"^unknown mode 'slow'; valid modes: fast, exact$"):
        parse_choice(Mode, "slow", "mode", "valid modes")
    with pytest.raises(StageConfigError, match=r"^unknown mode 3; choose one of: fast, exact$"):
        parse_choice(Mode, 3, "mode", "choose one of", error=StageConfigError)
