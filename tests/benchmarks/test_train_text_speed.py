"""The training benchmark's whole-text case: seeded caption texts whose sentences recur, and both forms
run through the text tower."""

from __future__ import annotations

import os

from benchmarks.train_text_speed import training_texts, whole_text_speedup
from encoders.text import text_sentences


def test_training_texts_are_seeded_and_their_sentences_recur() -> None:
    steps = training_texts(16, 6)
    assert steps == training_texts(16, 6) and steps != training_texts(16, 6, seed=1)
    assert all(len(texts) >= 16 for texts in steps)  # each clip's caption, and its reversal where it has one
    texts = {t for texts in steps for t in texts}
    sentences = {s for t in texts for s in text_sentences(t)}
    assert all(len(text_sentences(t)) == 2 for t in texts)  # an ego sentence and an object sentence
    # What the whole text as its sentences saves on: fewer distinct sentences than the texts have.
    assert len(sentences) < 2 * len(texts) * 0.8


def test_whole_text_speedup_runs_both_forms_over_the_same_texts() -> None:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    figures = whole_text_speedup(4, 2)
    assert figures["texts"] == sum(map(len, training_texts(4, 2)))
    text, sentences = figures["text"], figures["sentences"]
    assert text["strings"] > 0 and sentences["strings"] > 0
    # In one piece every caption is encoded as written; as sentences none of them is (two sentences each).
    assert text["characters"] > sentences["characters"]
    assert figures["strings_ratio"] == round(text["strings"] / sentences["strings"], 2)
