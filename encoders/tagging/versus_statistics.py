"""The tagging head against the dataset statistics: ``eval-tags``' Table 2 row of a run compared with
the statistics row, attribute by attribute (``scenesearch eval``'s ``tagging``, the demo's report and the
quality benchmark read it from here)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from encoders.tagging.evaluate import evaluate_runs
from encoders.tagging.inference import TAGGING_FILE


def beats_statistics(cell: Mapping[str, Any], statistics: Mapping[str, Any]) -> bool | None:
    """Whether a Table 2 cell beats the statistics row's (higher F1, lower L1); None when either is
    undefined (no positive test frame anywhere)."""
    if cell["value"] is None or statistics["value"] is None:
        return None
    if cell["metric"] == "F1":
        return bool(cell["value"] > statistics["value"])
    return bool(cell["value"] < statistics["value"])


def against_statistics(result: Mapping[str, Any]) -> dict[str, Any]:
    """The model's Table 2 row of an :func:`evaluate_runs` result against the dataset statistics.

    Returns:
        ``metric`` (attribute → ``F1`` or ``L1``); ``model`` and ``statistics`` (attribute → value);
        ``above_statistics`` (attribute → :func:`beats_statistics`); ``above_statistics_count`` of the
        ``defined`` attributes (those with a positive test frame somewhere) and ``below_statistics``
        (the others' names); ``skill`` (model and statistics); the held-out ``split``, its number of
        ``test_logs`` and ``frames_test`` (frames per region).
    """
    rows = result["inputs"]
    key = next(k for k in rows if k != "none")  # the evaluated run's row, named by its inputs
    above = {a: beats_statistics(cell, rows["none"][a]) for a, cell in rows[key].items()}
    defined = [a for a, b in above.items() if b is not None]
    return {
        "metric": {a: cell["metric"] for a, cell in rows[key].items()},
        "model": {a: cell["value"] for a, cell in rows[key].items()},
        "statistics": {a: cell["value"] for a, cell in rows["none"].items()},
        "above_statistics": above,
        "above_statistics_count": sum(bool(above[a]) for a in defined),
        "defined": len(defined),
        "below_statistics": [a for a in defined if not above[a]],
        "skill": {"model": result["skill"][key], "statistics": result["skill"]["none"]},
        "split": result["meta"]["split"],
        "test_logs": len(result["meta"]["test_logs"]),
        "frames_test": result["meta"]["frames"],
    }


def against_statistics_summary(versus: Mapping[str, Any]) -> str:
    """One line of :func:`against_statistics`: how many attributes the head beats the statistics on, and which not."""
    below = ", ".join(versus["below_statistics"]) or "none"
    return (f"the tagging head beats the dataset statistics on {versus['above_statistics_count']} of the "
            f"{versus['defined']} attributes defined on the {versus['test_logs']} {versus['split']} log(s) (skill "
            f"{versus['skill']['model']:.3f} against {versus['skill']['statistics']:.3f}; below: {below})")


def tagging_against_statistics(run_dir: Path | str, clips_dir: Path | str, split: str = "test",
                               say: Callable[[str], None] | None = None) -> dict[str, Any] | None:
    """The run's tagging head against the dataset statistics on a split (:func:`against_statistics` of
    :func:`~encoders.tagging.evaluate.evaluate_runs`, whose F1 thresholds and calibrations come from the
    validation logs); ``say`` gets its summary line.

    None for a run trained without tagging, and (saying why) when no log of the split has tag targets,
    so that an evaluation of retrieval goes on without it.
    """
    tell = say or (lambda _line: None)
    if not (Path(run_dir) / TAGGING_FILE).is_file():
        return None
    try:
        versus = against_statistics(evaluate_runs(run_dir, clips_dir, split=split))
    except FileNotFoundError as err:
        tell(f"eval: the tagging head is not scored ({err})")
        return None
    tell(f"eval: {against_statistics_summary(versus)}")
    return versus
