"""``report.html``: one self-contained page with the metrics, plots and example results of a run.

Plots are PNG files written beside the page by matplotlib (Agg backend, no display needed). Previews
stored in the clips folder are linked relatively; the others are drawn from the clips folder's rendered
frames into ``previews/`` beside the page, so the page, its plots and previews can be moved together
(with the clips folder where it links stored ones).
"""

from __future__ import annotations

import html
import json
import math
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from retrieval.records import SearchResult
from scenesearch_base.atomic import atomic_write_text

MAX_ACTIONS_COLOURED = 9
PLOTTED_FIGURES = ("R@1", "R@5", "R@10", "mAP")


@dataclass(frozen=True)
class Example:
    """One example query and its top results."""

    query: str
    results: list[SearchResult]
    mode: str = "text → clip"


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def read_training_log(path: Path) -> list[dict[str, Any]]:
    """Rows of a ``metrics.jsonl`` (one JSON object per line); unreadable lines are left out."""
    rows: list[dict[str, Any]] = []
    if not path.is_file():
        return rows
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict):
            rows.append(row)
    return rows


def _flatten(row: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in row.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{name}/"))
        else:
            out[name] = value
    return out


def plot_training_curves(rows: Sequence[dict[str, Any]], out_png: Path) -> bool:
    """Losses (left) and validation recall / mAP (right) per epoch; False when there is nothing to plot."""
    if not rows:
        return False
    flat = [_flatten(r) for r in rows]
    x_key = next((k for k in ("epoch", "step", "global_step", "iteration") if k in flat[0]), None)
    losses: dict[str, list[tuple[float, float]]] = {}
    figures: dict[str, list[tuple[float, float]]] = {}
    for i, row in enumerate(flat):
        x = float(row[x_key]) if x_key and isinstance(row.get(x_key), int | float) else float(i)
        for key, value in row.items():
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                continue
            if "loss" in key:
                losses.setdefault(key, []).append((x, float(value)))
            elif key.rsplit("/", 1)[-1] in PLOTTED_FIGURES:
                figures.setdefault(key, []).append((x, float(value)))
    if not losses and not figures:
        return False
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for ax, series, title in ((axes[0], losses, "training loss"), (axes[1], figures, "validation, text → clip")):
        for key, points in sorted(series.items()):
            xs, ys = zip(*points)
            ax.plot(xs, ys, label=key, marker="o" if len(points) < 30 else None)
        ax.set_xlabel(x_key or "record")
        ax.set_title(title)
        if ax.lines:
            ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return True


def pca_2d(x: np.ndarray) -> np.ndarray:
    """(N, 2) projection of (N, D) rows on their first two principal components."""
    centred = np.asarray(x, dtype=np.float64) - np.mean(x, axis=0, keepdims=True)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return np.asarray(centred @ vt[:2].T)


def plot_embedding_map(x: np.ndarray, actions: Sequence[str], out_png: Path, title: str = "") -> bool:
    """A 2-D map (PCA) of clip embeddings (N, D) coloured by action (the most common ones; others grey)."""
    if len(x) < 3:
        return False
    xy = pca_2d(x)
    counts = Counter(actions)
    top = [a for a, _ in counts.most_common(MAX_ACTIONS_COLOURED)]
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 6))
    other = np.array([a not in top for a in actions])
    if other.any():
        ax.scatter(xy[other, 0], xy[other, 1], s=8, c="#cccccc", label=f"other ({int(other.sum())})")
    cmap = plt.get_cmap("tab10")
    for i, action in enumerate(top):
        m = np.array([a == action for a in actions])
        ax.scatter(xy[m, 0], xy[m, 1], s=14, color=cmap(i % 10), label=f"{_short(action, 48)} ({int(m.sum())})")
    ax.set_title(title or "clip embeddings (PCA), coloured by action")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.legend(fontsize=6.5, loc="best", markerscale=1.5)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return True


