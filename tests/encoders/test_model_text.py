"""Text tower: the bundled MiniLM (offline, frozen, cached), top-layer fine-tuning, the scratch fallback."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from encoders.config import BUNDLED_TEXT_MODEL, ConfigError, TextConfig
from encoders.sentence import (
    TextModelUnavailableError,
    cache_name,
    inference_autocast,
    inference_dtype,
    load_sentence_encoder,
    shared_sentence_encoder,
    text_encoder_dtype,
)
from encoders.text import ENCODE_GROUP, PretrainedText, TextFeatureCache, TextTower, hash_tokens

os.environ["HF_HUB_OFFLINE"] = "1"
CAPTIONS = [
    "a car approaches in the left lane",
    "a truck moves away in the host lane",
    "a car approaches in the left lane",
]


@pytest.fixture(scope="module")
def pretrained() -> TextTower:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    return TextTower(TextConfig(), 16)


def test_pretrained_is_frozen_with_a_trainable_head(pretrained: TextTower) -> None:
    trainable = {n for n, p in pretrained.named_parameters() if p.requires_grad}
    assert trainable and all(n.startswith("head.") for n in trainable)
    assert pretrained.backbone.out_features == 384
    assert pretrained.frozen_prefixes() == ["backbone.encoder."]


def test_cache_serves_repeats_and_matches_the_encoder(pretrained: TextTower, tmp_path: Path) -> None:
    cache = pretrained.cache
    assert cache is not None
    cache.entries.clear()
    cache.hits = cache.misses = 0
    first = pretrained(CAPTIONS, torch.device("cpu"))
    assert cache.misses == 2 and cache.hits == 1 and len(cache) == 2
    second = pretrained(CAPTIONS, torch.device("cpu"))
    assert cache.misses == 2 and torch.equal(first, second)
    assert torch.allclose(first[0], first[2])
    first.sum().backward()  # the head trains through cached features
    assert pretrained.head[0].weight.grad is not None
    path = tmp_path / "text_cache.npz"
    cache.save(path)
    fresh = type(cache)(cache.model_name)
    assert fresh.load(path) == 2
    np.testing.assert_array_equal(fresh.get(CAPTIONS[1]), cache.get(CAPTIONS[1]))
    assert type(cache)("another-model").load(path) == 0  # entries are keyed by the model


def test_strings_encode_in_groups_by_length_and_come_back_in_order(pretrained: TextTower) -> None:
    backbone, cpu = pretrained.backbone, torch.device("cpu")
    cache = pretrained.cache
    assert cache is not None
    texts = [f"a car {'then approaches ' * (i % 7)}in lane {i}" for i in range(ENCODE_GROUP * 2 + 3)]
    cache.entries.clear()
    grouped = backbone(texts, cpu)  # every string missing: one call of the encoder, in groups
    one_by_one = []
    for t in texts:
        cache.entries.clear()
        one_by_one.append(backbone([t], cpu))
    assert grouped.shape == (len(texts), 384)
    assert isinstance(backbone, PretrainedText)
    # bfloat16 products round differently with the group's padded length; a text in the wrong place
    # differs by far more (0.1 and up).
    atol = 1e-5 if backbone.dtype == torch.float32 else 2e-3
    torch.testing.assert_close(grouped, torch.cat(one_by_one), atol=atol, rtol=0)
    assert backbone._run([], cpu).shape == (0, 384)


def test_precision_follows_the_cpu_and_the_config(monkeypatch: pytest.MonkeyPatch) -> None:
    import encoders.sentence as sentence

    assert inference_dtype("float32") == torch.float32 and inference_dtype("bfloat16") == torch.bfloat16
    for native, dtype in ((True, torch.bfloat16), (False, torch.float32)):
        monkeypatch.setattr(sentence, "native_bfloat16", lambda native=native: native)
        assert inference_dtype("auto") == dtype
    with pytest.raises(ConfigError, match="precision"):
        TextConfig(precision="float16")
    with pytest.raises(ConfigError, match="precision"):
        inference_dtype("half")
    # An encoder that trains, wholly or its top layers, stays in float32 whatever the precision says.
    assert text_encoder_dtype(TextConfig(precision="bfloat16")) == torch.bfloat16
    assert text_encoder_dtype(TextConfig(precision="bfloat16", freeze=False)) == torch.float32
    assert text_encoder_dtype(TextConfig(precision="bfloat16", finetune_top_layers=1)) == torch.float32
    assert cache_name(BUNDLED_TEXT_MODEL, torch.float32) == BUNDLED_TEXT_MODEL
    assert cache_name(BUNDLED_TEXT_MODEL, torch.bfloat16) == f"{BUNDLED_TEXT_MODEL}@bfloat16"


def test_bfloat16_inference_keeps_the_sentence_embeddings(pretrained: TextTower, tmp_path: Path) -> None:
    # The speed-up is worth having only if the embeddings stay what they were: measured on the demo's
    # rule captions, cosine 0.99998 at worst. On a CPU without bfloat16 instructions this is emulated.
    texts = [*CAPTIONS, "the ego vehicle brakes, then a cyclist on the right crosses in front of us"]
    exact = PretrainedText(TextConfig(precision="float32"))
    fast = PretrainedText(TextConfig(precision="bfloat16"))
    cpu = torch.device("cpu")
    x, y = exact(texts, cpu), fast(texts, cpu)  # (N, 384) each, unit rows
    assert y.dtype == torch.float32
    cosine = torch.nn.functional.cosine_similarity(x, y)
    assert cosine.min() > 0.9999 and not torch.equal(x, y)
    # Each precision's rows are cached under their own name: a float32 cache does not seed a bfloat16 run.
    assert exact.cache is not None and fast.cache is not None
    assert fast.cache.model_name == f"{BUNDLED_TEXT_MODEL}@bfloat16" != exact.cache.model_name
    exact.cache.save(tmp_path / "text_cache.npz")
    assert type(fast.cache)(fast.cache.model_name).load(tmp_path / "text_cache.npz") == 0
    # The context is a no-op in float32 and bfloat16 autocast otherwise.
    with inference_autocast(cpu, torch.float32):
        assert not torch.is_autocast_enabled("cpu")
    with inference_autocast(cpu, torch.bfloat16):
        assert torch.is_autocast_enabled("cpu") and torch.get_autocast_dtype("cpu") == torch.bfloat16


@pytest.mark.parametrize(("content", "field"), [
    (b"not a cache", "unreadable"),
    ({"keys": np.array(["k"]), "vectors": np.zeros((1, 4), np.float32)}, "'model'"),
    ({"model": np.array("m"), "keys": np.array(["a", "b"]), "vectors": np.zeros((3, 4), np.float32)}, "'vectors'"),
])
def test_a_broken_text_cache_names_its_file_and_field(tmp_path: Path, content: object, field: str) -> None:
    path = tmp_path / "text_cache.npz"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        np.savez(path, **content)  # type: ignore[arg-type]
    cache = TextFeatureCache("m")
    with pytest.raises(ValueError, match=field) as err:
        cache.load(path)
    assert str(path) in str(err.value) and len(cache) == 0


def test_finetune_top_layers_trains_them_without_cache() -> None:
    tower = TextTower(TextConfig(finetune_top_layers=1), 8)
    assert tower.cache is None and tower.frozen_prefixes() == []
    trainable = [n for n, p in tower.backbone.named_parameters() if p.requires_grad]
    assert trainable and all(".layer.5." in n for n in trainable)
    tower(CAPTIONS[:2], torch.device("cpu")).sum().backward()
    grads = [p.grad for n, p in tower.backbone.named_parameters() if p.requires_grad]
    assert all(g is not None for g in grads)


def test_missing_pretrained_model_explains_the_fallback(tmp_path: Path) -> None:
    with pytest.raises(TextModelUnavailableError, match="kind: scratch"):
        TextTower(TextConfig(model=str(tmp_path / "no_model")), 8)


def test_one_shared_encoder_per_process_and_private_copies_to_train(pretrained: TextTower) -> None:
    shared = shared_sentence_encoder()
    assert shared_sentence_encoder() is shared  # loaded once, whoever asks
    own = load_sentence_encoder()
    assert own is not shared and pretrained.backbone.encoder is not shared
    assert all(a is not b for a, b in zip(own.parameters(), shared.parameters()))
    # The tower's frozen features are the shared model's sentence embeddings (in the same precision).
    assert isinstance(pretrained.backbone, PretrainedText)
    with inference_autocast("cpu", pretrained.backbone.dtype):
        expected = torch.from_numpy(shared.encode(CAPTIONS[:1]))
    with torch.no_grad():
        got = pretrained.backbone(CAPTIONS[:1], torch.device("cpu"))
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5)
    # Training a copy leaves the shared model as it was.
    next(own.parameters()).data.add_(1.0)
    assert not torch.equal(next(own.parameters()), next(shared.parameters()))


def test_scratch_tower_reads_word_order() -> None:
    torch.manual_seed(0)
    tower = TextTower(TextConfig(kind="scratch", scratch_width=32, scratch_layers=1, scratch_vocab=256), 8).eval()
    ids = hash_tokens(["Left, then HOST", "left then host"], 256, 6)
    assert torch.equal(ids[0], ids[1]) and int((ids[0] > 0).sum()) == 3
    with torch.no_grad():
        out = tower(["left then host", "host then left", ""], torch.device("cpu"))
    assert out.shape == (3, 8) and torch.isfinite(out).all()
    assert (out[0] - out[1]).abs().max() > 1e-4
