"""Small Markdown helpers shared by the generated pages."""

from __future__ import annotations

import inspect
import re
import textwrap
from collections.abc import Sequence

#: The line every generated page opens with, after its title.
GENERATED = "Generated from the code by `python -m retrieval.docs_reference`: edit the code, not this page."


_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")


def rst(text: str) -> str:
    """Docstring roles as Markdown: ``:class:`~a.B``` becomes ```a.B```; double backticks stay as they are."""
    return _ROLE.sub(lambda m: f"``{m.group(1)}``", text)


def page(lines: Sequence[str]) -> str:
    """The page's text: the lines joined, runs of blank lines cut to one, one newline at the end."""
    out: list[str] = []
    for line in lines:
        if line == "" and (not out or out[-1] == ""):
            continue
        out.append(line)
    return "\n".join(out).rstrip("\n") + "\n"


def cell(text: object) -> str:
    """``text`` as one table cell: on one line, pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def code(text: object) -> str:
    """``text`` as inline code (backticks inside it are doubled around)."""
    value = str(text)
    return f"`` {value} ``" if "`" in value else f"`{value}`"


def table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> list[str]:
    """A Markdown table's lines."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return lines


def fence(text: str, language: str = "text") -> list[str]:
    """``text`` in a fenced block."""
    return [f"```{language}", text.rstrip("\n"), "```"]


def docstring_blocks(obj: object) -> tuple[str, str]:
    """The summary paragraph of ``obj``'s docstring (joined into one line) and the rest, dedented."""
    doc = inspect.getdoc(obj) or ""
    summary, _, rest = doc.partition("\n\n")
    return rst(" ".join(summary.split())), rst(rest.strip("\n"))


def attribute_docs(cls: type) -> dict[str, str]:
    """Field name → its text in the ``Attributes:`` section of ``cls``'s docstring (Google style)."""
    doc = inspect.getdoc(cls) or ""
    found: dict[str, str] = {}
    inside, current, indent = False, "", 0
    for line in doc.splitlines():
        stripped = line.strip()
        if not inside:
            inside = stripped == "Attributes:"
            continue
        if not stripped:
            current = ""
            continue
        depth = len(line) - len(line.lstrip())
        if depth == 0:  # the next section (e.g. "Upper bounds: ...") ends the attributes
            break
        head, sep, text = stripped.partition(":")
        names = [n.strip() for n in head.split(",")]
        if sep and (not current or depth <= indent) and all(n.replace("_", "").isalnum() for n in names):
            current, indent = head, depth
            found[head] = text.strip()
        elif current:
            found[current] = f"{found[current]} {stripped}".strip()
    # "width_px, height_px: size of ..." documents both fields.
    return {name.strip(): rst(text) for head, text in found.items() for name in head.split(",")}


_BORDER = re.compile(r"^=+( +=+)+ *$")
_SECTION = re.compile(r"^(Args|Arguments|Returns|Raises|Attributes|Yields|Example|Examples|Note|Notes):$")


def rst_to_markdown(doc: str) -> list[str]:
    """A module docstring as Markdown lines: literal blocks (after ``::``) and simple tables fenced."""
    lines = doc.strip("\n").splitlines()
    out: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if _BORDER.match(line):  # a simple table: top border, header, separator, rows, bottom border
            block, borders = [], 0
            while i < len(lines) and borders < 3:
                borders += bool(_BORDER.match(lines[i]))
                block.append(lines[i])
                i += 1
            out += fence("\n".join(block))
            continue
        if line.rstrip().endswith("::"):
            text = line.rstrip()[:-1]
            out.append(rst(text.rstrip(":") + ":" if text.strip() != ":" else ""))
            i += 1
            block = []
            while i < len(lines) and (not lines[i].strip() or lines[i].startswith(" ")):
                block.append(lines[i])
                i += 1
            out += ["", *fence(textwrap.dedent("\n".join(block)).strip("\n")), ""]
            continue
        if _SECTION.match(line):  # Google style: "Args:" then indented entries, as a list
            out += [f"**{line.strip()}**", ""]
            i += 1
            entries: list[str] = []
            base = None
            while i < len(lines) and (lines[i].startswith(" ") or not lines[i].strip()):
                text = lines[i]
                i += 1
                if not text.strip():
                    continue
                depth = len(text) - len(text.lstrip())
                base = depth if base is None else base
                if depth <= base or not entries:
                    entries.append("- " + rst(text.strip()))
                else:
                    entries[-1] += " " + rst(text.strip())
            out += [*entries, ""]
            continue
        if line.startswith(">>>"):  # doctest lines
            block = []
            while i < len(lines) and lines[i].startswith((">>>", "...")):
                block.append(lines[i])
                i += 1
            out += fence("\n".join(block), "python")
            continue
        out.append(rst(line))
        i += 1
    return out
