"""The one device resolver of training and inference: names it accepts and the errors it gives; clips loaded
in worker processes embed as in the model's own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from encoders.config import ConfigError
from encoders.inference import resolve_device
from encoders.sentence import evaluating


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


def test_a_model_loaded_without_its_text_tower_embeds_clips_alike_and_never_reads_the_sentence_encoder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``load_model(..., text=False)``, as the clip-embedding actors load it: the clip views are the
    full model's bit for bit in the same layout (channels-last convolutions) and within float rounding
    of the default layout's, the sentence encoder is not built, and encoding text is a clear error."""
    from dataclasses import replace

    from safetensors.torch import save_file

    from encoders.config import TextConfig, tiny_model_config
    from encoders.inference import load_model
    from encoders.model import DualEncoder
    from encoders.train_config import TrainConfig
    from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec, collate_clips

    torch.manual_seed(0)
    torch.set_num_threads(1)
    config = replace(TrainConfig(), model=replace(tiny_model_config(), text=TextConfig(kind="pretrained")))
    full = DualEncoder(config.model).eval()
    save_file({k: v.contiguous() for k, v in full.saved_state_dict().items()}, str(tmp_path / "model.safetensors"))
    (tmp_path / "config.json").write_text(config.to_json())
    ds = SyntheticClipDataset(3, spec=SyntheticSpec(frames=6, camera_hw=(32, 48), bev_hw=(32, 16)), seed=1)
    batch = collate_clips([ds[i] for i in range(3)])

    def no_encoder(name: str) -> None:
        raise AssertionError(f"the sentence encoder {name} was loaded")

    monkeypatch.setattr("encoders.text.load_sentence_encoder", no_encoder)
    clips_only = load_model(tmp_path, text=False)
    convolutions = [m.weight for m in clips_only.modules() if isinstance(m, torch.nn.Conv2d)]
    assert convolutions and all(w.is_contiguous(memory_format=torch.channels_last) for w in convolutions)
    with torch.no_grad():
        contiguous = full.encode_views(batch)
        full.to(memory_format=torch.channels_last)  # as load_model lays its convolution weights out
        expected, got = full.encode_views(batch), clips_only.encode_views(batch)
    assert all(torch.equal(expected[view], got[view]) for view in expected)
    for view in expected:  # the layout changes only the order of the sums
        torch.testing.assert_close(got[view], contiguous[view], rtol=1e-5, atol=1e-6)
    assert not any(k.startswith("text.") for k in clips_only.saved_state_dict())
    with pytest.raises(RuntimeError, match=r"loaded without its text tower .*text=True to encode text"):
        clips_only.encode_text(["a car turns left"])


def test_clips_loaded_in_worker_processes_embed_alike() -> None:
    from encoders.config import tiny_model_config
    from encoders.inference import embed_dataset_views
    from encoders.model import DualEncoder
    from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec

    torch.manual_seed(0)
    model = DualEncoder(tiny_model_config()).eval()
    ds = SyntheticClipDataset(7, spec=SyntheticSpec(frames=4, camera_hw=(32, 48), bev_hw=(32, 16)), seed=1)
    ids, views = embed_dataset_views(model, ds, batch_size=3)
    ids_w, views_w = embed_dataset_views(model, ds, batch_size=3, num_workers=2)
    assert ids_w == ids
    for view, x in views.items():
        np.testing.assert_array_equal(views_w[view], x)


@pytest.mark.parametrize("native", [True, False])
def test_batches_of_clips_run_in_bfloat16_where_the_cpu_multiplies_it(monkeypatch: pytest.MonkeyPatch,
                                                                      native: bool) -> None:
    import encoders.inference as inference

    monkeypatch.setattr(inference, "native_bfloat16", lambda: native)
    with inference.clip_autocast(torch.device("cpu")):
        assert torch.is_autocast_enabled("cpu") is native
        if native:
            assert torch.get_autocast_dtype("cpu") == torch.bfloat16


def test_bfloat16_embeddings_stay_within_1e_3_cosine_of_float32(monkeypatch: pytest.MonkeyPatch) -> None:
    import encoders.inference as inference
    from encoders.config import tiny_model_config
    from encoders.model import DualEncoder
    from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec

    torch.manual_seed(0)
    model = DualEncoder(tiny_model_config()).eval()
    ds = SyntheticClipDataset(6, spec=SyntheticSpec(frames=4, camera_hw=(32, 48), bev_hw=(32, 16)), seed=2)
    monkeypatch.setattr(inference, "native_bfloat16", lambda: False)
    _, exact = inference.embed_dataset_views(model, ds, batch_size=3)
    monkeypatch.setattr(inference, "native_bfloat16", lambda: True)  # autocast runs on any CPU, if slower
    _, mixed = inference.embed_dataset_views(model, ds, batch_size=3)
    for view, x in exact.items():
        assert mixed[view].dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(mixed[view], axis=1), 1.0, atol=1e-5)
        assert (x * mixed[view]).sum(axis=1).min() > 1 - 1e-3, view
        assert not np.array_equal(x, mixed[view]), view  # the products did run in bfloat16


def test_evaluating_restores_the_mode_it_found_even_on_an_error() -> None:
    module = torch.nn.Dropout(0.5)
    module.train()
    with evaluating(module):
        assert not module.training
    assert module.training
    with pytest.raises(RuntimeError), evaluating(module):
        raise RuntimeError("inside")
    assert module.training
    module.eval()
    with evaluating(module):
        pass
    assert not module.training
