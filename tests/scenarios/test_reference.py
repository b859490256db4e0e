"""The scenario language's reference page is the one the code generates."""

from __future__ import annotations

from pathlib import Path

from scenarios.reference import markdown

PAGE = Path(__file__).resolve().parents[2] / "docs" / "reference" / "scenario-language.md"


def test_the_reference_page_is_current() -> None:
    regenerate = "python -m scenarios.reference > docs/reference/scenario-language.md"
    assert PAGE.read_text() == markdown(), f"regenerate: {regenerate}"
