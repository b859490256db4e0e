"""The layering of ARCHITECTURE: data flows one way, `indexes/` is generic, inference apart from training.

Every import counts, function-level ones included: a circle hidden inside a function is still a circle
for a reader and for anyone who moves the function.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Stage order: a package may import from itself and packages to its left, never from one to its right.
ORDER = ("scenesearch_base", "scenes", "captioning", "scenarios", "encoders", "indexes", "retrieval")
#: `indexes/` is a generic vector store: besides itself it may import the base package alone.
GENERIC = {"indexes": {"scenesearch_base", "indexes"}}
#: Training code that later stages must not import (they use the inference modules instead).
TRAINING_MODULES = {"encoders.train", "encoders.training_loss", "encoders.calibration", "encoders.tagging.training"}
MAX_LINES = 450
#: Folders of modules that are not packages of the layering but are held to the same line limit.
OTHER_CODE = ("benchmarks", "scripts")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    found = {}
    for package in ORDER:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The project module an import of ``name`` loads last (its longest known prefix)."""
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


def _imports(module: str, path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            names = [f"{base}.{alias.name}" for alias in node.names] + [base]
        else:
            continue
        for name in names:
            target = _resolve(name)
            if target is not None and target != module:
                found.add(target)
    return found


GRAPH = {module: _imports(module, path) for module, path in MODULES.items()}


def _stage(module: str) -> str:
    return module.split(".")[0]


def test_no_stage_imports_a_later_one() -> None:
    wrong = []
    for module, targets in GRAPH.items():
        allowed = GENERIC.get(_stage(module), set(ORDER[: ORDER.index(_stage(module)) + 1]))
        wrong += [f"{module} -> {t}" for t in sorted(targets) if _stage(t) not in allowed]
    assert not wrong, "imports against the data flow:\n" + "\n".join(wrong)


def test_later_stages_use_inference_modules_not_training() -> None:
    wrong = [
        f"{module} -> {t}"
        for module, targets in GRAPH.items()
        if _stage(module) in ("indexes", "retrieval")
        for t in sorted(targets & TRAINING_MODULES)
        if not module.startswith("retrieval.commands.train")
    ]
    assert not wrong, "query-time code imports training modules:\n" + "\n".join(wrong)


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    circles: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    circles.append(sorted(component))
    return circles


def test_circle_finder_finds_a_circle() -> None:
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []


def test_no_import_circles() -> None:
    circles = _circles(GRAPH)
    assert not circles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_no_module_is_over_the_line_limit() -> None:
    others = [path for folder in OTHER_CODE for path in sorted((ROOT / folder).rglob("*.py"))]
    wrong = [f"{path.relative_to(ROOT)} ({lines} lines)" for path in [*MODULES.values(), *others]
             if (lines := path.read_text().count("\n")) > MAX_LINES]
    assert not wrong, f"split these (at most {MAX_LINES} lines a module):\n" + "\n".join(wrong)
