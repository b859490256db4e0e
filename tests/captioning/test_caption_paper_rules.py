"""``rules: paper`` gives the captions and frame tags of the paper's rules alone, byte for byte.

The fixture holds two simulated logs (seed 3, 12 s; one with tracker noise) as the arrays the
pipeline captions, and what the paper's rules made of them before own behaviour existed: the
caption rows (canonical captions, paraphrases, tags, …) and a digest of the frame-tag rows.
"""

from __future__ import annotations

import dataclasses
import gzip
import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from captioning.config import CaptioningConfig, RuleSet, WindowStrategy
from captioning.outputs import write_outputs
from captioning.pipeline import LogCaptions, caption_arrays
from captioning.tables import CAPTIONS_SCHEMA, FRAME_TAGS_SCHEMA

FIXTURE = Path(__file__).parent / "fixtures" / "paper_style"
#: fixture name → window strategy it was captioned with.
CASES = {"clean": WindowStrategy.HOST_SEGMENTS, "noisy": WindowStrategy.SLIDING}


def _caption(name: str, rules: RuleSet) -> LogCaptions:
    z = np.load(FIXTURE / f"{name}_tracks.npz")
    config = CaptioningConfig(rules=rules)
    config = dataclasses.replace(config, windows=dataclasses.replace(config.windows, strategy=CASES[name]))
    return caption_arrays(
        str(z["log_id"]), z["timestamps_ns"], z["track_ids"], z["categories"], z["valid"], z["center_ego_xy_m"],
        z["yaw_ego_rad"], z["city_SE3_ego"], config,
    )


def _payload(table) -> dict:  # type: ignore[no-untyped-def]
    return {"schema": [f"{f.name}:{f.type}:{f.nullable}" for f in table.schema], "rows": table.to_pylist()}


@pytest.mark.parametrize("name", list(CASES))
def test_paper_rules_give_the_recorded_captions_byte_for_byte(name: str, tmp_path: Path) -> None:
    result = _caption(name, RuleSet.PAPER)
    with gzip.open(FIXTURE / f"{name}_captions.json.gz", "rt", encoding="utf-8") as fh:
        expected = json.load(fh)
    frames_path, captions_path = write_outputs(tmp_path, [result])
    assert result.captions_table().schema.equals(CAPTIONS_SCHEMA)
    assert _payload(result.captions_table()) == expected  # every string of every row, paraphrases included
    assert pq.read_table(captions_path).to_pylist() == expected["rows"]  # and so is the published file
    digests = json.loads((FIXTURE / "frame_tags_sha256.json").read_text())
    frames = result.frame_tags_table()
    assert frames.schema.equals(FRAME_TAGS_SCHEMA)
    digest = hashlib.sha256(json.dumps(_payload(frames), sort_keys=True).encode()).hexdigest()
    assert digest == digests[name]
    assert pq.read_table(frames_path).to_pylist() == frames.to_pylist()
    assert len(expected["rows"]) > 20  # not vacuous: host and neighbour captions of several tracks


def test_behavior_rules_say_more_on_the_same_log() -> None:
    paper = _caption("clean", RuleSet.PAPER)
    rich = _caption("clean", RuleSet.BEHAVIOR)
    # Stationary objects are captioned too, and the frame tags carry the own behaviour.
    assert len({c.track_id for c in rich.captions}) > len({c.track_id for c in paper.captions})
    assert "parked" in rich.frame_tags_table().column_names
    assert any(c.attributes and c.attributes["stopped"] for c in rich.captions)
