"""A larger held-out test split for the everyday-sentence benchmark: fresh simulated logs, the demo's model.

The demo's test split (3 logs, about 280 clips) holds fewer than 10 clips for most everyday sentences,
so precision@10 cannot reach 1 there. This builds a split in which it can: ``LOGS`` sensor logs from a
seed (:data:`SEED`) that neither the demo nor any other benchmark simulates, of the demo's length, cut
into clips with the demo's clip settings, every log in the test split, and indexed with the demo's
trained model (``DEMO/run``). Nothing in it was seen in training or tuning.

``python -m benchmarks.everyday_data [--demo DIR] [--out DIR]`` (or :func:`build_split`) writes into
``DIR`` (default ``benchmarks/_work/everyday``)::

    logs/        the simulated logs (AV2 layout, LiDAR and camera)
    captions/    their rule captions
    clips/       their clips (the demo's ``clips.yaml``, every log in the test split, no previews)
    index/       the index built with the demo's model
    manifest.json  what the folder was built from (a folder that matches is reused)
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from scenesearch_base.atomic import atomic_write_text

#: Seed of the logs: no other benchmark and no demo setting simulates it.
SEED = 7301
#: Sensor logs and their length (the demo's): about 95 clips a log.
LOGS, DURATION_S = 30, 20.0
WORK = Path(__file__).resolve().parent / "_work" / "everyday"
#: Bump when the split changes meaning; a folder of another version is rebuilt.
DATA_VERSION = 1


def _run(argv: list[str]) -> None:
    from retrieval.cli import main

    if main(argv) != 0:
        raise RuntimeError(f"failed: scenesearch {' '.join(argv)}")


def _manifest(demo: Path) -> dict[str, Any]:
    """What the folder's clips come from (``clips``), and which model and formats their index was built
    with (``index``: an index whose stored scenario features are of another format cannot answer)."""
    from encoders.clips.layout import CLIPS_FORMAT_VERSION
    from retrieval.index_manifest import FORMAT_VERSION as INDEX_FORMAT_VERSION
    from scenarios.cache import CACHE_VERSION

    model = demo / "run" / "model.safetensors"
    return {"clips": {"version": DATA_VERSION, "seed": SEED, "logs": LOGS, "duration_s": DURATION_S,
                      "clips_yaml": (demo / "clips.yaml").read_text(), "clips_format": CLIPS_FORMAT_VERSION},
            "index": {"demo_run": str((demo / "run").resolve()), "index_format": INDEX_FORMAT_VERSION,
                      "scenario_features": CACHE_VERSION,
                      "model_bytes": model.stat().st_size if model.is_file() else None,
                      "model_mtime_ns": model.stat().st_mtime_ns if model.is_file() else None}}


def build_split(demo: Path, root: Path | None = None, rebuild: bool = False) -> Path:
    """Build (or reuse) the split in ``root`` and return its index folder (see the module docstring): the
    clips are made again when what they come from changed, the index when they, the model or the formats
    it stores did.

    Raises:
        FileNotFoundError: ``demo`` has no trained run or no ``clips.yaml``.
    """
    from encoders.clips.config import ClipsConfig

    root = Path(root or WORK)
    for needed in (demo / "run", demo / "clips.yaml"):
        if not needed.exists():
            raise FileNotFoundError(f"{needed}: the everyday split needs a finished demo (`make demo`)")
    manifest = _manifest(demo)
    manifest_path = root / "manifest.json"
    built = json.loads(manifest_path.read_text()).get("built", {}) if manifest_path.is_file() else {}
    same_clips = not rebuild and built.get("clips") == manifest["clips"]
    if same_clips and built.get("index") == manifest["index"]:
        return root / "index"
    seconds: dict[str, float] = {}
    if not same_clips:
        if root.exists():
            shutil.rmtree(root)
        root.mkdir(parents=True)
        start = time.perf_counter()
        _run(["simulate", "--out", str(root / "logs"), "--logs", str(LOGS), "--duration-s", str(DURATION_S),
              "--seed", str(SEED), "--overwrite"])
        logs = sorted(str(p) for p in (root / "logs").iterdir() if p.is_dir() and not p.name.startswith("."))
        seconds["simulate"] = time.perf_counter() - start
        start = time.perf_counter()
        _run(["caption", *logs, "--out", str(root / "captions")])
        seconds["caption"] = time.perf_counter() - start
        demo_clips = ClipsConfig.from_yaml(demo / "clips.yaml")
        config = replace(demo_clips, previews=False,
                         split=replace(demo_clips.split, test_only=tuple(Path(p).name for p in logs)))
        config.to_yaml(root / "clips.yaml")
        start = time.perf_counter()
        _run(["clips", *logs, "--captions", str(root / "captions"), "--out", str(root / "clips"),
              "--frames-per-clip", str(config.frames_per_clip), "--config", str(root / "clips.yaml")])
        seconds["clips"] = time.perf_counter() - start
    elif (root / "index").exists():
        shutil.rmtree(root / "index")
    start = time.perf_counter()
    _run(["index", str(demo / "run"), str(root / "clips"), "--out", str(root / "index")])
    seconds["index"] = time.perf_counter() - start
    atomic_write_text(manifest_path, json.dumps({"built": manifest, "seconds": seconds}, indent=2))
    return root / "index"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", type=Path, default=Path("demo_out"), help="the demo's folder (default demo_out)")
    parser.add_argument("--out", type=Path, help=f"folder to build into (default {WORK})")
    parser.add_argument("--rebuild", action="store_true", help="build again even when the folder matches")
    args = parser.parse_args(argv)
    print(build_split(args.demo, args.out, args.rebuild))
    return 0


if __name__ == "__main__":
    sys.exit(main())