def plot_recall_curves(curves: dict[str, Any], out_png: Path) -> bool:
    """Recall@K of the model, the single views, the baselines and hybrid search."""
    ks = curves.get("k") or []
    if not ks:
        return False
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    styles = {"model": ("fused model", "-", 2.2), "camera": ("camera only (clips it saw)", "--", 1.3),
              "bev": ("BEV only", "--", 1.3), "bag_of_frames": ("bag of frames", ":", 1.6),
              "random": ("random", "-.", 1.3), "rule_captions": ("rule captions", ":", 1.3),
              "hybrid": ("hybrid (model + rule captions)", "-", 1.3)}
    for key, (label, style, width) in styles.items():
        ys = curves.get(key)
        if ys:
            ax.plot(ks[: len(ys)], ys, style, linewidth=width, label=label)
    ax.set_xlabel("K")
    ax.set_ylabel("recall@K (text → clip)")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return True


def _short(text: str, n: int) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


def metrics_html(metrics: dict[str, Any]) -> str:
    """The figures of ``scenesearch eval`` against its baselines (rule-caption search among them), the same
    rows as its printed table (:func:`retrieval.metrics_tables.metrics_rows`)."""
    from retrieval.metrics_tables import metrics_rows

    rows = metrics_rows(metrics)
    out = ["<table class='metrics'><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in rows.header) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows.body]
    out.append("</table>")
    notes = ["Queries are the split's unique canonical captions (or one half of them: the object's sentence, the "
             "ego's); a clip is relevant when its caption matches. Free-form queries are held-out everyday "
             "sentences whose relevance comes from each clip's tags. Lower is better for the median rank and the "
             "appearance bias", *rows.notes]
    out += [f"<p class='note'>{html.escape(note[0].upper() + note[1:])}.</p>" for note in notes]
    return "\n".join(out)


def draw_preview(result: SearchResult, out_dir: Path, clips_dir: Path, referred: Sequence[str] = (),
                 related: Sequence[str] = ()) -> Path | None:
    """Draw the result's preview from ``clips_dir``'s rendered frames into ``out_dir/previews/``, marking
    ``referred`` and ``related`` tracks (a drawing per clip and marks, drawn once); None when the clips
    folder cannot draw it (no rendered frames of its log, the clip not in its table, damaged arrays),
    so that one clip never stops a report."""
    import hashlib

    from encoders.clips.layout import preview_file_name, rendered_log_dir
    from encoders.clips.preview import preview_gif
    from scenesearch_base.atomic import atomic_path

    if not rendered_log_dir(Path(clips_dir), result.log_id).is_dir():
        return None
    name = preview_file_name(result.clip_id)
    if referred or related:  # the same clip may be shown unmarked elsewhere on the page
        marks = hashlib.blake2b(repr((tuple(referred), tuple(related))).encode(), digest_size=4).hexdigest()
        name = f"{Path(name).stem}_{marks}{Path(name).suffix}"
    path = Path(out_dir) / "previews" / name
    if path.is_file():
        return path
    try:
        data = preview_gif(clips_dir, result.clip_id, referred=referred, related=related)
    except (OSError, ValueError, KeyError):
        return None
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(data)
    return path


def preview_html(result: SearchResult, out_dir: Path, clips_dir: Path | None = None, referred: Sequence[str] = (),
                 related: Sequence[str] = ()) -> str:
    """The result's preview as an image linked relative to the page: drawn from ``clips_dir`` (marking
    ``referred`` and ``related`` tracks) where no preview was stored or tracks are to be marked, else the
    stored one; a placeholder when neither is at hand."""
    stored = Path(result.preview_path) if result.preview_path and Path(result.preview_path).is_file() else None
    path = stored
    if clips_dir is not None and (stored is None or referred or related):
        path = draw_preview(result, out_dir, clips_dir, referred, related) or stored
    if path is None:
        return "<div class='nopreview'>no preview</div>"
    rel = os.path.relpath(path, out_dir)
    return f"<img src='{html.escape(rel)}' alt='preview of {html.escape(result.clip_id)}' loading='lazy'>"


def examples_html(examples: Sequence[Example], out_dir: Path, clips_dir: Path | None = None) -> str:
    parts = []
    for ex in examples:
        cards = []
        for r in ex.results:
            cards.append(
                "<div class='card'>" + preview_html(r, out_dir, clips_dir) +
                f"<div class='meta'><b>#{r.rank}</b> score {r.score:.3f} · {html.escape(r.category)}<br>"
                f"<span class='cap'>{html.escape(r.caption)}</span><br>"
                f"<code>{html.escape(r.clip_id)}</code></div></div>")
        parts.append(f"<h3>{html.escape(ex.mode)}: “{html.escape(ex.query)}”</h3>"
                     f"<div class='cards'>{''.join(cards) or '(no results)'}</div>")
    return "\n".join(parts)


CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
h1{margin-bottom:0} .sub{color:#666;margin-top:.2em}
table{border-collapse:collapse;margin:1em 0} th,td{border:1px solid #ddd;padding:4px 10px;text-align:right}
th:first-child,td:first-child{text-align:left} th{background:#f4f4f4}
.cards{display:flex;gap:12px;flex-wrap:wrap} .card{width:260px;border:1px solid #ddd;border-radius:6px;padding:6px}
.card img{width:100%;image-rendering:pixelated} .nopreview{height:120px;background:#eee;color:#888;display:flex;
align-items:center;justify-content:center} .meta{font-size:12px} .cap{color:#333} code{font-size:10px;color:#777}
.plots img{max-width:100%;border:1px solid #eee;margin:.5em 0} .note{color:#666;font-size:13px}
"""


def write_report(out_dir: Path, metrics: dict[str, Any] | None, examples: Sequence[Example],
                 run_dir: Path | None = None, embedding_map: tuple[np.ndarray, Sequence[str]] | None = None,
                 stage_timings_s: dict[str, float] | None = None, title: str = "scenesearch demo",
                 notes: Sequence[str] = (), sections: Sequence[str] = (), clips_dir: Path | None = None) -> Path:
    """Write ``out_dir/report.html`` and its plots (``out_dir/plots/*.png``); returns the page's path.

    ``sections`` are extra HTML fragments (already escaped), placed after the example queries.
    ``clips_dir``: the examples' clips folder, whose rendered frames draw the previews it does not store.
    """
    out_dir = Path(out_dir)
    plots = out_dir / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    figures: list[tuple[str, str]] = []
    if run_dir is not None and plot_training_curves(read_training_log(Path(run_dir) / "metrics.jsonl"),
                                                    plots / "training_curves.png"):
        figures.append(("Training curves", "plots/training_curves.png"))
    if embedding_map is not None and plot_embedding_map(embedding_map[0], embedding_map[1],
                                                        plots / "embedding_map.png"):
        figures.append(("Clip embeddings coloured by action (unified tag sequence)", "plots/embedding_map.png"))
    if metrics is not None and plot_recall_curves(metrics.get("curves", {}), plots / "recall_at_k.png"):
        figures.append(("Recall@K, text → clip, against baselines", "plots/recall_at_k.png"))
    body = [f"<h1>{html.escape(title)}</h1>"]
    if stage_timings_s:
        total = sum(stage_timings_s.values())
        stages = ", ".join(f"{html.escape(k)} {v:.0f} s" for k, v in stage_timings_s.items())
        body.append(f"<p class='sub'>stages: {stages} (total {total / 60:.1f} min)</p>")
    body.extend(f"<p class='note'>{html.escape(n)}</p>" for n in notes)
    if metrics is not None:
        body.append("<h2>Metrics against baselines</h2>")
        body.append(metrics_html(metrics))
    if examples:
        body.append("<h2>Example queries</h2>")
        body.append(examples_html(examples, out_dir, clips_dir))
    body.extend(sections)
    if figures:
        body.append("<h2>Plots</h2><div class='plots'>")
        body.extend(f"<h3>{html.escape(t)}</h3><img src='{src}' alt='{html.escape(t)}'>" for t, src in figures)
        body.append("</div>")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{CSS}</style></head><body>{''.join(body)}</body></html>\n")
    path = out_dir / "report.html"
    atomic_write_text(path, page)
    return path
