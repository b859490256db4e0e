"""Text → clip retrieval metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from encoders.metrics import text_to_clip_metrics


def test_hand_computed() -> None:
    sim = np.array([[0.9, 0.8, 0.1, 0.0], [0.1, 0.2, 0.3, 0.4], [0.5, 0.4, 0.3, 0.2]])
    relevant = np.array([[1, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 0]], dtype=bool)
    m = text_to_clip_metrics(sim, relevant, ks=(1, 2, 4))
    # query 0: relevant at ranks 1 and 3; query 1: at rank 4; query 2 has none and is left out
    assert m["queries"] == 2
    assert m["R@1"] == 0.5 and m["R@2"] == 0.5 and m["R@4"] == 1.0
    assert m["median_rank"] == 2.5
    assert m["mAP"] == pytest.approx(((1 + 2 / 3) / 2 + 1 / 4) / 2)


def test_perfect_and_shape_errors() -> None:
    eye = np.eye(5)
    m = text_to_clip_metrics(eye, eye.astype(bool))
    assert m["R@1"] == 1.0 and m["median_rank"] == 1.0 and m["mAP"] == 1.0
    with pytest.raises(ValueError, match="must both be"):
        text_to_clip_metrics(eye, np.ones((5, 4), bool))
