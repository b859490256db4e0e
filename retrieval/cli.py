"""The ``scenesearch`` command line.

Each subcommand lives in its own module under :mod:`retrieval.commands` and defines::

    HELP: str                                   # one line for ``scenesearch --help``
    def configure(parser: argparse.ArgumentParser) -> None: ...
    def run(args: argparse.Namespace) -> int: ...   # exit status

Modules are imported only when their command runs (plus once to build ``--help``), so a
command's heavy dependencies (torch, faiss, SUMO) never slow down the others.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# name -> module under retrieval.commands. Add one line per command.
COMMANDS: dict[str, str] = {
    "validate": "validate",
    "import": "import_",
    "simulate": "simulate",
    "render-sensors": "render_sensors",
    "caption": "caption",
    "track": "track",
    "eval-tracking": "eval_tracking",
    "clips": "clips",
    "train": "train",
    "index": "index",
    "search": "search",
    "similar": "similar",
    "export": "export",
    "eval": "eval",
    "demo": "demo",
    "serve": "serve",
    "tag": "tag",
    "find": "find",
    "eval-tags": "eval_tags",
    "mine": "mine",
    "eval-mining": "eval_mining",
}


def _load(module_name: str) -> object | None:
    try:
        return importlib.import_module(f"retrieval.commands.{module_name}")
    except ModuleNotFoundError as exc:
        # Only a command that does not exist yet is hidden; a broken import inside one is an error.
        if exc.name == f"retrieval.commands.{module_name}":
            return None
        raise


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scenesearch",
        description="Find moments in driving logs by what an object does over time.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module_name in COMMANDS.items():
        module = _load(module_name)
        if module is None:
            continue
        command_parser = sub.add_parser(name, help=module.HELP, description=module.HELP)  # type: ignore[attr-defined]
        module.configure(command_parser)  # type: ignore[attr-defined]
        command_parser.set_defaults(_run=module.run)  # type: ignore[attr-defined]
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from common.memory import retain_freed_memory

    retain_freed_memory()  # every command moves large arrays: reuse freed memory (see common.memory)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except MemoryError as exc:  # what the size checks could not foresee: one line, not a traceback
        print(f"scenesearch {args.command}: error: out of memory ({exc or 'an allocation failed'}); lower the "
              "sizes of this command's inputs or options (batch size, frames, grid)", file=sys.stderr)
        return 2
    except Exception as exc:
        from scenes.errors import ScenesError

        known: tuple[type[BaseException], ...] = (ScenesError, FileNotFoundError, FileExistsError, ValueError)
        if isinstance(exc, known):
            print(f"scenesearch {args.command}: error: {exc}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
