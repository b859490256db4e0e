// The scenesearch page: a search form with filters, result cards that say what matched and why, "more like
// this" with the query clip pinned, pages, the embedding map and a detail panel. The whole state lives in
// the address (q or like, mode, view, k, page, f, s, other, same, map, clip), so a link reopens the same view.
"use strict";

const $ = (id) => document.getElementById(id);
const TIMELINE_COLOURS = ["#3d5a80", "#98c1d9", "#ee6c4d", "#6a994e", "#bc4749", "#f2cc8f", "#81b29a"];
const ACTION_COLOURS = ["#e6194b", "#3cb44b", "#ffe119", "#4363d8", "#f58231", "#911eb4", "#46f0f0", "#f032e6",
                        "#bcf60c", "#fabebe"];
const MODE_NAMES = { model: "trained model", captions: "rule captions", hybrid: "model + rule captions" };
let FIELDS = null;
let MAP = null;

function escapeHtml(text) {
  const div = document.createElement("div");
  div.textContent = String(text);
  return div.innerHTML;
}

function clipUrl(clipId, suffix = "") {
  return "/api/clips/" + encodeURIComponent(clipId) + suffix;
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

// ------------------------------------------------------------------ state in the address

function readState() {
  const p = new URLSearchParams(location.search);
  return {
    q: p.get("q") || "", like: p.get("like") || "", mode: p.get("mode") || "model", view: p.get("view") || "fused",
    k: Number(p.get("k") || 12), page: Math.max(Number(p.get("page") || 1), 1), f: p.getAll("f"), s: p.getAll("s"),
    other: p.get("other") !== "0", same: p.get("same") === "1", map: p.get("map") === "1", clip: p.get("clip") || "",
  };
}

function writeState(state, push = true) {
  const p = new URLSearchParams();
  if (state.like) p.set("like", state.like); else if (state.q) p.set("q", state.q);
  if (state.mode !== "model") p.set("mode", state.mode);
  if (state.view !== "fused") p.set("view", state.view);
  if (state.k !== 12) p.set("k", String(state.k));
  if (state.page > 1) p.set("page", String(state.page));
  for (const f of state.f) p.append("f", f);
  for (const s of state.s) p.append("s", s);
  if (!state.other) p.set("other", "0");
  if (state.same) p.set("same", "1");
  if (state.map) p.set("map", "1");
  if (state.clip) p.set("clip", state.clip);
  const url = "?" + p.toString();
  if (url !== location.search) (push ? history.pushState : history.replaceState).call(history, null, "", url);
}

function formState(page = 1) {
  const state = readState();
  const text = $("query").value.trim();
  const like = text.startsWith("like:") ? text.slice(5).trim() : "";
  const f = [];
  for (const select of document.querySelectorAll("#menus select")) if (select.value) f.push(`${select.dataset.field}=${select.value}`);
  const s = [...document.querySelectorAll("#switches input:checked")].map((box) => box.dataset.field);
  return { ...state, q: like ? "" : text, like, mode: $("mode").value, view: $("view").value, k: Number($("k").value),
           page, f, s, other: $("other-moments").checked, same: $("same-track").checked, map: false };
}

function showState(state) {
  $("query").value = state.like ? "like: " + state.like : state.q;
  $("mode").value = state.mode;
  $("view").value = state.view;
  $("k").value = String(state.k);
  $("other-moments").checked = state.other;
  $("same-track").checked = state.same;
  const chosen = Object.fromEntries(state.f.map((f) => [f.split("=")[0], f.slice(f.indexOf("=") + 1)]));
  for (const select of document.querySelectorAll("#menus select")) select.value = chosen[select.dataset.field] || "";
  for (const box of document.querySelectorAll("#switches input")) box.checked = state.s.includes(box.dataset.field);
}

function filterParams(state) {
  const params = [];
  for (const f of state.f) {
    const [field, value] = [f.split("=")[0], f.slice(f.indexOf("=") + 1)];
    params.push(field === "tags" ? `tags contains '${value}'` : `${field}=${value}`);
  }
  for (const s of state.s) params.push(`${s}=true`);
  return params;
}

// ------------------------------------------------------------------ filters and landing page

function buildFilters() {
  const menus = $("menus");
  menus.innerHTML = "";
  for (const [field, menu] of Object.entries(FIELDS.menus)) {
    if (menu.values.length < 2 && field !== "split") continue;
    const label = document.createElement("label");
    label.textContent = menu.name + " ";
    const select = document.createElement("select");
    select.id = "f-" + field;
    select.dataset.field = field;
    select.innerHTML = `<option value="">any</option>` + menu.values.map((v) =>
      `<option value="${escapeHtml(v.value)}">${escapeHtml(v.label)} (${v.count})</option>`).join("");
    select.addEventListener("change", () => run(formState()));
    label.appendChild(select);
    menus.appendChild(label);
  }
  const switches = $("switches");
  switches.innerHTML = FIELDS.switches.filter((s) => s.count > 0).map((s) =>
    `<label class="switch ${s.kind}"><input type="checkbox" data-field="${escapeHtml(s.field)}" id="s-${escapeHtml(s.field)}">` +
    `${escapeHtml(s.label)} <span class="count">${s.count}</span></label>`).join("");
  for (const box of switches.querySelectorAll("input")) box.addEventListener("change", () => run(formState()));
}

function showLanding() {
  const s = FIELDS.summary;
  const cats = Object.entries(s.categories).sort((a, b) => b[1] - a[1])
    .map(([c, n]) => `<span class="chip">${escapeHtml(c)} ${n}</span>`).join(" ");
  const splits = Object.entries(s.splits).map(([c, n]) => `${escapeHtml(c)} ${n}`).join(" · ");
  $("summary").innerHTML = `<b>${s.clips.toLocaleString()}</b> moments from <b>${s.logs}</b> logs, ` +
    `<b>${Object.keys(s.categories).length}</b> categories: ${cats}` + (splits ? `<div class="meta">splits: ${splits}</div>` : "");
  $("examples").innerHTML = FIELDS.examples.map((q) =>
    `<button type="button" class="example secondary">${escapeHtml(q)}</button>`).join("");
  for (const button of $("examples").querySelectorAll("button")) {
    button.addEventListener("click", () => { $("query").value = button.textContent; run(formState()); });
  }
  $("landing").hidden = false;
}

// ------------------------------------------------------------------ results

function scoreLabel(score, mode) {
  return mode === "hybrid" ? `${score.toFixed(2)} σ` : score.toFixed(3);
}

function card(r, mode, pinned = false) {
  const el = document.createElement("article");
  el.className = "card" + (pinned ? " pinned-card" : "");
  el.dataset.clipId = r.clip_id;
  const preview = r.preview_url
    ? `<img class="preview" src="${escapeHtml(r.preview_url)}" alt="camera and BEV preview of ${escapeHtml(r.clip_id)}" loading="lazy">`
    : `<div class="nopreview">no preview</div>`;
  const matched = new Set(r.matched_tags || []);
  const chips = (r.tags || []).map((t, i) =>
    `<span class="chip${matched.has(t) ? " match" : ""}" title="${escapeHtml(t)}">${escapeHtml((r.tag_labels || [])[i] || t)}</span>`).join("");
  const rest = r.caption.replace(r.object_sentence, "").trim();
  const when = r.time_in_log ? r.time_in_log.text : `${r.duration_s.toFixed(1)} s`;
  const marks = (r.referred_tracks || []).filter((t) => t !== r.track_id && t !== "ego").length +
    (r.related_tracks || []).filter((t) => t !== "ego").length;
  const track = r.track_id.length > 12 ? r.track_id.slice(0, 8) + "…" : r.track_id;
  const score = pinned ? `<span class="score pin">query clip</span>`
    : `<span class="score" title="${escapeHtml(mode)} score">${scoreLabel(r.score, mode)}</span>`;
  el.innerHTML = `${preview}
    <div class="body">
      <div class="caption">${score}<span class="rank">${pinned ? "" : "#" + r.rank}</span>
        <span class="object">${escapeHtml(r.object_sentence || r.caption)}</span>
        ${rest ? `<span class="host">${escapeHtml(rest)}</span>` : ""}</div>
      <div class="chips">${chips}</div>
      <div class="meta">${escapeHtml(r.category)} · ${escapeHtml(logName(r.log_id))} · <span title="${escapeHtml(r.track_id)}">track ${escapeHtml(track)}</span> ·
        <span class="when">${escapeHtml(when)}</span>${marks ? ` · <span class="marks">${marks} related object(s) marked</span>` : ""}</div>
      <div class="actions">
        <button class="more-like-this">More like this</button>
        <button class="secondary details">Details</button>
      </div>
    </div>`;
  el.querySelector(".more-like-this").addEventListener("click", () => {
    run({ ...formState(), q: "", like: r.clip_id });
    window.scrollTo(0, 0);
  });
  el.querySelector(".details").addEventListener("click", () => showDetail(r.clip_id));
  const img = el.querySelector("img.preview");
  if (img) {  // a preview that cannot be drawn (its frames gone since indexing) says so instead of a broken image
    img.addEventListener("error", () => {
      const none = document.createElement("div");
      none.className = "nopreview";
      none.textContent = "no preview";
      img.replaceWith(none);
    });
  }
  return el;
}

function logName(logId) {
  const menu = FIELDS && FIELDS.menus.log_id;
  const entry = menu && menu.values.find((v) => v.value === logId);
  return entry ? entry.label : logId;
}

function renderResults(results, mode) {
  const grid = $("results");
  grid.innerHTML = "";
  let divided = false;
  for (const r of results) {
    if (r.program_selects === false && !divided) {  // a short answer goes on with the search's next best
      const note = document.createElement("div");
      note.className = "outside-program";
      note.textContent = "The program selects no more moments here. The closest others follow; it does not select them.";
      grid.appendChild(note);
      divided = true;
    }
    grid.appendChild(card(r, mode));
  }
  $("legend").hidden = results.length === 0;
}

function renderPager(state, body) {
  const start = body.offset + 1;
  const end = body.offset + body.results.length;
  $("pager").hidden = !(state.page > 1 || body.next_offset !== null);
  $("prev-page").disabled = state.page <= 1;
  $("next-page").disabled = body.next_offset === null;
  $("page-info").textContent = body.results.length ? `${start}–${end}` + (body.total !== undefined ? ` of ${body.total}` : "") : "";
}

function renderExplain(body) {
  const parts = [];
  const sc = body.scenario;
  if (sc) {
    if (sc.program && !sc.fallback) {
      parts.push(`<div class="reads">Read as: <b>${escapeHtml(sc.reads)}</b> <span class="meta">— ${sc.matched_moments} moments qualify</span>
        <details><summary>program</summary><code>${escapeHtml(sc.program)}</code></details></div>`);
    }
    if (sc.fallback) {
      parts.push(`<div class="fallback">No scenario program decided: ${escapeHtml(sc.fallback)}. Every moment is ranked by the ${escapeHtml(MODE_NAMES[body.mode])}` +
        (sc.program ? ` (the query read as <b>${escapeHtml(sc.reads)}</b>)` : "") + ".</div>");
    }
    if (sc.suggestion) {
      const s = sc.suggestion;
      parts.push(`<div class="unused">Not understood: ${s.unused_words.map((w) => `<b>${escapeHtml(w)}</b>`).join(", ")} — the search used the rest.` +
        (s.phrasing ? ` A phrasing the index knows: <button type="button" class="link suggestion">${escapeHtml(s.phrasing)}</button>` : "") + "</div>");
    }
    for (const note of sc.notes || []) parts.push(`<div class="meta">${escapeHtml(note)}</div>`);
  }
  if (body.confidence && body.confidence.weak && body.results.length) {
    parts.push(`<div class="weak">⚠ Weak match: the best score (${scoreLabel(body.confidence.best, body.mode)}) is below ` +
      `${scoreLabel(body.confidence.threshold, body.mode)}, under which the index usually holds no such moment. ` +
      `<span class="meta">${escapeHtml(body.confidence.basis)}</span></div>`);
  }
  if (body.score_scale) parts.push(`<div class="meta scale">Scores (${escapeHtml(MODE_NAMES[body.mode] || body.mode)}): ${escapeHtml(body.score_scale)}.</div>`);
  $("explain").innerHTML = parts.join("");
  $("explain").hidden = parts.length === 0;
  const suggestion = $("explain").querySelector(".suggestion");
  if (suggestion) suggestion.addEventListener("click", () => { $("query").value = suggestion.textContent; run(formState()); });
}

async function run(state, push = true) {
  writeState(state, push);
  showState(state);
  $("map").hidden = true;
  if (state.map) return openMap();
  $("landing").hidden = Boolean(state.q || state.like);
  $("pinned").hidden = true;
  $("explain").hidden = true;
  if (!state.q && !state.like) {
    $("results").innerHTML = "";
    $("legend").hidden = true;
    $("pager").hidden = true;
    setStatus("");
    if (FIELDS) showLanding();
    return;
  }
  const params = new URLSearchParams({ k: String(state.k), offset: String((state.page - 1) * state.k), view: state.view });
  for (const f of filterParams(state)) params.append("filter", f);
  setStatus(state.like ? "Finding similar moments…" : "Searching…");
  try {
    if (state.like) {
      params.set("other_moments", String(state.other));
      params.set("same_track", String(state.same));
      const body = await getJson("/api/similar/" + encodeURIComponent(state.like) + "?" + params.toString());
      $("pinned").innerHTML = `<h2>Moments like this one</h2>`;
      $("pinned").appendChild(card(body.query, "similar", true));
      $("pinned").hidden = false;
      renderResults(body.results, "similar");
      renderPager(state, body);
      $("explain").innerHTML = `<div class="meta scale">Scores: ${escapeHtml(body.score_scale)}. ` +
        (body.same_track ? "The query's own object is kept." : "The query's own object (any time window) is left out.") +
        (body.other_moments ? " Other objects in view at the same time are left out." : "") + "</div>";
      $("explain").hidden = false;
      setStatus(`${body.results.length} moments like “${body.query.object_sentence}”`);
    } else {
      params.set("q", state.q);
      params.set("mode", state.mode);
      const body = await getJson("/api/search?" + params.toString());
      renderExplain(body);
      renderResults(body.results, body.mode);
      renderPager(state, body);
      setStatus(body.results.length
        ? `${body.total} results for “${state.q}” (${MODE_NAMES[body.mode]}), in ${body.elapsed_ms.toFixed(1)} ms`
        : `No results for “${state.q}”`);
    }
    if (state.clip) showDetail(state.clip, false);
  } catch (err) {
    $("results").innerHTML = "";
    $("pager").hidden = true;
    setStatus(err.message, true);
  }
}

// ------------------------------------------------------------------ detail panel

async function showDetail(clipId, remember = true) {
  try {
    const clip = await getJson(clipUrl(clipId));
    if (remember) writeState({ ...readState(), clip: clipId }, false);
    const bar = clip.timeline.map((step, i) =>
      `<div style="background:${TIMELINE_COLOURS[i % TIMELINE_COLOURS.length]}" title="${escapeHtml(step.tag)}: ${step.start_s}–${step.end_s} s">${escapeHtml(step.label)}</div>`).join("");
    const rows = Object.entries({ clip_id: clip.clip_id, log: logName(clip.log_id), track_id: clip.track_id,
      category: clip.category, "time in log": clip.time_in_log ? clip.time_in_log.text : "", ...clip.metadata })
      .filter(([, v]) => v !== null && v !== "" && typeof v !== "object")
      .map(([k, v]) => `<tr><td>${escapeHtml(k)}</td><td>${escapeHtml(v)}</td></tr>`).join("");
    $("detail-body").innerHTML = `
      <h2>${escapeHtml(clip.object_sentence)}</h2>
      <p class="meta">${escapeHtml(clip.caption)}</p>
      ${clip.preview_url ? `<img class="preview" style="width:100%" src="${escapeHtml(clip.preview_url)}" alt="preview">` : ""}
      <h3>Timeline of tags</h3>
      <div class="timeline" id="timeline">${bar}</div>
      <div class="meta">${clip.duration_s.toFixed(1)} s${clip.time_in_log ? " (" + escapeHtml(clip.time_in_log.text) + ")" : ""}, ${clip.timeline.length} steps in order</div>
      <h3>Clip</h3><table class="kv">${rows}</table>
      <button class="more-like-this" id="detail-similar">More like this</button>`;
    $("detail-similar").addEventListener("click", () => {
      $("detail").hidden = true;
      run({ ...formState(), q: "", like: clip.clip_id, clip: "" });
    });
    $("detail").hidden = false;
  } catch (err) {
    setStatus(err.message, true);
  }
}

// ------------------------------------------------------------------ embedding map

async function openMap() {
  $("landing").hidden = true;
  $("results").innerHTML = "";
  $("pinned").hidden = true;
  $("pager").hidden = true;
  $("explain").hidden = true;
  $("legend").hidden = true;
  $("map").hidden = false;
  setStatus("Loading the embedding map…");
  try {
    const view = $("view").value;
    if (!MAP || MAP.view !== view) MAP = await getJson("/api/map?view=" + encodeURIComponent(view));
    drawMap();
    setStatus("");
    $("map-info").textContent = `${MAP.points.length} moments, ${MAP.view} embeddings projected on their first two ` +
      "principal components. Click a point to open its moment.";
    $("map-legend").innerHTML = MAP.actions.map((a, i) =>
      `<span><i style="background:${actionColour(i)}"></i>${escapeHtml(a)} (${MAP.action_counts[i]})</span>`).join("");
  } catch (err) {
    setStatus(err.message, true);
  }
}

function actionColour(i) {
  return i === MAP.actions.length - 1 && MAP.actions[i] === "other" ? "#777777" : ACTION_COLOURS[i % ACTION_COLOURS.length];
}

function mapXY(point, canvas) {
  const pad = 16;
  return [pad + point[0] * (canvas.width - 2 * pad), pad + (1 - point[1]) * (canvas.height - 2 * pad)];
}

function drawMap() {
  const canvas = $("map-canvas");
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = "#0c1116";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  MAP.points.forEach((p) => {
    const [x, y] = mapXY(p, canvas);
    ctx.fillStyle = actionColour(p[2]);
    ctx.beginPath();
    ctx.arc(x, y, 3, 0, 2 * Math.PI);
    ctx.fill();
  });
}

function nearestPoint(event) {
  const canvas = $("map-canvas");
  const box = canvas.getBoundingClientRect();
  const mx = (event.clientX - box.left) * canvas.width / box.width;
  const my = (event.clientY - box.top) * canvas.height / box.height;
  let best = -1;
  let bestD = 64;
  MAP.points.forEach((p, i) => {
    const [x, y] = mapXY(p, canvas);
    const d = (x - mx) ** 2 + (y - my) ** 2;
    if (d < bestD) { bestD = d; best = i; }
  });
  return best;
}

$("map-canvas").addEventListener("mousemove", (event) => {
  if (!MAP) return;
  const i = nearestPoint(event);
  const tip = $("map-tip");
  if (i < 0) { tip.hidden = true; return; }
  const p = MAP.points[i];
  tip.textContent = `${MAP.actions[p[2]]} · ${MAP.categories[p[3]]} · ${MAP.clip_ids[i]}`;
  tip.style.left = `${event.pageX + 12}px`;
  tip.style.top = `${event.pageY + 12}px`;
  tip.hidden = false;
});
$("map-canvas").addEventListener("click", (event) => {
  if (!MAP) return;
  const i = nearestPoint(event);
  if (i >= 0) showDetail(MAP.clip_ids[i]);
});

// ------------------------------------------------------------------ wiring

$("search-form").addEventListener("submit", (event) => {
  event.preventDefault();
  const state = formState();
  if (!state.q && !state.like) { setStatus("Type a sentence to search.", true); return; }
  run(state);
});
$("mode").addEventListener("change", () => { if (readState().q) run(formState()); });
$("view").addEventListener("change", () => { if (readState().map) { run({ ...readState(), view: $("view").value }); } else if (readState().q || readState().like) run(formState()); });
$("k").addEventListener("change", () => { if (readState().q || readState().like) run(formState()); });
$("other-moments").addEventListener("change", () => { if (readState().like) run(formState()); });
$("same-track").addEventListener("change", () => { if (readState().like) run(formState()); });
$("clear-filters").addEventListener("click", () => {
  for (const select of document.querySelectorAll("#menus select")) select.value = "";
  for (const box of document.querySelectorAll("#switches input")) box.checked = false;
  run(formState());
});
$("prev-page").addEventListener("click", () => { run({ ...readState(), page: readState().page - 1, clip: "" }); window.scrollTo(0, 0); });
$("next-page").addEventListener("click", () => { run({ ...readState(), page: readState().page + 1, clip: "" }); window.scrollTo(0, 0); });
$("map-button").addEventListener("click", () => run({ ...readState(), map: true, clip: "" }));
$("detail-close").addEventListener("click", () => {
  $("detail").hidden = true;
  writeState({ ...readState(), clip: "" }, false);
});
window.addEventListener("popstate", () => run(readState(), false));

getJson("/api/fields").then((fields) => {
  FIELDS = fields;
  buildFilters();
}).catch((err) => setStatus("Could not load filters: " + err.message, true)).finally(() => run(readState(), false));
