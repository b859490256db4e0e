"""The documentation: generated pages current, the README's quick starts valid commands, every relative link alive."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from retrieval.docs_reference import ROOT, pages

README = ROOT / "README.md"
#: Every Markdown file whose links are checked.
MARKDOWN = [README, *sorted((ROOT / "docs").rglob("*.md"))]
_FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.M | re.S)
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _bash_commands(text: str) -> list[str]:
    """The ``scenesearch …`` lines of the ```bash blocks, continuation lines joined."""
    commands = []
    for language, body in _FENCE.findall(text):
        if language != "bash":
            continue
        for line in body.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words and Path(words[0]).name == "scenesearch":
                commands.append(line.strip())
    return commands


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = _FENCE.sub("", path.read_text(encoding="utf-8"))
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, re.M)}


@pytest.mark.parametrize("relative", sorted(pages()))
def test_generated_page_is_current(relative: str) -> None:
    path = ROOT / relative
    assert path.is_file(), f"{relative} is missing; run: python -m retrieval.docs_reference"
    expected = pages()[relative]()
    assert path.read_text(encoding="utf-8") == expected, f"{relative} is stale; run: python -m retrieval.docs_reference"


def test_readme_quick_starts_parse_with_the_cli() -> None:
    from retrieval.cli import build_parser

    commands = _bash_commands(README.read_text(encoding="utf-8"))
    for needed in ("validate", "caption", "index", "search", "clips", "train", "serve"):
        assert any(shlex.split(c, comments=True)[1] == needed for c in commands), f"no quick start runs {needed}"
    for command in commands:
        words = shlex.split(command, comments=True)
        try:
            build_parser().parse_args(words[1:])
        except SystemExit as exc:  # argparse exits: 0 after --help, 2 on a bad command line
            if exc.code != 0:
                pytest.fail(f"README command does not parse: {command}")


def test_readme_is_short_and_keeps_the_make_targets() -> None:
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    assert "make test" in text and "make demo" in text


def test_the_command_extractor_reads_continuations_and_comments() -> None:
    text = "```bash\nscenesearch index run/ clips/ \\\n    --out index/   # a comment\nmake demo\n```\n"
    assert _bash_commands(text) == ["scenesearch index run/ clips/      --out index/   # a comment"]


@pytest.mark.parametrize("path", MARKDOWN, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path: Path) -> None:
    text = _FENCE.sub("", path.read_text(encoding="utf-8"))
    broken = []
    for target in _LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        resolved = (path.parent / file_part).resolve() if file_part else path
        if not resolved.exists():
            broken.append(f"{target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(f"{target}: no heading #{anchor}")
    assert not broken, f"{path.relative_to(ROOT)}:\n" + "\n".join(broken)
