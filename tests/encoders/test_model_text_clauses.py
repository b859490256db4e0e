"""The clauses text tower: a text's steps in order, each through the frozen encoder and its cache."""

from __future__ import annotations

import os

import pytest
import torch

from encoders.config import ConfigError, TextConfig
from encoders.sentence import TextModelUnavailableError
from encoders.text import ClauseText, TextTower, text_steps

os.environ["HF_HUB_OFFLINE"] = "1"
CAPTION = ("The ego vehicle is cruising straight. A car in the left lane approaches, then moves into the ego lane "
           "and keeps its distance.")
REVERSED = ("The ego vehicle is cruising straight. A car in the ego lane keeps its distance, then moves into the "
            "left lane and approaches.")


def test_steps_are_sentences_split_before_then() -> None:
    assert text_steps(CAPTION, 6) == ["The ego vehicle is cruising straight", "A car in the left lane approaches",
                                      "then moves into the ego lane and keeps its distance"]
    assert text_steps("a car approaches then stops", 6) == ["a car approaches", "stops"]
    assert text_steps("it brakes, after that it turns; it stops.", 6) == ["it brakes", "it turns", "it stops"]
    assert text_steps("It brakes, and then it turns", 6) == ["It brakes", "it turns"]
    assert text_steps("a cyclist next to us on the right", 6) == ["a cyclist next to us on the right"]
    assert text_steps("A. B. C. D.", 2) == ["A", "B C D"]  # beyond max_steps: merged into the last
    assert text_steps("", 6) == [""] and text_steps("...", 6) == ["..."]  # any text is at least one step
    with pytest.raises(ConfigError, match="max_steps"):
        TextConfig(kind="clauses", max_steps=0)


@pytest.fixture(scope="module")
def tower() -> TextTower:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    try:
        return TextTower(TextConfig(kind="clauses", max_steps=4, step_hidden=32), 16)
    except TextModelUnavailableError as exc:
        pytest.skip(f"the pretrained sentence encoder is not installed: {exc}")


def test_slots_hold_the_text_then_its_steps_in_order(tower: TextTower) -> None:
    backbone = tower.backbone
    assert isinstance(backbone, ClauseText) and backbone.out_features == 5 * 384
    assert tower.frozen_prefixes() == ["backbone.sentence.encoder."]
    assert {n for n, p in tower.named_parameters() if p.requires_grad} == {
        "head.0.weight", "head.0.bias", "head.2.weight", "head.2.bias"}
    cache = tower.cache
    assert cache is not None
    cache.entries.clear()
    cache.hits = cache.misses = 0
    with torch.no_grad():
        x = backbone([CAPTION, REVERSED], torch.device("cpu")).reshape(2, 5, 384)
    # 2 texts + 3 distinct steps each, the host sentence shared: 7 strings, each encoded once and cached.
    assert cache.misses == 7 and len(cache) == 7
    for slot, part in enumerate([CAPTION, *text_steps(CAPTION, 4)]):
        torch.testing.assert_close(x[0, slot], torch.from_numpy(cache.get(part)))
    assert torch.equal(x[0, 4], torch.zeros(384))  # a step slot the text does not fill
    torch.testing.assert_close(x[0, 1], x[1, 1])  # the same host sentence in both
    cos = torch.nn.functional.cosine_similarity
    # The pooled sentences are nearly one vector; the slots in order are not.
    assert float(cos(x[0, 0], x[1, 0], dim=0)) > 0.95
    assert float(cos(x[0].flatten(), x[1].flatten(), dim=0)) < 0.9


def test_any_free_text_gives_one_embedding(tower: TextTower) -> None:
    texts = ["we brake and stop", "", "a car cuts in front of us from the left, then slows down. " * 40]
    out = tower(texts, torch.device("cpu"))
    assert out.shape == (3, 16) and torch.isfinite(out).all()
    out.sum().backward()  # the head trains on cached features
    assert tower.head[0].weight.grad is not None
