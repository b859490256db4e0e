"""The scenario language's reference page, generated from its registries: every kind, predicate and
relation with its parameters and defaults, so the page cannot drift from the code.

``python -m scenarios.reference > docs/reference/scenario-language.md`` writes it; a test checks it is current.
"""

from __future__ import annotations

from collections.abc import Mapping

from scenarios.kinds import KIND_NAMES
from scenarios.predicates import PREDICATES
from scenarios.relations import RELATIONS


def _params(defaults: Mapping[str, float | str], choices: Mapping[str, tuple[str, ...]]) -> str:
    parts = []
    for key, value in defaults.items():
        allowed = f" ({' / '.join(choices[key])})" if key in choices else ""
        parts.append(f"`{key}={value:g}`" if isinstance(value, float) else f"`{key}={value}`{allowed}")
    return ", ".join(parts) or "—"


def markdown() -> str:
    """The reference page (Markdown)."""
    lines = [
        "# The scenario language",
        "",
        "Generated from the code by `python -m scenarios.reference`; the guide is "
        "[scenario queries](../guide/scenario-queries.md).",
        "",
        "A program is a kind, or a call `name(program, ..., key=value)`. Lengths are metres (`_m`), "
        "durations seconds (`_s`), speeds m/s, angles degrees (`_deg`).",
        "",
        "## Kinds",
        "",
        ", ".join(f"`{k}`" for k in KIND_NAMES),
        "",
        "## Predicates: `name(objects, key=value)`",
        "",
        "| name | reads | parameters | needs the map |",
        "|---|---|---|---|",
    ]
    for name, spec in sorted(PREDICATES.items()):
        lines.append(f"| `{name}` | {spec.phrase} | {_params(spec.defaults, spec.choices)} | "
                     f"{'yes' if spec.needs_map else ''} |")
    lines += ["", "## Relations: `name(subjects, others, key=value, min_count=1, max_count=…, nearest=…)`", "",
              "`not(...)` keeps the subjects with no such other; `reverse(...)` answers the others; `nearest=N` "
              "counts, at each frame, only the N others nearest each subject (box to box), among those the "
              "second argument selects.", "",
              "| name | reads | parameters | needs the map |", "|---|---|---|---|"]
    for name, rel in sorted(RELATIONS.items()):
        lines.append(f"| `{name}` | {rel.phrase} | {_params(rel.defaults, rel.choices)} | "
                     f"{'yes' if rel.needs_map else ''} |")
    lines += ["", "## Composition", "",
              "| call | selects |", "|---|---|",
              "| `and(a, b, ...)` / `or(a, b, ...)` | objects and frames in all / any of them |",
              "| `excluding(a, b)` | those of `a` not in `b` |",
              "| `not(p)` | a predicate or relation negated |",
              "| `between(subjects, left, right, lateral_m=5)` | subjects with one of `left` on one side and one "
              "of `right` on the other |",
              "| `together(a, min_count=2)` | `a`'s objects at frames where at least that many are selected |",
              "| `for_at_least(a, seconds=1)` | runs of `a` that last that long |",
              "| `then(a, b, within_s=5)` | an object doing `a`, then `b` within that time |",
              "| `before(a, b, within_s=5)` / `after(a, b, within_s=5)` | `a`'s runs that begin at most that long "
              "before / after any object's `b` begins (two objects in turn; a `then` begins at its last step) |",
              "| `while(a, b)` | `a` at frames where any object does `b` |", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown(), end="")
