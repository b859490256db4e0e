"""The report's section on spatio-temporal tags: the head against the dataset statistics, pooled tags
over a test log, and the spans ``find`` ranks.

A trained run with a tagging model answers tag queries from the universal BEV embedding. This
section shows what it says about held-out logs: the head's figures per attribute against the dataset
statistics (as ``scenesearch eval`` measured them), four pooled tags over time (a plot beside the page)
and the spans where a vehicle is stopped in front, each checked against the simulator's behaviour
labels where the clips carry them. The span threshold is the one with the best frame F1 on the
validation logs (on the training logs when no validation frame is positive), never on the test logs.
The fragments go into :func:`retrieval.report.write_report` as ``sections``.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

if TYPE_CHECKING:
    from retrieval.tagging import TagSearch

#: (tag, region) pairs plotted over time.
PLOTTED_TAGS = (("vehicle_density", "front"), ("pedestrian_density", "around"), ("stopped", "front"),
                ("braking", "front"))
#: The tag query whose spans the section lists.
FOUND_TAG, FOUND_REGION = "stopped", "front"
MAX_SPANS = 5
MIN_SPAN_S = 1.0
SOURCE_NAMES = {"val": "validation logs", "train": "training logs", "default": "default (no labelled logs)"}


def tag_sections(run_dir: Path, clips_dir: Path, log_dirs: Sequence[Path], meta: pa.Table, out_dir: Path,
                 say: Callable[[str], None] = print, versus: Mapping[str, Any] | None = None) -> list[str]:
    """HTML fragments of the tag section (empty when the run has no tagging model).

    Args:
        run_dir: the trained run (``tagging.json`` beside the model when it tags).
        clips_dir: the clips the run was trained on (behaviour-label targets per rendered log).
        log_dirs: the log folders; their names are log ids.
        meta: the indexed clips' metadata (``log_id`` and ``split`` columns).
        out_dir: the report's folder; the plot goes to ``out_dir/plots/tags_over_time.png``.
        say: prints one summary line.
        versus: the head against the dataset statistics (``metrics.json``'s ``tagging``), tabled when given.
    """
    if not (run_dir / "tagging.json").is_file():
        return []
    from retrieval.tagging import TagSearch

    rows = meta.to_pylist()
    test_logs = sorted({str(r["log_id"]) for r in rows if r.get("split") == "test"})
    logs = [d for d in log_dirs if d.name in test_logs] or list(log_dirs[:1])
    tags = TagSearch(run_dir, clips_dir=clips_dir)
    _plot_tags_over_time(tags, logs[0], out_dir / "plots" / "tags_over_time.png")
    split_of = {str(r["log_id"]): str(r.get("split")) for r in rows}
    held = {s: [d for d in log_dirs if split_of.get(d.name) == s] for s in ("val", "train")}
    threshold, truth, source = _tag_threshold(tags, clips_dir, held, logs)
    spans = tags.find(logs, FOUND_TAG, FOUND_REGION, threshold=threshold, min_duration_s=MIN_SPAN_S, k=MAX_SPANS)
    first_ns = {d.name: int(tags.frames(d).timestamps_ns[0]) for d in logs}
    confirmed = []
    for s in spans:
        ts = tags.frames(next(d for d in logs if d.name == s.log_id)).timestamps_ns
        inside = (ts >= s.start_ns) & (ts <= s.end_ns)
        hit = truth.get(s.log_id)
        confirmed.append(None if hit is None else float(hit[inside].mean()) if inside.any() else 0.0)
    table_rows = "".join(
        f"<tr><td>{html.escape(s.log_id[:8])}</td><td>{(s.start_ns - first_ns[s.log_id]) * 1e-9:.1f}"
        f"</td><td>{s.duration_s:.1f}</td><td>{s.score:.2f}</td>"
        f"<td>{'–' if c is None else f'{c:.0%}'}</td></tr>" for s, c in zip(spans, confirmed))
    known = [c for c in confirmed if c is not None]
    precision = (f"; the labels confirm {sum(c > 0.5 for c in known)} of {len(known)} (most of a span's frames)"
                 if known else "")
    say(f"tags: {len(spans)} spans where a vehicle is stopped in front, in {len(logs)} test log(s) "
        f"(threshold {threshold:.2f} from the {source}{precision})")
    return ["<h2>Spatio-temporal tags from the universal BEV embedding</h2>",
            *statistics_section(versus),
            "<p>Pooled attribute values over a held-out log (densities in m², probabilities otherwise):</p>",
            "<img src='plots/tags_over_time.png' alt='tags over time'>",
            "<h3>scenesearch find RUN LOG... --tag stopped --region front</h3>",
            f"<p>Test logs; threshold {threshold:.2f}, the best frame F1 against the behaviour labels on the "
            f"{source}. <i>labelled</i>: share of the span's frames whose labels put a stopped vehicle "
            f"in front{html.escape(precision)}.</p>",
            "<table><tr><th>log</th><th>start (s into the log)</th><th>duration (s)</th><th>score</th>"
            f"<th>labelled</th></tr>{table_rows}</table>" if spans else f"<p>no span above {threshold:.2f}</p>"]


def statistics_section(versus: Mapping[str, Any] | None) -> list[str]:
    """The tagging head against the dataset statistics (``metrics.json``'s ``tagging``, from ``scenesearch
    eval``) as a table; empty without it."""
    if not versus:
        return []
    from encoders.tagging.evaluate import cell_text
    from encoders.tagging.versus_statistics import against_statistics_summary

    rows = "".join(
        f"<tr><td>{html.escape(a)}</td><td>{html.escape(versus['metric'][a])}</td>"
        f"<td>{cell_text(versus['statistics'][a])}</td><td>{cell_text(versus['model'][a])}</td>"
        f"<td>{'n/a' if above is None else 'yes' if above else 'no'}</td></tr>"
        for a, above in versus["above_statistics"].items())
    return ["<h3>The head against the dataset statistics</h3>",
            f"<p>{html.escape(versus['split'].capitalize())} logs; mean over regions of F1 (higher is better) or L1 "
            "(lower is better; densities in m², speed in m/s), thresholds and calibrations from the validation logs; "
            f"{html.escape(against_statistics_summary(versus))}. Per region: <code>scenesearch eval-tags RUN CLIPS "
            "--out DIR</code>.</p>",
            "<table><tr><th>attribute</th><th>metric</th><th>statistics</th><th>model</th><th>beats them</th></tr>"
            f"{rows}</table>"]


def _plot_tags_over_time(tags: TagSearch, log_dir: Path, out_png: Path) -> None:
    """One panel per :data:`PLOTTED_TAGS` pair: its pooled value over the log's frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(PLOTTED_TAGS), 1, figsize=(9, 1.8 * len(PLOTTED_TAGS)), sharex=True)
    for ax, (tag, region) in zip(axes, PLOTTED_TAGS):
        ts, values = tags.series(log_dir, tag, region)
        ax.plot((ts - ts[0]) * 1e-9, values)
        ax.set_ylabel(f"{tag}\n{region}", fontsize=8)
    axes[-1].set_xlabel(f"time in log {log_dir.name[:8]} (s)")
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=90)
    plt.close(fig)


