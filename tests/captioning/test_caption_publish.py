"""``frame_tags.parquet`` and ``captions.parquet`` are published together, or not at all."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from captioning.outputs import write_outputs
from captioning.pipeline import CAPTIONS_FILENAME, FRAME_TAGS_FILENAME, LogCaptions
from retrieval.cli import main
from scenesearch_base.atomic import machine_tag
from scenesearch_base.publish import GENERATIONS_DIR, current_generation, publish

from .conftest import Scene

REPO = Path(__file__).resolve().parents[2]


def small_result(make_scene, n: int) -> LogCaptions:  # type: ignore[no-untyped-def]
    """A log with ``n`` moving neighbours (so that two results differ)."""
    s: Scene = make_scene(8.0, num_frames=60)
    t = np.arange(60) * 0.1
    for i in range(n):
        s.add_relative(f"car{i}", "car", np.stack([20.0 + 5 * i - 2.0 * (i + 1) * t, np.full(60, 3.5 * (i % 2))], 1),
                       0.0)
    return s.caption()


def load(out: Path) -> tuple[list[dict], list[dict]]:
    return (pq.read_table(out / FRAME_TAGS_FILENAME).to_pylist(), pq.read_table(out / CAPTIONS_FILENAME).to_pylist())


def test_each_publish_replaces_both_and_leaves_one_generation(make_scene, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "captions"
    first, second = small_result(make_scene, 1), small_result(make_scene, 2)
    write_outputs(out, [first])
    frames_1, captions_1 = load(out)
    write_outputs(out, [second])
    frames_2, captions_2 = load(out)
    assert frames_2 != frames_1 and len(captions_2) > len(captions_1)
    assert frames_2 == second.frame_tags_table().to_pylist()
    assert [p.name for p in (out / GENERATIONS_DIR).iterdir() if p.name != "current"] == [current_generation(out).name]


def test_plain_files_of_an_older_writer_are_replaced_and_stale_temporaries_removed(tmp_path: Path) -> None:
    out = tmp_path / "captions"
    out.mkdir()
    (out / FRAME_TAGS_FILENAME).write_bytes(b"old frames")
    (out / CAPTIONS_FILENAME).write_bytes(b"old captions")
    # A temporary file of a single-file writer that was killed (its process is gone).
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True).stdout.strip()
    stale = [out / f".captions.parquet.{gone}@{machine_tag()}.a1b2c3d4.tmp.parquet",
             out / GENERATIONS_DIR / ".tmp-deadbeef"]
    stale[1].mkdir(parents=True)
    stale[0].write_bytes(b"half")
    publish(out, {FRAME_TAGS_FILENAME: lambda p: p.write_bytes(b"new frames"),
                  CAPTIONS_FILENAME: lambda p: p.write_bytes(b"new captions")})
    assert (out / FRAME_TAGS_FILENAME).read_bytes() == b"new frames"
    assert (out / CAPTIONS_FILENAME).read_bytes() == b"new captions"
    assert not any(p.exists() for p in stale)


CHILD = """
import sys, time
from pathlib import Path
import numpy as np
import pyarrow.parquet as pq
from captioning.config import CaptioningConfig, RuleSet
from captioning.pipeline import caption_arrays
from captioning.outputs import write_outputs
sys.path.insert(0, {tests!r})
from captioning_scene import busy_result

original = pq.ParquetWriter.close
calls = []

def pausing(self):
    if calls:  # the second file: say so, then wait to be killed
        Path({marker!r}).write_text("between")
        time.sleep(60)
    calls.append(self)
    original(self)

pq.ParquetWriter.close = pausing
write_outputs(Path({out!r}), [busy_result()])
"""

SCENE_MODULE = '''
import numpy as np
from captioning.config import CaptioningConfig, RuleSet
from captioning.pipeline import caption_arrays

def busy_result():
    t = 60
    poses = np.tile(np.eye(4), (t, 1, 1))
    poses[:, 0, 3] = np.arange(t) * 0.8
    center = np.stack([np.full((3, t), 15.0) + np.arange(3)[:, None] * 6 - np.arange(t) * 0.3,
                       np.tile([[0.0], [3.5], [-3.5]], (1, t))], axis=2)
    return caption_arrays("child", (np.arange(t) * 100_000_000).astype(np.int64), np.array(["a", "b", "c"]),
                          np.array(["car"] * 3), np.ones((3, t), bool), center, np.zeros((3, t)), poses,
                          CaptioningConfig(rules=RuleSet.PAPER))
'''


def test_a_write_killed_between_the_two_files_leaves_the_previous_state(make_scene, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "captions"
    write_outputs(out, [small_result(make_scene, 1)])
    before = load(out)
    helpers = tmp_path / "helpers"
    helpers.mkdir()
    (helpers / "captioning_scene.py").write_text(SCENE_MODULE)
    marker = tmp_path / "marker"
    code = CHILD.format(tests=str(helpers), marker=str(marker), out=str(out))
    child = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 60
        while not marker.exists():
            assert child.poll() is None, "the child ended before its second write"
            assert time.monotonic() < deadline, "the child never reached its second write"
            time.sleep(0.05)
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == -signal.SIGKILL
    # The first file of the killed write exists, but only in its unpublished generation.
    assert any(p.name.startswith(".tmp-") for p in (out / GENERATIONS_DIR).iterdir())
    assert load(out) == before
    # The next run removes what the killed one left behind.
    write_outputs(out, [small_result(make_scene, 2)])
    assert not any(p.name.startswith(".tmp-") for p in (out / GENERATIONS_DIR).iterdir())
    assert load(out) != before


def test_caption_command_where_every_log_fails_leaves_outputs_untouched(
    make_scene, tmp_path: Path, capsys: pytest.CaptureFixture[str]  # type: ignore[no-untyped-def]
) -> None:
    out = tmp_path / "captions"
    write_outputs(out, [small_result(make_scene, 1)])
    before = {p.name: p.read_bytes() for p in (out / FRAME_TAGS_FILENAME, out / CAPTIONS_FILENAME)}
    generation = current_generation(out)
    assert main(["caption", str(tmp_path / "no_such_log"), str(tmp_path / "nor_this"), "--out", str(out)]) == 2
    said = capsys.readouterr().out
    assert "skipped log" in said and "left as it was" in said
    assert {p.name: p.read_bytes() for p in (out / FRAME_TAGS_FILENAME, out / CAPTIONS_FILENAME)} == before
    assert current_generation(out) == generation
    fresh = tmp_path / "never_made"  # nothing captioned: not even the folder is made
    assert main(["caption", str(tmp_path / "no_such_log"), "--out", str(fresh)]) == 2 and not fresh.exists()
