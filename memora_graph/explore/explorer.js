// memora explorer: renders one participant's memory from the JSON embedded in the page.
// Hand-written DOM + SVG, no library: the page must open from a file with nothing to fetch.
// State (filters, the selected segment and video) lives in the URL hash, so a view can be
// bookmarked or shared: #object=P01:plate&place=sink_area&video=P01_102&segment=P01_102%23t0012
"use strict";
(function () {
  const DATA = JSON.parse(document.getElementById("memora-data").textContent);
  const SVGNS = "http://www.w3.org/2000/svg";
  const OPS = { ADD: "#2e9e44", UPDATE: "#3b73c4", NOOP: "#9aa0a6", DELETE: "#d64541" };
  const PALETTE = ["#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#edc948", "#b07aa1", "#ff9da7",
    "#9c755f", "#bab0ac", "#86bcb6", "#d4a6c8", "#8cd17d", "#f1ce63", "#a0cbe8", "#ffbe7d"];
  const MAX_LANES = 60, MAX_CHIPS = 24, GRAPH_OBJECTS = 24, GRAPH_KNOWLEDGE = 16;

  // -- small DOM helpers ------------------------------------------------------------------
  function setAttrs(n, attrs) {
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "text") n.textContent = v;
      else if (k.startsWith("on")) n.addEventListener(k.slice(2), v);
      else n.setAttribute(k, v === true ? "" : String(v));
    }
  }
  function addKids(n, kids) {
    for (const k of kids.flat(3)) {
      if (k === null || k === undefined || k === false) continue;
      n.append(k instanceof Node ? k : document.createTextNode(String(k)));
    }
  }
  function el(tag, attrs, ...kids) { const n = document.createElement(tag); setAttrs(n, attrs); addKids(n, kids); return n; }
  function sv(tag, attrs, ...kids) { const n = document.createElementNS(SVGNS, tag); setAttrs(n, attrs); addKids(n, kids); return n; }
  function tip(text) { return sv("title", { text }); }
  function $(id) { return document.getElementById(id); }
  function group(rows, key) {
    const m = new Map();
    for (const r of rows) { const k = key(r); if (!m.has(k)) m.set(k, []); m.get(k).push(r); }
    return m;
  }
  function clock(t) {
    t = Math.max(0, Math.round(t));
    const h = Math.floor(t / 3600), m = Math.floor((t % 3600) / 60), s = t % 60;
    return (h ? h + ":" + String(m).padStart(2, "0") : String(m)) + ":" + String(s).padStart(2, "0");
  }
  function short(text, n) { text = String(text || ""); return text.length > n ? text.slice(0, n - 1) + "…" : text; }
  function niceStep(scale, minPx) {
    for (const s of [10, 30, 60, 120, 300, 600, 900, 1200, 1800, 3600, 7200]) if (s * scale >= minPx) return s;
    return 7200;
  }
  function widthOf(box, fallback) { return Math.max(320, box.clientWidth - 4 || fallback); }

  // -- indexes over the data ----------------------------------------------------------------
  const places = DATA.places;
  const placeById = new Map(places.map((p) => [p.id, p]));
  const colourOf = new Map(places.map((p, i) => [p.id, PALETTE[i % PALETTE.length]]));
  const placeColour = (id) => colourOf.get(id) || "#d0d7de";
  const placeName = (id) => (placeById.has(id) ? placeById.get(id).name : id || "unknown place");
  const entById = new Map(DATA.entities.map((e) => [e.id, e]));
  // a name, with the record's number where the editor opened several (potato, potato #2, ...)
  const entName = (id) => {
    const e = entById.get(id);
    if (!e) return id;
    const n = id.includes("#") ? id.slice(id.lastIndexOf("#")) : "";
    return (e.name || e.object_id) + (n ? " " + n : "");
  };
  const videoById = new Map(DATA.videos.map((v) => [v.id, v]));
  const segById = new Map(DATA.segments.map((s) => [s.id, s]));
  const segsByVideo = group(DATA.segments, (s) => s.video);
  const eventsByVideo = group(DATA.events, (e) => e.video);
  const editsByVideo = group(DATA.edits, (e) => e.video);
  const eventsBySeg = group(DATA.events, (e) => e.segment);
  const knowledge = DATA.routines.map((r) => Object.assign({ kind: "routine", title: r.goal, things: r.key_objects || [] }, r))
    .concat(DATA.preferences.map((p) => Object.assign({ kind: "preference", title: p.statement, things: p.objects || [] }, p)));
  knowledge.forEach((k, i) => { k.key = "k" + i; });
  const citedBy = new Map();
  for (const k of knowledge) for (const s of k.segments) { if (!citedBy.has(s)) citedBy.set(s, []); citedBy.get(s).push(k); }
  const mergedInto = group(DATA.entities.filter((e) => e.merged_into), (e) => e.merged_into);
  const videoEnd = (v) => Math.max(v.duration || 0, ...(segsByVideo.get(v.id) || []).map((s) => s.t1), 10);
  const segmentAt = (video, t) => (segsByVideo.get(video) || []).find((s) => t >= s.t0 && t < s.t1) || null;

  // the records an object filter stands for: the entity and the records merged into it
  function objectIds(id) { return new Set([id, ...(mergedInto.get(id) || []).map((e) => e.id)]); }
  function objectSegments(id) {
    const ids = objectIds(id), out = new Set();
    for (const e of DATA.events) if (ids.has(e.entity) && e.segment) out.add(e.segment);
    return out;
  }
  function knowledgeMatches(k) {
    if (state.object) {
      const ids = objectIds(state.object), e = entById.get(state.object);
      if (!k.entities.some((x) => ids.has(x)) && !(e && k.things.includes(e.object_id))) return false;
    }
    if (state.place && !k.segments.some((id) => segById.has(id) && segById.get(id).place === state.place)) return false;
    return true;
  }

  // -- state, kept in the URL hash ------------------------------------------------------------
  const state = { object: "", place: "", video: "", segment: "" };
  const expanded = new Set();
  function readHash() {
    const q = new URLSearchParams(location.hash.replace(/^#/, ""));
    for (const k of Object.keys(state)) state[k] = q.get(k) || "";
    if (!entById.has(state.object)) state.object = "";
    if (!placeById.has(state.place)) state.place = "";
    if (!segById.has(state.segment)) state.segment = "";
    if (!videoById.has(state.video)) state.video = "";
  }
  function update(changes) {
    Object.assign(state, changes);
    const q = new URLSearchParams();
    for (const [k, v] of Object.entries(state)) if (v) q.set(k, v);
    const hash = "#" + q.toString();
    if (location.hash !== hash) {
      try { history.replaceState(null, "", hash); } catch (e) { /* some viewers forbid it: the view still updates */ }
    }
    render();
  }
  function selectSegment(id) {
    const s = segById.get(id);
    if (s) update({ segment: id, video: s.video });
  }
  function laneVideo() {
    if (state.video) return state.video;
    if (state.segment) return segById.get(state.segment).video;
    const counts = new Map();
    const ids = state.object ? objectIds(state.object) : null;
    for (const e of DATA.events) {
      if ((!ids || ids.has(e.entity)) && (!state.place || e.location === state.place)) counts.set(e.video, (counts.get(e.video) || 0) + 1);
    }
    let best = DATA.videos.length ? DATA.videos[0].id : "", n = -1;
    for (const [v, c] of counts) if (c > n) { best = v; n = c; }
    return best;
  }

  // -- header: counts, filters, legend --------------------------------------------------------
  function renderHeader() {
    const active = DATA.entities.filter((e) => e.status === "active").length;
    $("title").replaceChildren(`memora explorer: ${DATA.participant}`,
      el("small", { text: `${DATA.bank} · ${DATA.generated_at}` }));
    const counts = [["videos", DATA.videos.length], ["segments", DATA.segments.length], ["entities", active],
      ["state_events", DATA.events.length], ["places", places.length], ["routines", DATA.routines.length],
      ["preferences", DATA.preferences.length], ["decisions", DATA.edits.length]];
    $("counts").replaceChildren(...counts.map(([k, v]) => el("div", { class: "count", "data-count": k, "data-value": v },
      el("dt", { text: k.replace("_", " ") }), el("dd", { text: v.toLocaleString("en") }))));
    const byName = (a, b) => entName(a.id).localeCompare(entName(b.id)) || a.id.localeCompare(b.id);
    const option = (e) => el("option", { value: e.id, text: `${entName(e.id)} · ${e.observations}`, title: e.id });
    const gone = DATA.entities.filter((e) => e.status !== "active").sort(byName);
    $("filter-object").replaceChildren(el("option", { value: "", text: `all objects (${active})` }),
      el("optgroup", { label: "in memory now" }, DATA.entities.filter((e) => e.status === "active").sort(byName).map(option)),
      gone.length ? el("optgroup", { label: "gone (deleted or merged)" }, gone.map(option)) : null);
    $("filter-place").replaceChildren(el("option", { value: "", text: `all places (${places.length})` }),
      ...places.map((p) => el("option", { value: p.id, text: `${p.name} · ${DATA.segments.filter((s) => s.place === p.id).length} segments` })));
    $("filter-object").addEventListener("change", (ev) => {
      const id = ev.target.value, changes = { object: id };
      if (id && state.video && !(eventsByVideo.get(state.video) || []).some((e) => objectIds(id).has(e.entity))) changes.video = "";
      update(changes);
    });
    $("filter-place").addEventListener("change", (ev) => update({ place: ev.target.value }));
    $("filter-clear").addEventListener("click", () => update({ object: "", place: "" }));
    $("lane-video").replaceChildren(...DATA.videos.map((v) => el("option", { value: v.id,
      text: `${v.id} · ${clock(v.duration)} · ${(eventsByVideo.get(v.id) || []).length} states` })));
    $("lane-video").addEventListener("change", (ev) => update({ video: ev.target.value }));
  }

  function renderFilters() {
    $("filter-object").value = state.object;
    $("filter-place").value = state.place;
    const parts = [];
    if (state.object) parts.push(`${objectSegments(state.object).size} segments with ${entName(state.object)}`);
    if (state.place) parts.push(`${DATA.segments.filter((s) => s.place === state.place).length} segments at ${placeName(state.place)}`);
    $("filter-note").textContent = parts.join(" · ");
    const turns = group(DATA.segments, (s) => s.place);
    $("legend").replaceChildren(
      ...places.map((p) => el("span", { class: "key" + (state.place === p.id ? " on" : state.place ? " dim" : ""),
        "data-place": p.id, title: `${p.name}: ${(turns.get(p.id) || []).length} segments as the main place; zones ${(p.zones || []).join(", ") || "-"}`,
        onclick: () => update({ place: state.place === p.id ? "" : p.id }) },
        el("span", { class: "swatch", style: `background:${placeColour(p.id)}` }), `${p.name} (${(turns.get(p.id) || []).length})`)),
      el("span", { class: "key opkey", text: " editor:" }),
      ...Object.entries(OPS).map(([op, c]) => el("span", { class: "key opkey" }, el("span", { class: "swatch", style: `background:${c}` }), op)));
  }

  // -- timeline ----------------------------------------------------------------------------------
  function axis(svg, x0, scale, end, y, h) {
    const g = sv("g", { class: "axis" });
    const step = niceStep(scale, 70);
    for (let t = 0; t <= end; t += step) {
      const x = x0 + t * scale;
      g.append(sv("line", { x1: x, x2: x, y1: y + 4, y2: y + h }), sv("text", { x: x + 2, y: y + 10, text: clock(t) }));
    }
    svg.append(g);
  }

  function renderTimeline() {
    const box = $("timeline");
    const W = widthOf(box, 1300), labelW = 70, axisH = 14, n = DATA.videos.length;
    const rowH = Math.max(7, Math.min(18, Math.floor(360 / Math.max(n, 1)) - 2));
    const maxEnd = Math.max(10, ...DATA.videos.map(videoEnd));
    const scale = (W - labelW - 6) / maxEnd;
    const svg = sv("svg", { width: W, height: axisH + n * (rowH + 2) + 2, class: "timeline" });
    axis(svg, labelW, scale, maxEnd, 0, axisH + n * (rowH + 2));
    const hitObj = state.object ? objectSegments(state.object) : null;
    const current = laneVideo();
    DATA.videos.forEach((v, i) => {
      const y = axisH + i * (rowH + 2);
      svg.append(sv("text", { x: 0, y: y + rowH - 2, class: "vlabel" + (v.id === current ? " current" : ""), "data-video": v.id,
        style: rowH < 10 ? "font-size:8px" : null, text: v.id }, tip(`${v.id}: ${clock(v.duration)}, ${(segsByVideo.get(v.id) || []).length} segments; click to show its objects`)));
      for (const s of segsByVideo.get(v.id) || []) {
        const hit = (!hitObj || hitObj.has(s.id)) && (!state.place || s.place === state.place);
        svg.append(sv("rect", { x: labelW + s.t0 * scale, y, width: Math.max(1, (s.t1 - s.t0) * scale - (scale > 0.4 ? 0.6 : 0)),
          height: rowH, fill: placeColour(s.place), "data-segment": s.id, "data-hit": hit ? "1" : "0",
          class: "seg" + (hit ? "" : " dim") + (s.id === state.segment ? " selected" : "") },
          tip(`${s.video} turn ${s.turn} (${clock(s.t0)}), ${placeName(s.place)}: ${s.summary}`)));
      }
    });
    const rowOf = new Map(DATA.videos.map((v, i) => [v.id, i]));
    for (const t of DATA.tasks || []) {  // tasks: a band at the foot of their video's row
      const i = rowOf.get(t.video);
      if (i === undefined) continue;
      const y = axisH + i * (rowH + 2) + rowH - 3;
      const stages = Object.entries(t.stages || {}).filter(([, xs]) => xs.length)
        .map(([k, xs]) => `${k}: ${xs.slice(0, 4).join(", ")}`).join("; ");
      svg.append(sv("rect", { x: labelW + t.t_start * scale, y, width: Math.max(2, (t.t_end - t.t_start) * scale - 1), height: 3,
        class: "task", "data-segment": (t.segments || [])[0] || null },
        tip(`task "${t.goal}" (${clock(t.t_start)}-${clock(t.t_end)}): ${stages}`)));
    }
    svg.addEventListener("click", (ev) => {
      const seg = ev.target.getAttribute("data-segment"), video = ev.target.getAttribute("data-video");
      if (seg) selectSegment(seg);
      else if (video) update({ video, segment: "" });
    });
    box.replaceChildren(svg);
  }

  // -- swimlanes: object state histories of one video ------------------------------------------
  function renderLanes() {
    const box = $("lanes"), vid = laneVideo();
    $("lane-video").value = vid;
    const v = videoById.get(vid);
    if (!v) { box.replaceChildren(el("p", { class: "hint", text: "No videos." })); return; }
    const events = eventsByVideo.get(vid) || [], byEnt = group(events, (e) => e.entity);
    const edits = group(editsByVideo.get(vid) || [], (e) => e.entity);
    let ids = [...byEnt.keys()];
    if (state.object) { const want = objectIds(state.object); ids = ids.filter((id) => want.has(id)); }
    if (state.place) ids = ids.filter((id) => byEnt.get(id).some((e) => e.location === state.place));
    const total = ids.length, shown = ids.slice(0, MAX_LANES);
    const end = videoEnd(v), W = widthOf(box, 780), labelW = 160, laneH = 18, axisH = 16;
    const scale = (W - labelW - 8) / end, x = (t) => labelW + t * scale;
    const svg = sv("svg", { width: W, height: axisH + Math.max(shown.length, 1) * laneH + 4, class: "lanes" });
    axis(svg, labelW, scale, end, 0, axisH + shown.length * laneH);
    const selected = state.segment ? segById.get(state.segment) : null;
    shown.forEach((id, i) => {
      const y = axisH + i * laneH, evs = byEnt.get(id), e = entById.get(id);
      svg.append(sv("rect", { class: "lane-bg", x: labelW, y: y + 2, width: W - labelW - 8, height: laneH - 4 }));
      svg.append(sv("text", { class: "lane-label" + (state.object && objectIds(state.object).has(id) ? " on" : "") +
        (e && e.status !== "active" ? " gone" : ""), x: labelW - 6,
        y: y + laneH - 5, "text-anchor": "end", "data-entity": id, text: short(entName(id), 22) },
        tip(`${id}${e && e.status !== "active" ? ` (${e.status}, into ${e.merged_into})` : ""}: ${evs.length} observations in ${vid}; click to filter`)));
      evs.forEach((ev, j) => {
        const t1 = j + 1 < evs.length ? evs[j + 1].t : (segById.has(ev.segment) ? segById.get(ev.segment).t1 : ev.t + 10);
        const w = Math.max(2, (t1 - ev.t) * scale - 1), off = state.place && ev.location !== state.place;
        svg.append(sv("rect", { class: "span" + (off ? " dim" : "") + (ev.segment === state.segment ? " selected" : ""),
          x: x(ev.t), y: y + 3, width: w, height: laneH - 6, rx: 2, fill: placeColour(ev.location), "data-segment": ev.segment },
          tip(`${entName(id)}: ${ev.state || "-"} at ${placeName(ev.location)}${ev.held_by ? ", held by " + ev.held_by : ""} from ${clock(ev.t)}` +
            `${ev.narration ? ` (“${ev.narration}”)` : ""}; editor: ${ev.op}`)));
        if (w > 34 && ev.state) svg.append(sv("text", { class: "span-text", x: x(ev.t) + 3, y: y + laneH - 6, text: short(ev.state, Math.floor(w / 6)) }));
      });
      for (const d of edits.get(id) || []) {
        const cx = x(d.t), cy = y + laneH / 2, seg = segmentAt(vid, d.t);
        svg.append(sv("path", { class: "mark", d: `M${cx} ${cy - 5}L${cx + 4} ${cy}L${cx} ${cy + 5}L${cx - 4} ${cy}Z`, fill: OPS[d.op] || "#555",
          "data-op": d.op, "data-segment": seg ? seg.id : null }, tip(`${d.op} at ${clock(d.t)}: ${d.reason}`)));
      }
    });
    if (selected && selected.video === vid) {
      svg.append(sv("line", { class: "now", x1: x(selected.t0), x2: x(selected.t0), y1: axisH, y2: axisH + shown.length * laneH }));
    }
    svg.addEventListener("click", (ev) => {
      const seg = ev.target.getAttribute("data-segment"), ent = ev.target.getAttribute("data-entity");
      if (seg) selectSegment(seg);
      else if (ent) update({ object: ent });
    });
    const note = total === 0 ? "No object matches the filters in this video; pick another video."
      : total > shown.length ? `${shown.length} of ${total} objects shown (filter by object or place to narrow).`
        : `${total} object${total === 1 ? "" : "s"} in ${vid} (${clock(end)}).`;
    box.replaceChildren(el("p", { id: "lanes-note", text: note }), svg);
  }

  // -- the selected segment --------------------------------------------------------------------
  function renderSegment() {
    const box = $("segment"), s = state.segment ? segById.get(state.segment) : null;
    if (!s) {
      const turns = group(DATA.segments, (x) => x.place);
      box.replaceChildren(el("p", { class: "hint", text: "Click a segment in the timeline, a state in a lane, or a supporting segment of a routine." }),
        el("table", { class: "obs" }, el("tr", {}, el("th", { text: "place" }), el("th", { text: "segments" }), el("th", { text: "zones" })),
          places.map((p) => el("tr", {}, el("td", {}, el("span", { class: "chip place", style: `background:${placeColour(p.id)}`,
            onclick: () => update({ place: p.id }), text: p.name })), el("td", { text: (turns.get(p.id) || []).length }),
            el("td", { text: (p.zones || []).join(", ") })))));
      return;
    }
    const list = segsByVideo.get(s.video), i = list.indexOf(s);
    const nav = (j) => (j >= 0 && j < list.length ? () => selectSegment(list[j].id) : null);
    const obs = eventsBySeg.get(s.id) || [], cites = citedBy.get(s.id) || [];
    box.replaceChildren(
      el("div", { class: "seg-head" }, `${s.video} · turn ${s.turn} · ${clock(s.t0)}–${clock(s.t1)} `,
        el("span", { class: "chip place", style: `background:${placeColour(s.place)}`, onclick: () => update({ place: s.place }), text: placeName(s.place) })),
      el("div", {}, el("button", { type: "button", onclick: nav(i - 1), disabled: i <= 0 }, "◀ previous"), " ",
        el("button", { type: "button", onclick: nav(i + 1), disabled: i >= list.length - 1 }, "next ▶")),
      el("p", { text: s.summary }),
      s.narrative ? el("p", { class: "narrative", text: s.narrative }) : null,
      el("h2", {}, `Objects observed (${obs.length})`),
      obs.length ? el("table", { class: "obs" }, obs.map((e) => el("tr", {},
        el("td", {}, el("span", { class: "chip", onclick: () => update({ object: e.entity }), text: entName(e.entity) })),
        el("td", { text: e.state }), el("td", { text: placeName(e.location) }),
        el("td", {}, el("span", { class: "op", style: `background:${OPS[e.op] || "#555"}`, text: e.op }))))) : el("p", { class: "hint", text: "none" }),
      el("h2", {}, `Supports (${cites.length})`),
      cites.length ? el("div", {}, cites.map((k) => el("div", {}, el("span", { class: "badge " + k.kind, text: k.kind }),
        el("a", { href: "#", onclick: (ev) => { ev.preventDefault(); flash(k.key); }, text: short(k.title, 90) })))) : el("p", { class: "hint", text: "no routine or preference cites this segment" }));
  }

  function flash(key, again) {
    const card = document.querySelector(`.card[data-key="${key}"]`);
    if (!card) { if (!again) { update({ object: "", place: "" }); flash(key, true); } return; }
    card.scrollIntoView({ block: "nearest" });
    card.classList.add("flash");
    setTimeout(() => card.classList.remove("flash"), 1500);
  }

  // -- routines and preferences -----------------------------------------------------------------
  function renderKnowledge() {
    const box = $("knowledge"), shown = knowledge.filter(knowledgeMatches);
    $("knowledge-note").textContent = knowledge.length ? `${shown.length} of ${knowledge.length}; click a supporting segment to open it`
      : "";
    if (!knowledge.length) { box.replaceChildren(el("p", { class: "hint", text: "No routines or preferences: this memory was not consolidated (MEMORA-Episodic)." })); return; }
    const objSegs = state.object ? objectSegments(state.object) : null;
    box.replaceChildren(...shown.map((k) => {
      const segs = expanded.has(k.key) ? k.segments : k.segments.slice(0, MAX_CHIPS);
      return el("div", { class: "card", "data-key": k.key, "data-kind": k.kind, "data-id": k.id },
        el("h3", {}, el("span", { class: "badge " + k.kind, text: k.kind === "routine" ? k.source.replace("_", " ") : k.subtype }), k.title),
        el("div", { class: "meta", text: `${k.count} times · confidence ${Number(k.confidence).toFixed(2)} · videos ${(k.videos || []).join(", ")}` +
          (k.evidence ? ` · ${k.evidence}` : "") }),
        k.kind === "routine" && k.steps && k.steps.length ? el("ol", {}, k.steps.slice(0, 10).map((st) => el("li", { text: st }))) : null,
        k.entities.length ? el("div", {}, "objects: ", k.entities.map((id) => el("span", { class: "chip" + (state.object && objectIds(state.object).has(id) ? " hit" : ""),
          onclick: () => update({ object: id }), text: entName(id) }))) : null,
        el("div", { class: "segs" }, `supporting segments (${k.segments.length}): `, segs.map((id) => {
          const s = segById.get(id), hit = s && ((objSegs && objSegs.has(id)) || (state.place && s.place === state.place));
          return el("span", { class: "chip" + (hit ? " hit" : "") + (id === state.segment ? " current" : ""), "data-segment": id, onclick: () => selectSegment(id),
            title: s ? `${placeName(s.place)}: ${s.summary}` : id, text: s ? `${s.video} ${clock(s.t0)}` : id });
        }), k.segments.length > segs.length ? el("button", { class: "more", type: "button", onclick: () => { expanded.add(k.key); render(); } },
          `+${k.segments.length - segs.length} more`) : null));
    }));
  }

  // -- graph: routines / preferences -> objects -> places ---------------------------------------
  function renderGraph() {
    const box = $("graph"), W = widthOf(box, 540);
    const atPlace = new Map();  // entity -> Map(place -> observations)
    for (const e of DATA.events) {
      if (!atPlace.has(e.entity)) atPlace.set(e.entity, new Map());
      const m = atPlace.get(e.entity); m.set(e.location, (m.get(e.location) || 0) + 1);
    }
    const active = DATA.entities.filter((e) => e.status === "active");
    let objs;
    if (state.object) {
      const related = new Set([state.object]);
      for (const k of knowledge) if (k.entities.includes(state.object)) k.entities.forEach((id) => related.add(id));
      objs = active.filter((e) => related.has(e.id));
    } else if (state.place) {
      objs = active.filter((e) => (atPlace.get(e.id) || new Map()).has(state.place))
        .sort((a, b) => atPlace.get(b.id).get(state.place) - atPlace.get(a.id).get(state.place));
    } else objs = active.slice();
    objs = objs.slice(0, GRAPH_OBJECTS);
    const objSet = new Set(objs.map((e) => e.id));
    const ks = knowledge.filter(knowledgeMatches).filter((k) => k.entities.some((id) => objSet.has(id)))
      .sort((a, b) => b.count - a.count).slice(0, GRAPH_KNOWLEDGE);
    const rowH = 20, top = 24, n = Math.max(places.length, objs.length, ks.length, 1);
    const H = top + n * rowH + 8;
    const xs = [Math.round(W * 0.40), Math.round(W * 0.58), Math.round(W * 0.83)];
    const spread = (count, i) => top + (i + 0.5) * (n * rowH) / count;  // each column over the full height
    const placeY = new Map(places.map((p, i) => [p.id, spread(places.length, i)]));
    const placeEdges = (id) => [...(atPlace.get(id) || new Map()).entries()].filter(([p]) => placeY.has(p))
      .sort((a, b) => b[1] - a[1]).slice(0, 3);
    const bary = (pairs) => { let s = 0, w = 0; for (const [y, k] of pairs) { s += y * k; w += k; } return w ? s / w : 0; };
    objs.sort((a, b) => bary(placeEdges(a.id).map(([p, c]) => [placeY.get(p), c])) - bary(placeEdges(b.id).map(([p, c]) => [placeY.get(p), c])));
    const objY = new Map(objs.map((e, i) => [e.id, spread(objs.length, i)]));
    ks.sort((a, b) => bary(a.entities.filter((id) => objY.has(id)).map((id) => [objY.get(id), 1])) -
      bary(b.entities.filter((id) => objY.has(id)).map((id) => [objY.get(id), 1])));
    const kY = new Map(ks.map((k, i) => [k.key, spread(ks.length, i)]));
    const svg = sv("svg", { width: W, height: H, class: "graph" });
    [["routines · preferences", xs[0], "end"], ["objects", xs[1], "middle"], ["places", xs[2], "start"]].forEach(([t, x, a]) =>
      svg.append(sv("text", { x, y: 12, "text-anchor": a, class: "axis", style: "fill:#656d76", text: t })));
    const curve = (x1, y1, x2, y2) => `M${x1} ${y1}C${(x1 + x2) / 2} ${y1},${(x1 + x2) / 2} ${y2},${x2} ${y2}`;
    const edges = sv("g", {});
    for (const e of objs) {
      for (const [p, c] of placeEdges(e.id)) {
        edges.append(sv("path", { class: "gedge", d: curve(xs[1], objY.get(e.id), xs[2], placeY.get(p)), stroke: placeColour(p),
          "stroke-opacity": state.place && p !== state.place ? 0.15 : 0.7, "stroke-width": Math.min(6, 0.6 + Math.sqrt(c) / 2) }, tip(`${e.name} at ${placeName(p)}: ${c} observations`)));
      }
    }
    for (const k of ks) {
      for (const id of k.entities.filter((x) => objY.has(x))) {
        edges.append(sv("path", { class: "gedge", d: curve(xs[0], kY.get(k.key), xs[1], objY.get(id)),
          stroke: k.kind === "routine" ? "#6e40c9" : "#bf3989", "stroke-opacity": 0.45, "stroke-width": 1.2 }));
      }
    }
    svg.append(edges);
    for (const k of ks) {
      svg.append(sv("g", { class: "gnode", "data-kind": k.kind, onclick: () => flash(k.key) },
        sv("rect", { x: xs[0] - 5, y: kY.get(k.key) - 5, width: 10, height: 10, rx: 2, fill: k.kind === "routine" ? "#6e40c9" : "#bf3989" }),
        sv("text", { x: xs[0] - 10, y: kY.get(k.key) + 4, "text-anchor": "end", text: short(k.title, Math.floor(xs[0] / 6.2)) }), tip(k.title)));
    }
    for (const e of objs) {
      svg.append(sv("g", { class: "gnode" + (state.object === e.id ? " on" : ""), "data-kind": "object", "data-entity": e.id,
        onclick: () => update({ object: state.object === e.id ? "" : e.id }) },
        sv("circle", { cx: xs[1], cy: objY.get(e.id), r: 3 + Math.min(5, Math.sqrt(e.observations) / 3), fill: "#444" }),
        sv("text", { x: xs[1] + 9, y: objY.get(e.id) + 4, text: short(e.name, 18) }), tip(`${e.name}: ${e.state} at ${placeName(e.location)}; ${e.observations} observations`)));
    }
    for (const p of places) {
      svg.append(sv("g", { class: "gnode" + (state.place === p.id ? " on" : ""), "data-kind": "place", "data-place": p.id,
        onclick: () => update({ place: state.place === p.id ? "" : p.id }) },
        sv("circle", { cx: xs[2], cy: placeY.get(p.id), r: 7, fill: placeColour(p.id) }),
        sv("text", { x: xs[2] + 11, y: placeY.get(p.id) + 4, text: short(p.name, 22) }), tip(`${p.name}: ${p.turns} turns`)));
    }
    box.replaceChildren(svg, el("p", { class: "hint", text: `${objs.length} objects (${state.object ? "the object and those its routines use" :
      state.place ? "most observed at " + placeName(state.place) : "most observed"}), their 3 main places, and ${ks.length} routines / preferences about them.` }));
  }

  function render() {
    renderFilters();
    renderTimeline();
    renderLanes();
    renderSegment();
    renderKnowledge();
    renderGraph();
    document.documentElement.setAttribute("data-rendered", String(Number(document.documentElement.getAttribute("data-rendered") || 0) + 1));
  }

  const t0 = performance.now();
  readHash();
  renderHeader();
  render();
  document.documentElement.setAttribute("data-render-ms", String(Math.round(performance.now() - t0)));
  window.addEventListener("hashchange", () => { readHash(); render(); });
  let resizeTimer = null;
  window.addEventListener("resize", () => { clearTimeout(resizeTimer); resizeTimer = setTimeout(render, 150); });
})();
