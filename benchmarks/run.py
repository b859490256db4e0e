"""Run every benchmark module and write ``benchmarks/results.json``.

A benchmark is a module ``benchmarks/bench_<name>.py`` with ``run(quick: bool) -> dict``. Each
reports figures as ratios against a baseline measured in the same run, plus the raw numbers.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import sys
import time
import traceback
from pathlib import Path

from scenesearch_base.memory import retain_freed_memory
from scenesearch_base.ray_cluster import usable_cpus
from scenesearch_base.threads import shorten_thread_spin


def discover() -> list[str]:
    here = Path(__file__).parent
    return sorted(p.stem for p in here.glob("bench_*.py"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results.json"))
    parser.add_argument("--only", nargs="*", help="benchmark names (without bench_) to run")
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    args = parser.parse_args(argv)
    retain_freed_memory()  # as the command line does: the benchmarks measure what its commands get
    shorten_thread_spin()
    names = discover()
    if args.only:
        names = [n for n in names if n.removeprefix("bench_") in set(args.only)]
    results: dict[str, object] = {}
    if args.out.exists():
        # Keep figures of benchmarks not run this time, so that `--only` updates in place.
        results = json.loads(args.out.read_text()).get("benchmarks", {})
    failed = []
    for name in names:
        print(f"== {name}", flush=True)
        start = time.perf_counter()
        try:
            module = importlib.import_module(f"benchmarks.{name}")
            figures = module.run(quick=args.quick)
        except Exception:  # one failing benchmark must not hide the others
            traceback.print_exc()
            failed.append(name)
            continue
        figures["wall_s"] = round(time.perf_counter() - start, 2)
        previous = results.get(name.removeprefix("bench_"))
        for key in getattr(module, "FIGURES_FROM_OTHER_RUNS", ()):  # e.g. a quality check run on its own
            if isinstance(previous, dict) and key in previous and key not in figures:
                figures[key] = previous[key]
        results[name.removeprefix("bench_")] = figures
        print(json.dumps(figures, indent=2), flush=True)
    payload = {
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": usable_cpus()},
        "benchmarks": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True))
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
