"""The frozen sentence encoder of rule-caption search: seeded with a run's own text cache; a text of
several sentences embedded as their mean."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from encoders.config import BUNDLED_TEXT_MODEL
from encoders.sentence import cache_name, inference_dtype
from encoders.text import TEXT_CACHE_FILE, TextFeatureCache
from retrieval.sentence_encoder import SentenceEncoder

os.environ["HF_HUB_OFFLINE"] = "1"
#: What a run trained on this machine files its cache under (the precision follows the CPU).
HERE = cache_name(BUNDLED_TEXT_MODEL, inference_dtype("auto"))


def _planted_cache(run_dir: Path, model: str, text: str) -> np.ndarray:
    row = np.zeros(384, np.float32)
    row[7] = 1.0  # no sentence encodes to this: a row from the cache is recognisable
    cache = TextFeatureCache(model)
    cache.put(text, row)
    run_dir.mkdir(parents=True, exist_ok=True)
    cache.save(run_dir / TEXT_CACHE_FILE)
    return row


def test_known_rows_come_from_the_run_and_the_rest_is_encoded(tmp_path: Path) -> None:
    row = _planted_cache(tmp_path / "run", HERE, "a car approaches")
    texts = ["a truck moves away", "a car approaches", "a truck moves away"]
    xq = SentenceEncoder.for_run(tmp_path / "run")(texts)
    assert xq.shape == (3, 384)
    np.testing.assert_array_equal(xq[1], row)
    reference = SentenceEncoder()(["a truck moves away"])[0]
    np.testing.assert_allclose(xq[0], reference, atol=1e-6)
    np.testing.assert_array_equal(xq[0], xq[2])


def test_a_cache_of_another_model_or_none_is_not_used(tmp_path: Path) -> None:
    _planted_cache(tmp_path / "other", "another-model", "a car approaches")
    # The same model in the other precision: its rows differ from this machine's by up to ~1e-3.
    other = torch.float32 if inference_dtype("auto") == torch.bfloat16 else torch.bfloat16
    _planted_cache(tmp_path / "precision", cache_name(BUNDLED_TEXT_MODEL, other), "a car approaches")
    reference = SentenceEncoder()(["a car approaches"])[0]
    for run_dir in (tmp_path / "other", tmp_path / "precision", tmp_path / "no-run"):
        xq = SentenceEncoder.for_run(run_dir)(["a car approaches"])
        np.testing.assert_allclose(xq[0], reference, atol=1e-6)
        assert abs(float(np.linalg.norm(xq[0])) - 1.0) < 1e-5


def _planted_rows(run_dir: Path, rows: dict[str, int]) -> dict[str, np.ndarray]:
    """A run's text cache holding one basis vector per text: a row from it is recognisable."""
    cache, out = TextFeatureCache(HERE), {}
    for text, axis in rows.items():
        out[text] = np.eye(384, dtype=np.float32)[axis]
        cache.put(text, out[text])
    run_dir.mkdir(parents=True, exist_ok=True)
    cache.save(run_dir / TEXT_CACHE_FILE)
    return out


def test_a_text_of_several_sentences_is_the_mean_of_its_sentences(tmp_path: Path) -> None:
    rows = _planted_rows(tmp_path / "run", {"We stop.": 3, "A car passes.": 9, "We stop. A car passes.": 20})
    encoder = SentenceEncoder.for_run(tmp_path / "run")
    assert encoder.whole_text == "sentences"
    xq = encoder(["We stop. A car passes.", "We stop.", "A car passes."])  # (3, 384)
    np.testing.assert_allclose(xq[0], (rows["We stop."] + rows["A car passes."]) / np.sqrt(2), atol=1e-7)
    np.testing.assert_array_equal(xq[1:], np.stack([rows["We stop."], rows["A car passes."]]))
    # In one piece the whole text is a string of its own.
    whole = SentenceEncoder.for_run(tmp_path / "run", whole_text="text")(["We stop. A car passes."])
    np.testing.assert_array_equal(whole[0], rows["We stop. A car passes."])


def test_an_unknown_whole_text_is_refused() -> None:
    with pytest.raises(ValueError, match="whole_text must be one of"):
        SentenceEncoder(whole_text="words")