def _tag_threshold(tags: TagSearch, clips_dir: Path, held: dict[str, list[Path]],
                   test_logs: list[Path]) -> tuple[float, dict[str, NDArray[np.bool_]], str]:
    """The span threshold with the best frame F1 on the validation logs — on the training logs
    when no validation frame is positive — (0.5 without labels), the per-frame truth of the test
    logs (empty without tag targets), and which logs chose the threshold."""
    from encoders.tagging.evaluate import held_out_threshold, pooled_truth_and_pred
    from encoders.tagging.targets import has_targets

    factor = tags.tagger.downsample

    def truth_of(d: Path) -> NDArray[np.bool_] | None:
        if not has_targets(clips_dir, d.name):
            return None
        pooled = pooled_truth_and_pred(clips_dir, d.name, None, factor, (FOUND_TAG,))[0]
        return np.asarray(pooled[FOUND_TAG][FOUND_REGION] > 0)

    def pooled(logs: list[Path]) -> tuple[NDArray[np.float32] | None, NDArray[np.bool_] | None]:
        labelled = [(d, t) for d, t in ((d, truth_of(d)) for d in logs) if t is not None]
        if not any(t.any() for _, t in labelled):
            return None, None  # skipped without running the model
        return (np.concatenate([tags.series(d, FOUND_TAG, FOUND_REGION)[1] for d, _ in labelled]),
                np.concatenate([t for _, t in labelled]))

    threshold, source = held_out_threshold((split, *pooled(logs)) for split, logs in held.items())
    test = {d.name: truth_of(d) for d in test_logs}
    return threshold, {k: v for k, v in test.items() if v is not None}, SOURCE_NAMES[source]
