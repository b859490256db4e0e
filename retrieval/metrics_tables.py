"""The figures of :func:`retrieval.evaluation.evaluate` as one table, the model beside every baseline.

One set of rows (:func:`metrics_rows`) rendered three ways: plain text for ``scenesearch eval`` and
the demo's log (:func:`metrics_table`), Markdown for the model card (:func:`metrics_markdown`) and
HTML for the demo's report (:func:`retrieval.report.metrics_html`), so that they never disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from retrieval.freeform import FREEFORM_K


@dataclass(frozen=True)
class MetricsRows:
    """The headline figures against the baselines, ready to render (:func:`metrics_rows`).

    Attributes:
        header: (C,) column names.
        body: (R, C) formatted cells; "" where a figure does not apply to a column.
        notes: sentences that say what the figures were measured over.
    """

    header: tuple[str, ...]
    body: tuple[tuple[str, ...], ...]
    notes: tuple[str, ...]


def metrics_rows(metrics: dict[str, Any]) -> MetricsRows:
    """The figures of ``metrics`` (:func:`evaluate`) as rows: the one table that ``scenesearch eval``
    prints, the demo's report shows and a model card holds (:func:`metrics_table`,
    :func:`metrics_markdown`, :func:`retrieval.report.metrics_html`)."""
    base = metrics["baselines"]
    rule = base.get("rule_captions", {})
    hybrid = metrics.get("hybrid") or {}
    header = ("figure", "model", "camera only", "bev only", "bag of frames", "random", "rule captions", "hybrid")

    def fmt(v: Any) -> str:
        return "—" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v))

    def get(d: dict[str, Any], *keys: str) -> Any:
        for key in keys:
            d = d.get(key, {}) if isinstance(d, dict) else {}
        return None if d == {} else d

    body: list[tuple[str, ...]] = []
    for key in ("R@1", "R@5", "R@10", "median_rank", "mAP"):
        body.append((f"text→clip {key}", fmt(metrics["text_to_clip"][key]), fmt(get(metrics, "views", "camera", key)),
                     fmt(metrics["views"]["bev"][key]), fmt(base["bag_of_frames"]["text_to_clip"][key]),
                     fmt(base["random"]["text_to_clip"][key]), fmt(get(rule, "text_to_clip", key))))
    body.append(("temporal order acc.", fmt(metrics["temporal_order_accuracy"]["accuracy"]), "", "",
                 fmt(base["bag_of_frames"]["temporal_order_accuracy"]["accuracy"]),
                 fmt(base["random"]["temporal_order_accuracy"]["accuracy"]),
                 fmt(get(rule, "temporal_order_accuracy", "accuracy"))))
    for key in ("mean_cosine", "kept_apart"):
        body.append((f"text order {key}", fmt(get(metrics, "text_order", key)), "", "", "", "",
                     fmt(get(rule, "text_order", key))))
    p_key = f"precision@{FREEFORM_K}"
    body.append((f"free-form {p_key}", fmt(get(metrics, "freeform", p_key)), "", "",
                 fmt(get(base, "bag_of_frames", "freeform", p_key)), fmt(get(base, "random", "freeform", p_key)),
                 fmt(get(rule, "freeform", p_key))))
    for name in ("object", "ego"):
        for key in ("R@5", "mAP"):
            body.append((f"{name} sentence alone {key}", fmt(get(metrics, "halves", name, key)), "", "",
                         fmt(get(base, "bag_of_frames", "halves", name, key)),
                         fmt(get(base, "random", "halves", name, key)), fmt(get(rule, "halves", name, key))))
    for key in ("action_precision@5", "appearance_bias", "same_log_share_neighbours", "action_precision@5_other_logs",
                "appearance_bias_other_logs", "same_moment_share_neighbours", "action_precision@5_other_moments",
                "appearance_bias_other_moments"):
        # A share of neighbours is read against the share among all clips, in the random column.
        chance = (get(metrics, "clip_to_clip", key.replace("_neighbours", "_chance")) if key.endswith("_neighbours")
                  else get(base, "random", "clip_to_clip", key))
        body.append((f"clip→clip {key}", fmt(get(metrics, "clip_to_clip", key)), "", "",
                     fmt(get(base, "bag_of_frames", "clip_to_clip", key)), fmt(chance),
                     fmt(get(rule, "clip_to_clip", key))))
    for suffix in ("", "_other_moments"):  # what a perfect ranking reaches
        ceiling = get(metrics, "clip_to_clip", f"action_precision@5_ceiling{suffix}")
        body.append((f"clip→clip action_precision@5 ceiling{suffix}", fmt(ceiling), "", "", "", "", ""))
        bias = get(metrics, "clip_to_clip", f"appearance_bias{suffix}_perfect_ranking")
        body.append((f"clip→clip appearance_bias{suffix} of a perfect ranking", fmt(bias), "", "", "", "", ""))
    # Hybrid search answers text queries only: its cells on the text → clip, order and free-form rows.
    hybrid_cells = {**{f"text→clip {key}": get(hybrid, "text_to_clip", key) for key in ("R@1", "R@5", "R@10",
                                                                                        "median_rank", "mAP")},
                    "temporal order acc.": get(hybrid, "temporal_order_accuracy", "accuracy"),
                    f"free-form {p_key}": get(hybrid, "freeform", p_key)}
    body = [(*row, fmt(hybrid_cells[row[0]]) if hybrid and row[0] in hybrid_cells else "") for row in body]
    counts = metrics.get("counts", {})
    free = metrics.get("freeform", {})
    notes = [f"{counts.get('clips')} {metrics.get('split')} clips, {counts.get('queries')} caption queries, "
             f"{counts.get('temporal_pairs')} temporal-order pairs, {free.get('answered')} of "
             f"{free.get('queries')} free-form queries with a relevant clip"]
    if hybrid:
        chosen = hybrid.get("origin") or "the default"  # WeightChoice.origin, in words
        notes.append(f"hybrid: the model's and rule-caption scores, each standardised per query, mixed with the rule "
                     f"captions' share {fmt(hybrid.get('weight'))} ({chosen})")
    dense = metrics.get("frame_tags") or {}
    for stream, figures in (dense.get("streams") or {}).items():
        tasks = ", ".join(f"{task} {fmt(v)} (majority {fmt(dense['majority'].get(task))})"
                          for task, v in figures.items())
        first, last = dense.get("first_last_motion", {}).get(stream, [None, None])
        notes.append(f"frame tags from the {stream} stream: {tasks}; motion at the first / last tagged frame "
                     f"{fmt(first)} / {fmt(last)}")
    seen = get(metrics, "views", "camera_clips") or {}
    if seen:
        notes.append(f"camera only: over the {seen.get('clips')} clips the camera saw and the {seen.get('queries')} "
                     f"queries with a relevant one among them; there the fused model's R@5 is "
                     f"{fmt(get(seen, 'fused', 'R@5'))} and random's {fmt(get(seen, 'random', 'R@5'))}")
    if metrics.get("tagging"):
        from encoders.tagging.versus_statistics import against_statistics_summary

        notes.append(f"{against_statistics_summary(metrics['tagging'])}; per region: `scenesearch eval-tags`")
    return MetricsRows(header, tuple(body), tuple(notes))


def metrics_table(metrics: dict[str, Any]) -> str:
    """The headline figures against the baselines, as a plain-text table (:func:`metrics_rows`)."""
    rows = metrics_rows(metrics)
    widths = [max(len(r[i]) for r in [rows.header, *rows.body]) for i in range(len(rows.header))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(rows.header, widths)), "  ".join("-" * w for w in widths)]
    lines.extend("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows.body)
    lines.extend(f"({note})" for note in rows.notes)
    return "\n".join(lines)


def metrics_markdown(metrics: dict[str, Any]) -> str:
    """The headline figures against the baselines, as a Markdown table and notes (:func:`metrics_rows`)."""
    rows = metrics_rows(metrics)
    lines = ["| " + " | ".join(rows.header) + " |", "|" + "---|" * len(rows.header)]
    lines.extend("| " + " | ".join(r) + " |" for r in rows.body)
    lines.append("")
    lines.extend(f"- {note[0].upper()}{note[1:]}." for note in rows.notes)
    return "\n".join(lines)
