"""One set of rows, rendered as the plain-text table, the Markdown of a model card and the report's HTML."""

from __future__ import annotations

from typing import Any

from retrieval.metrics_tables import metrics_markdown, metrics_rows, metrics_table
from retrieval.report import metrics_html


def _figures(r1: float) -> dict[str, Any]:
    return {"R@1": r1, "R@5": 0.5, "R@10": 0.75, "median_rank": 4, "mAP": 0.25}


def _metrics() -> dict[str, Any]:
    halves = {"object": {"R@5": 0.625, "mAP": 0.375}, "ego": {"R@5": 0.875, "mAP": 0.8125}}
    c2c = {"action_precision@5": 0.3, "appearance_bias": 1.5, "same_log_share_neighbours": 0.9,
           "same_log_share_chance": 0.4, "action_precision@5_ceiling": 0.5, "same_moment_share_neighbours": 0.3,
           "same_moment_share_chance": 0.0625, "action_precision@5_other_moments": 0.2,
           "appearance_bias_other_moments": 1.25, "action_precision@5_ceiling_other_moments": 0.375,
           "appearance_bias_perfect_ranking": 1.5625}
    return {
        "split": "test", "counts": {"clips": 12, "queries": 5, "temporal_pairs": 3},
        "text_to_clip": _figures(0.125), "temporal_order_accuracy": {"accuracy": 0.875},
        "text_order": {"mean_cosine": 0.7, "kept_apart": 0.9},
        "freeform": {"queries": 4, "answered": 3, "precision@10": 0.3}, "halves": halves, "clip_to_clip": c2c,
        "views": {"camera": _figures(0.0625), "bev": _figures(0.1),
                  "camera_clips": {"clips": 6, "queries": 2, "fused": {"R@5": 0.5}, "random": {"R@5": 0.25}}},
        "hybrid": {"weight": 0.4, "chosen_on": "val", "origin": "chosen on 9 val clips", "text_to_clip": _figures(0.75),
                   "temporal_order_accuracy": {"accuracy": 0.9375}, "freeform": {"precision@10": 0.4}},
        "baselines": {
            "random": {"text_to_clip": _figures(0.01), "temporal_order_accuracy": {"accuracy": 0.5},
                       "freeform": {"precision@10": 0.05}, "halves": {}, "clip_to_clip": {"appearance_bias": 1.0}},
            "bag_of_frames": {"text_to_clip": _figures(0.05), "temporal_order_accuracy": {"accuracy": 0.6},
                              "halves": halves},
            "rule_captions": {"text_to_clip": _figures(0.7), "temporal_order_accuracy": {"accuracy": 0.95},
                              "halves": {"object": {"R@5": 1.0, "mAP": 0.96875}}},
        },
    }


def test_the_rows_hold_every_figure_beside_its_baselines() -> None:
    rows = metrics_rows(_metrics())
    assert rows.header == ("figure", "model", "camera only", "bev only", "bag of frames", "random", "rule captions",
                           "hybrid")
    assert all(len(row) == len(rows.header) for row in rows.body)
    by_name = {row[0]: row[1:] for row in rows.body}
    assert by_name["text→clip R@1"] == ("0.125", "0.062", "0.100", "0.050", "0.010", "0.700", "0.750")
    assert by_name["text→clip median_rank"][0] == "4"
    assert by_name["temporal order acc."] == ("0.875", "", "", "0.600", "0.500", "0.950", "0.938")
    # Each half asked alone; a figure a baseline lacks is a dash, not a blank or a zero.
    assert by_name["object sentence alone mAP"] == ("0.375", "", "", "0.375", "—", "0.969", "")
    assert by_name["ego sentence alone R@5"][-2] == "—"
    assert by_name["free-form precision@10"] == ("0.300", "", "", "—", "0.050", "—", "0.400")
    # Hybrid search answers text only: no clip → clip cells.
    assert by_name["clip→clip action_precision@5"][-1] == ""
    assert "rule captions' share 0.400 (chosen on 9 val clips)" in rows.notes[1]
    # How often neighbours share the query's log is compared with the share by chance.
    assert by_name["clip→clip same_log_share_neighbours"][4] == "0.400"
    assert by_name["clip→clip action_precision@5 ceiling"][0] == "0.500"
    # The query's own moment: its share against chance, and the figures outside it with their own ceiling.
    assert by_name["clip→clip same_moment_share_neighbours"][::4] == ("0.300", "0.062")
    assert by_name["clip→clip appearance_bias_other_moments"][0] == "1.250"
    assert by_name["clip→clip action_precision@5 ceiling_other_moments"][0] == "0.375"
    assert by_name["clip→clip appearance_bias of a perfect ranking"][0] == "1.562"
    assert by_name["clip→clip appearance_bias_other_moments of a perfect ranking"][0] == "—"
    assert rows.notes[0] == "12 test clips, 5 caption queries, 3 temporal-order pairs, 3 of 4 free-form queries " \
                            "with a relevant clip"
    assert "over the 6 clips the camera saw" in rows.notes[2]


def test_metrics_from_before_hybrid_search_leave_its_column_blank() -> None:
    metrics = _metrics()
    del metrics["hybrid"]
    rows = metrics_rows(metrics)
    assert all(row[-1] == "" for row in rows.body) and not any("hybrid" in note for note in rows.notes)
    metrics = _metrics()
    metrics["hybrid"].pop("origin")  # metrics.json written before the origin was recorded
    assert "(the default)" in metrics_rows(metrics).notes[1]


def test_the_three_renderings_show_the_same_rows() -> None:
    metrics = _metrics()
    rows = metrics_rows(metrics)
    text, markdown, page = metrics_table(metrics), metrics_markdown(metrics), metrics_html(metrics)
    table_lines = [line for line in markdown.splitlines() if line.startswith("| ")]
    assert table_lines[0] == "| " + " | ".join(rows.header) + " |" and len(table_lines) == len(rows.body) + 1
    assert "- 12 test clips, 5 caption queries" in markdown
    for row in rows.body:
        assert "| " + " | ".join(row) + " |" in markdown
        assert "<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" in page
        assert any(line.split()[:len(row[0].split())] == row[0].split() and row[1] in line
                   for line in text.splitlines())
    assert "(12 test clips, 5 caption queries" in text
