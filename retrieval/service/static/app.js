// The scenesearch page: one search form, a grid of results, "more like this", and a detail panel.
"use strict";

const $ = (id) => document.getElementById(id);
const FILTER_FIELDS = ["category", "tags", "log_id", "time_of_day"];
const TIMELINE_COLOURS = ["#3d5a80", "#98c1d9", "#ee6c4d", "#6a994e", "#bc4749", "#f2cc8f", "#81b29a"];

function escapeHtml(text) {
  const div = document.createElement("div");
  div.textContent = String(text);
  return div.innerHTML;
}

function clipUrl(clipId, suffix = "") {
  return "/api/clips/" + encodeURIComponent(clipId) + suffix;
}

function filterParams() {
  const params = [];
  for (const field of FILTER_FIELDS) {
    const value = $("f-" + field).value;
    if (!value) continue;
    // Tags are lists: match clips whose unified sequence holds the tag.
    params.push(field === "tags" ? `tags contains '${value}'` : `${field}=${value}`);
  }
  return params;
}

async function getJson(url) {
  const response = await fetch(url);
  const body = await response.json().catch(() => ({ detail: response.statusText }));
  if (!response.ok) {
    const detail = typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail);
    throw new Error(`${response.status}: ${detail}`);
  }
  return body;
}

function setStatus(text, isError = false) {
  $("status").textContent = text;
  $("status").className = isError ? "error" : "";
}

function renderResults(results) {
  const grid = $("results");
  grid.innerHTML = "";
  for (const r of results) {
    const card = document.createElement("article");
    card.className = "card";
    card.dataset.clipId = r.clip_id;
    const preview = r.preview_url
      ? `<img class="preview" src="${r.preview_url}" alt="camera and BEV preview of ${escapeHtml(r.clip_id)}" loading="lazy">`
      : `<div class="nopreview">no preview</div>`;
    const chips = (r.tags || []).map((t) => `<span class="chip">${escapeHtml(t)}</span>`).join("");
    card.innerHTML = `${preview}
      <div class="body">
        <div class="caption"><span class="score">${r.score.toFixed(3)}</span>${escapeHtml(r.caption)}</div>
        <div class="chips">${chips}</div>
        <div class="meta">${escapeHtml(r.category)} · ${escapeHtml(r.log_id)} · track ${escapeHtml(r.track_id)} · ${r.duration_s.toFixed(1)} s</div>
        <div class="actions">
          <button class="more-like-this">More like this</button>
          <button class="secondary details">Details</button>
        </div>
      </div>`;
    card.querySelector(".more-like-this").addEventListener("click", () => similar(r.clip_id, r.caption));
    card.querySelector(".details").addEventListener("click", () => showDetail(r.clip_id));
    grid.appendChild(card);
  }
}

async function search(event) {
  if (event) event.preventDefault();
  const q = $("query").value.trim();
  if (!q) { setStatus("Type a sentence to search.", true); return; }
  const params = new URLSearchParams({ q, k: $("k").value, view: $("view").value, mode: $("mode").value });
  for (const f of filterParams()) params.append("filter", f);
  history.replaceState(null, "", "?" + new URLSearchParams({ q }).toString());
  setStatus("Searching…");
  try {
    const body = await getJson("/api/search?" + params.toString());
    renderResults(body.results);
    setStatus(`${body.results.length} results for “${q}” in ${body.elapsed_ms.toFixed(1)} ms`);
  } catch (err) {
    $("results").innerHTML = "";
    setStatus(err.message, true);
  }
}

async function similar(clipId, caption) {
  const params = new URLSearchParams({ k: $("k").value, view: $("view").value,
                                       other_moments: $("other-moments").value });
  for (const f of filterParams()) params.append("filter", f);
  setStatus("Finding similar moments…");
  try {
    const body = await getJson("/api/similar/" + encodeURIComponent(clipId) + "?" + params.toString());
    renderResults(body.results);
    setStatus(`${body.results.length} moments like “${caption}” (${clipId})`);
    window.scrollTo(0, 0);
  } catch (err) {
    setStatus(err.message, true);
  }
}

async function showDetail(clipId) {
  try {
    const clip = await getJson(clipUrl(clipId));
    const bar = clip.timeline.map((step, i) =>
      `<div style="background:${TIMELINE_COLOURS[i % TIMELINE_COLOURS.length]}" title="${step.start_s}–${step.end_s} s">${escapeHtml(step.tag)}</div>`).join("");
    const rows = Object.entries({ clip_id: clip.clip_id, log_id: clip.log_id, track_id: clip.track_id,
      category: clip.category, start_ns: clip.start_ns, end_ns: clip.end_ns, ...clip.metadata })
      .filter(([, v]) => v !== null && typeof v !== "object")
      .map(([k, v]) => `<tr><td>${escapeHtml(k)}</td><td>${escapeHtml(v)}</td></tr>`).join("");
    $("detail-body").innerHTML = `
      <h2>${escapeHtml(clip.caption)}</h2>
      ${clip.preview_url ? `<img class="preview" style="width:100%" src="${clip.preview_url}" alt="preview">` : ""}
      <h3>Timeline of tags</h3>
      <div class="timeline" id="timeline">${bar}</div>
      <div class="meta">${clip.duration_s.toFixed(1)} s, ${clip.timeline.length} steps in order</div>
      <h3>Clip</h3><table class="kv">${rows}</table>
      <button class="more-like-this" id="detail-similar">More like this</button>`;
    $("detail-similar").addEventListener("click", () => { $("detail").hidden = true; similar(clip.clip_id, clip.caption); });
    $("detail").hidden = false;
  } catch (err) {
    setStatus(err.message, true);
  }
}

async function loadFields() {
  try {
    const fields = await getJson("/api/fields");
    for (const field of FILTER_FIELDS) {
      const values = field === "tags" ? fields.tags : (fields.menus[field] || []);
      const select = $("f-" + field);
      for (const value of values) {
        const option = document.createElement("option");
        option.value = value;
        option.textContent = value;
        select.appendChild(option);
      }
    }
  } catch (err) {
    setStatus("Could not load filters: " + err.message, true);
  }
}

$("search-form").addEventListener("submit", search);
$("detail-close").addEventListener("click", () => { $("detail").hidden = true; });
loadFields().then(() => {
  const q = new URLSearchParams(location.search).get("q");
  if (q) { $("query").value = q; search(); }
});
