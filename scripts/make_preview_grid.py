"""Make the README's clip preview grid: one still frame per clip, camera and BEV side by side.

    .venv/bin/python scripts/make_preview_grid.py --out docs/images/clip_previews.png
    .venv/bin/python scripts/make_preview_grid.py --clips CLIPS_DIR --out grid.png --count 6

Without ``--clips`` it builds a small clips folder first: one simulated log with rendered sensors
(``scenesearch simulate``, the sensor simulation, ``scenesearch caption``), or the synthetic log of
:mod:`tests.encoders.clip_fixtures` where the simulator is unavailable.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def build_demo_clips(work: Path, seed: int) -> Path:
    from encoders.clips.build import build_clips
    from encoders.clips.config import ClipsConfig

    logs_dir, captions = work / "logs", work / "captions"
    try:
        subprocess.run([sys.executable, "-m", "retrieval.cli", "simulate", "--out", str(logs_dir), "--logs", "1",
                        "--duration-s", "20", "--seed", str(seed)], check=True, capture_output=True, cwd=ROOT)
        from scenes.sensorsim.render import render_log_sensors

        logs = sorted(p for p in logs_dir.iterdir() if p.is_dir())
        for log_dir in logs:
            render_log_sensors(log_dir, progress=False)
        subprocess.run([sys.executable, "-m", "retrieval.cli", "caption", *map(str, logs), "--out", str(captions)],
                       check=True, capture_output=True, cwd=ROOT)
    except (subprocess.CalledProcessError, ImportError, OSError) as exc:
        print(f"simulator unavailable ({exc}); using the synthetic log", file=sys.stderr)
        from tests.encoders.clip_fixtures import synthetic_captions, write_synthetic_log

        logs = [write_synthetic_log(logs_dir, num_frames=40)]
        captions.mkdir(parents=True, exist_ok=True)
        pq.write_table(synthetic_captions(logs), captions / "captions.parquet")
    clips = work / "clips"
    build_clips(logs, captions, clips, replace(ClipsConfig(), previews=False))
    return clips


def pick_clips(clips_dir: Path, count: int) -> list[str]:
    """Clips with a camera view first, one per distinct tag sequence, in table order."""
    from encoders.clips.layout import read_clip_table

    rows = read_clip_table(clips_dir).to_pylist()
    rows.sort(key=lambda r: (not r["has_camera"], r["clip_id"]))
    chosen, seen = [], set()
    for row in rows:
        key = tuple(row["tags"])
        if key not in seen:
            chosen.append(row["clip_id"])
            seen.add(key)
        if len(chosen) == count:
            return chosen
    return (chosen + [r["clip_id"] for r in rows if r["clip_id"] not in chosen])[:count]


def main() -> int:
    from encoders.clips.layout import read_clip_rows
    from encoders.clips.preview import write_preview_grid

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=Path, help="an existing clips folder (default: build a small one)")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--count", type=int, default=6)
    parser.add_argument("--columns", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        clips = args.clips or build_demo_clips(Path(tmp), args.seed)
        ids = pick_clips(clips, args.count)
        write_preview_grid(clips, ids, args.out, columns=args.columns)
        for row in read_clip_rows(clips, ids):
            print(f"{row['clip_id']}: {row['caption']}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
