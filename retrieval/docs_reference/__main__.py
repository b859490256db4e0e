"""``python -m retrieval.docs_reference [--check]``: rewrite the generated pages of ``docs/``, or check them."""

from __future__ import annotations

import argparse
import sys

from retrieval.docs_reference import stale, write_all


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m retrieval.docs_reference", description=__doc__)
    parser.add_argument("--check", action="store_true", help="only list the stale pages; exit 1 if any")
    args = parser.parse_args(argv)
    if args.check:
        names = stale()
        for name in names:
            print(f"stale: {name}")
        return 1 if names else 0
    for name in write_all():
        print(f"wrote {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
