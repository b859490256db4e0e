"""The ``scenesearch`` command line.

Each subcommand lives in its own module under :mod:`retrieval.commands` and defines::

    HELP: str                                   # one line for ``scenesearch --help``
    def configure(parser: argparse.ArgumentParser) -> None: ...
    def run(args: argparse.Namespace) -> int: ...   # exit status

Only the module of the command given is imported (all of them for ``scenesearch --help``), so a
command's heavy dependencies (torch, faiss, SUMO) never slow down the others.

The libraries that load models print progress bars and notices of their own (transformers' "Loading
weights" bar as the sentence encoder loads): every command silences them through their documented
switches, ``HF_HUB_DISABLE_PROGRESS_BARS`` and ``TRANSFORMERS_VERBOSITY``, set before they are
imported; ``--verbose`` leaves them on, and a value the user has set in the environment wins.
"""

from __future__ import annotations

import argparse
import importlib
import os
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


#: What silences the model-loading libraries' progress bars and notices (see the module docstring).
QUIET_LIBRARIES = {"HF_HUB_DISABLE_PROGRESS_BARS": "1", "TRANSFORMERS_VERBOSITY": "error"}
VERBOSE_HELP = "show the progress bars and notices of the libraries that load models (e.g. 'Loading weights')"


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of the command ``only`` alone (its module is the only one imported)."""
    parser = argparse.ArgumentParser(
        prog="scenesearch",
        description="Find moments in driving logs by what an object does over time.",
    )
    parser.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            continue
        module = _load(module_name)
        if module is None:
            continue
        command_parser = sub.add_parser(name, help=module.HELP, description=module.HELP)  # type: ignore[attr-defined]
        module.configure(command_parser)  # type: ignore[attr-defined]
        # Also after the command; SUPPRESS keeps a --verbose given before it.
        command_parser.add_argument("--verbose", action="store_true", default=argparse.SUPPRESS, help=VERBOSE_HELP)
        command_parser.set_defaults(_run=module.run)  # type: ignore[attr-defined]
    return parser


def _command_of(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names (its first word that is not an option), when it is a known one."""
    first = next((a for a in argv if not a.startswith("-")), None)
    return first if first in COMMANDS else None


def _quiet_libraries() -> None:
    """Silence the model-loading libraries (see the module docstring): through the environment before they
    are imported, through their own switches where this process has imported them already."""
    for name, value in QUIET_LIBRARIES.items():
        os.environ.setdefault(name, value)
    if "huggingface_hub" in sys.modules and os.environ["HF_HUB_DISABLE_PROGRESS_BARS"] == "1":
        from huggingface_hub.utils import disable_progress_bars

        disable_progress_bars()
    if "transformers" in sys.modules and os.environ["TRANSFORMERS_VERBOSITY"] == "error":
        from transformers.utils import logging as transformers_logging

        transformers_logging.disable_progress_bar()
        transformers_logging.set_verbosity_error()


def main(argv: Sequence[str] | None = None) -> int:
    from scenesearch_base.memory import retain_freed_memory
    from scenesearch_base.threads import shorten_thread_spin

    retain_freed_memory()  # every command moves large arrays: reuse freed memory (see scenesearch_base.memory)
    shorten_thread_spin()  # before torch loads OpenMP: idle threads sleep early (scenesearch_base.threads)
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(_command_of(argv))
    args = parser.parse_args(argv)
    if not args.verbose:
        _quiet_libraries()
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
        if isinstance(exc, OSError):  # a path the system refuses (permissions, a folder, a full disk)
            where = f"{exc.filename}: " if exc.filename and str(exc.filename) not in str(exc) else ""
            if not exc.filename and getattr(args, "out", None) is not None:  # a library's write names no file
                where = f"writing {args.out}: "
            print(f"scenesearch {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
