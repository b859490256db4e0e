"""A text's steps: its sentences, each split again before "then" (what the slots text tower lays out in time)."""

from __future__ import annotations

from encoders.text import sentence_steps, text_steps

CAPTION = ("The ego vehicle is cruising straight. A car in the left lane approaches, then moves into the ego lane "
           "and keeps its distance.")


def test_steps_are_sentences_split_before_then() -> None:
    assert text_steps(CAPTION, 6) == ["The ego vehicle is cruising straight", "A car in the left lane approaches",
                                      "then moves into the ego lane and keeps its distance"]
    assert text_steps("a car approaches then stops", 6) == ["a car approaches", "stops"]
    assert text_steps("it brakes, after that it turns; it stops.", 6) == ["it brakes", "it turns", "it stops"]
    assert text_steps("It brakes, and then it turns", 6) == ["It brakes", "it turns"]
    assert text_steps("a cyclist next to us on the right", 6) == ["a cyclist next to us on the right"]
    assert text_steps("A. B. C. D.", 2) == ["A", "B C D"]  # beyond max_steps: merged into the last
    assert text_steps("", 6) == [""] and text_steps("...", 6) == ["..."]  # any text is at least one step


def test_each_sentence_keeps_its_own_steps() -> None:
    assert sentence_steps(CAPTION) == [["The ego vehicle is cruising straight"],
                                       ["A car in the left lane approaches",
                                        "then moves into the ego lane and keeps its distance"]]
