"""The training benchmark's caption texts: seeded, and made of sentences that recur across captions."""

from __future__ import annotations

from benchmarks.bench_train import _training_texts
from encoders.text import text_sentences


def test_training_texts_are_seeded_and_their_sentences_recur() -> None:
    steps = _training_texts(16, 6)
    assert steps == _training_texts(16, 6) and steps != _training_texts(16, 6, seed=1)
    assert all(len(texts) >= 16 for texts in steps)  # each clip's caption, and its reversal where it has one
    texts = {t for texts in steps for t in texts}
    sentences = {s for t in texts for s in text_sentences(t)}
    assert all(len(text_sentences(t)) == 2 for t in texts)  # an ego sentence and an object sentence
    # What the whole text as its sentences saves on: fewer distinct sentences than the texts have.
    assert len(sentences) < 2 * len(texts) * 0.8
