"""``scenesearch tag RUN_DIR LOG_DIR --attribute ATTR [--region front] [--plot FILE.png]``.

Prints the attribute (or a composition such as ``"stopped & four_way"``) pooled over the region at
every frame of the log: m² covered for densities, m/s for ``vehicle_speed``, a probability for the
other attributes. ``--plot`` also draws it over time.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "print (and plot) a scene tag of one log over time: an attribute pooled over a region"


def configure(parser: argparse.ArgumentParser) -> None:
    from encoders.tagging.attributes import Attribute, Region

    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a trained run with a tagging model")
    parser.add_argument("log_dir", type=Path, metavar="LOG_DIR", help="a log folder (AV2 layout)")
    parser.add_argument("--attribute", required=True,
                        help="attribute or composition ('a & b', 'a | b'); one of: "
                        + ", ".join(a.value for a in Attribute))
    parser.add_argument("--region", default="full", help=f"one of: {', '.join(r.value for r in Region)} (default full)")
    parser.add_argument("--indicator", type=float, metavar="KAPPA",
                        help="use the indicator 1{V >= KAPPA} instead of the value (compositions)")
    parser.add_argument("--plot", type=Path, help="also write a PNG plot of the value over time")
    parser.add_argument("--every", type=int, default=1, help="print every N-th frame (default 1)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.add_argument("--cache", type=Path,
                        help="folder for the log's rendered BEV frames (default RUN_DIR/tag_cache)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from retrieval.tagging import TagSearch

    search = TagSearch(args.run_dir, args.cache)
    h, kappa = ("indicator", args.indicator) if args.indicator is not None else ("identity", 0.5)
    ts, values = search.series(args.log_dir, args.attribute, args.region, h, kappa)
    t_s = (ts - ts[0]) * 1e-9 if ts.shape[0] else np.zeros(0)
    if args.json:
        print(json.dumps({"log_id": args.log_dir.name, "tag": args.attribute, "region": args.region,
                          "timestamps_ns": ts.tolist(), "values": [round(float(v), 4) for v in values]}))
    else:
        print(f"# {args.log_dir.name}: {args.attribute} over {args.region} ({ts.shape[0]} frames)")
        print("time_s  timestamp_ns  value")
        for i in range(0, ts.shape[0], max(1, args.every)):
            print(f"{t_s[i]:7.2f}  {int(ts[i])}  {float(values[i]):.4f}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from scenesearch_base.atomic import atomic_path

        fig, ax = plt.subplots(figsize=(8, 2.8))
        ax.plot(t_s, values, lw=1.5)
        ax.set_xlabel("time (s)")
        ax.set_ylabel(args.attribute)
        ax.set_title(f"{args.log_dir.name}: {args.attribute} — {args.region}")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        with atomic_path(args.plot) as tmp:
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
        print(f"wrote {args.plot}")
    return 0
