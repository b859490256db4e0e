"""The demo report's scenario query: a description, the program it compiles to, and the moments it selects,
each drawn from above at the middle of its window around the object the program refers to (red), with the
objects it relates to (orange) and the ego (blue), beside the moment's camera preview.

The drawing reads the index's scenario features (:class:`retrieval.scenario_search.ScenarioStore`), so it
shows what the program saw: boxes turned to the ego's heading (its forward up the page, its left to the left).
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from retrieval.records import SearchResult
from retrieval.report import preview_html, pyplot
from retrieval.scenario_search import ScenarioMatch
from scenarios.features import LogFeatures

if TYPE_CHECKING:
    from retrieval.scenesearch import SceneSearch

#: Half the side of the square drawn around the referred object, metres.
VIEW_M = 30.0
_REFERRED, _RELATED, _EGO, _OTHER = "#d62728", "#ff7f0e", "#1f77b4", "#bbbbbb"


def _corners_xy(center_xy: np.ndarray, yaw_rad: float, length_m: float, width_m: float) -> np.ndarray:
    """(4, 2) corners of a box on the ground."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length_m / 2, width_m / 2]
    return np.asarray(center_xy + half @ np.array([[c, s], [-s, c]]))


def draw_moment(x: LogFeatures, result: SearchResult, referred: Sequence[str], related: Sequence[str],
                out_png: Path) -> bool:
    """Draw the moment's middle frame from above around the referred object, turned to the ego's heading, into
    ``out_png``; False when the log holds no frame."""
    if x.num_frames == 0:
        return False
    plt = pyplot()
    middle_ns = (result.start_ns + result.end_ns) // 2
    f = int(np.argmin(np.abs(x.timestamps_ns - middle_ns)))
    ego = x.ego_index
    ids = x.track_ids.tolist()
    at = [ids.index(t) for t in (*referred, result.track_id) if t in ids and x.valid[ids.index(t), f]]
    origin = x.xy_m[at[0] if at else ego, f].astype(np.float64)  # the view's centre
    ego_yaw = float(x.yaw_rad[ego, f])
    c, s = np.cos(-ego_yaw), np.sin(-ego_yaw)
    to_ego = np.array([[c, -s], [s, c]])  # city → ego rotation
    colour = {i: _OTHER for i in range(x.num_objects)}
    colour.update({ids.index(t): _RELATED for t in related if t in ids})
    colour.update({ids.index(t): _REFERRED for t in referred if t in ids})
    colour[ego] = _EGO
    fig, ax = plt.subplots(figsize=(3.2, 3.2), dpi=90)
    for k in np.flatnonzero(x.valid[:, f]):
        center = to_ego @ (x.xy_m[k, f].astype(np.float64) - origin)
        if np.abs(center).max() > VIEW_M * 1.2:
            continue
        length_m, width_m = (float(v) for v in x.size_lwh_m[k, :2])
        box = _corners_xy(center, float(x.yaw_rad[k, f]) - ego_yaw, length_m, width_m)
        # Drawn with x forward pointing up the page: page (horizontal, vertical) = (−y, x).
        ax.fill(-box[:, 1], box[:, 0], color=colour[int(k)], alpha=0.9 if colour[int(k)] != _OTHER else 0.6,
                zorder=3 if colour[int(k)] != _OTHER else 2)
    ax.set_xlim(-VIEW_M, VIEW_M)
    ax.set_ylim(-VIEW_M, VIEW_M)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)
    ax.set_title(f"t = {(x.timestamps_ns[f] - x.timestamps_ns[0]) / 1e9:.1f} s in the log", fontsize=7)
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png)
    plt.close(fig)
    return True


def scenario_section(search: SceneSearch, query: str, k: int, out_dir: Path) -> tuple[str, list[SearchResult],
                                                                                      ScenarioMatch]:
    """The report's HTML fragment for ``query`` (its drawings under ``out_dir/plots``), its results and match."""
    results, match = search.search_scenario(query, k=k)
    program = match.compiled.text if match.compiled is not None else "(none)"
    reads = match.compiled.rendering if match.compiled is not None else ""
    head = (f"<h2>Scenario query</h2><p>“{html.escape(query)}” compiles to <code>{html.escape(program)}</code>"
            f"{f' (reads: {html.escape(reads)})' if reads else ''}; it selects {len(match.clip_ids)} of "
            f"{len(search)} moments, ranked by the model.</p>")
    if match.fallback:
        head += f"<p class='note'>{html.escape(match.fallback)}</p>"
    head += ("<p class='note'>Each moment from above at the middle of its window, turned to the ego's heading: "
             "the object the program refers to in red, the objects it relates to in orange, the ego in blue.</p>")
    cards = []
    for r in results:
        features = search.scenarios.features(r.log_id)
        png = out_dir / "plots" / f"scenario_{r.rank}.png"
        drawn = features is not None and draw_moment(features, r, match.referred.get(r.clip_id, ()),
                                                     match.related.get(r.clip_id, ()), png)
        top = f"<img src='plots/{png.name}' alt='the moment from above'>" if drawn else ""
        preview = preview_html(r, out_dir, search.clips_dir, *match.preview_marks(r.clip_id, r.track_id))
        outside = "" if match.fallback or match.selects(r.clip_id) else \
            "<br><i>not selected by the program: the model's next best</i>"
        cards.append(f"<div class='card'>{top}{preview}<div class='meta'><b>#{r.rank}</b> "
                     f"{html.escape(r.category)}{outside}<br><span class='cap'>{html.escape(r.caption)}</span><br>"
                     f"<code>{html.escape(r.clip_id)}</code></div></div>")
    return head + f"<div class='cards'>{''.join(cards) or '(no results)'}</div>", results, match
