"""The report's scenario drawing marks the referred object red and the related ones orange, around the referred one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from retrieval.records import SearchResult
from retrieval.scenario_report import draw_moment
from tests.scenarios.synthetic import car, make_features, pedestrian


def _pixels(path: Path, rgb: tuple[int, int, int]) -> int:
    image = np.asarray(Image.open(path).convert("RGB")).astype(int)
    return int((np.abs(image - np.array(rgb)).sum(axis=2) < 40).sum())


def test_the_referred_object_is_red_and_the_related_ones_orange(tmp_path: Path) -> None:
    # A car 200 m from the ego with a pedestrian beside it: the view centres on the car, the ego is out of it.
    x = make_features([{**car((200.0, 0.0)), "id": "car1"}, {**pedestrian((200.0, 3.0)), "id": "ped1"},
                       {**car((260.0, 0.0)), "id": "far"}])
    t = x.timestamps_ns
    result = SearchResult(1, "synthetic:car1:0", "synthetic", "car1", "car", int(t[0]), int(t[-1]), "", (), 1.0,
                          None, "fused")
    out = tmp_path / "moment.png"
    assert draw_moment(x, result, ["car1"], ["ped1"], out)
    red, orange, blue = _pixels(out, (214, 39, 40)), _pixels(out, (255, 127, 14)), _pixels(out, (31, 119, 180))
    assert red > orange > 0  # the car's box is larger than the pedestrian's
    assert blue == 0  # the ego, 200 m away, is outside the view
