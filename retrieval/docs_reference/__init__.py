"""The generated reference pages of ``docs/``: each is a function of the code (or of
``benchmarks/results.json``), so a page cannot drift from what it documents.

``python -m retrieval.docs_reference`` rewrites every page; ``--check`` only says which are stale
(exit 1), as ``tests/test_docs.py`` does. The pages:

=================================  =================================================================
``docs/reference/cli.md``          every ``scenesearch`` command and option, from ``retrieval.cli.build_parser()``
``docs/reference/configuration.md`` every key of every config file, from the config dataclasses
                                   (type, default, upper bound, the ``Attributes:`` text of its class)
``docs/reference/folders.md``      each folder kind scenesearch writes, its marker, files and columns
``docs/reference/python-api.md``   the public classes and functions, from their signatures and docstrings
``docs/results.md``                every figure of ``benchmarks/results.json``
=================================  =================================================================

The scenario language's page has a generator of its own (:mod:`scenarios.reference`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

#: The repository root: pages are written under ``ROOT / "docs"``.
ROOT = Path(__file__).resolve().parents[2]


def pages() -> dict[str, Callable[[], str]]:
    """Each generated page's path (relative to the repository root) → the function that writes it."""
    from retrieval.docs_reference import api_page, cli_page, config_page, folders_page, results_page

    return {
        "docs/reference/cli.md": cli_page.markdown,
        "docs/reference/configuration.md": config_page.markdown,
        "docs/reference/folders.md": folders_page.markdown,
        "docs/reference/python-api.md": api_page.markdown,
        "docs/results.md": lambda: results_page.markdown(ROOT / "benchmarks" / "results.json"),
    }


def stale(root: Path = ROOT) -> list[str]:
    """The generated pages whose file differs from what the code generates now (missing ones included)."""
    out = []
    for relative, generate in pages().items():
        path = root / relative
        if not path.is_file() or path.read_text(encoding="utf-8") != generate():
            out.append(relative)
    return out


def write_all(root: Path = ROOT) -> list[str]:
    """Rewrite every generated page; returns the pages whose content changed."""
    from scenesearch_base.atomic import atomic_write_text

    changed = []
    for relative, generate in pages().items():
        path = root / relative
        text = generate()
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, text)
            changed.append(relative)
    return changed
