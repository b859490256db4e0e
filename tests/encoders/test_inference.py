"""The one device resolver of training and inference: names it accepts and the errors it gives."""

from __future__ import annotations

import pytest
import torch

from encoders.config import ConfigError
from encoders.inference import resolve_device


@pytest.fixture
def no_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


@pytest.mark.usefixtures("no_cuda")
def test_without_cuda_auto_and_cpu_are_the_cpu() -> None:
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device("cpu") == torch.device("cpu")


@pytest.mark.usefixtures("no_cuda")
@pytest.mark.parametrize("name", ["cuda", "cuda:0", "cuda:1"])
def test_without_cuda_a_cuda_device_is_a_clear_error(name: str) -> None:
    with pytest.raises(ConfigError, match=r"requested but torch\.cuda\.is_available\(\) is False"):
        resolve_device(name)


@pytest.mark.parametrize("name", ["tpu", "gpu", "cuda0", "cuda:x", "CPU", ""])
def test_unknown_names_are_an_error(name: str) -> None:
    with pytest.raises(ConfigError, match=r"must be 'auto', 'cpu' or 'cuda\[:i\]'"):
        resolve_device(name)


def test_with_cuda_auto_picks_it_and_indexes_are_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert resolve_device("auto") == torch.device("cuda")
    assert resolve_device("cuda:0") == torch.device("cuda", 0)
    with pytest.raises(ConfigError, match="only 1 CUDA devices"):
        resolve_device("cuda:1")
