// The labelling page: the queue, an episode's animated path over the arena (or, for your own
// task, its state dimensions over time), the label form and the labels given; with comparisons,
// two episodes side by side and the answers given. Every value from the server is written with textContent or as an SVG
// attribute, never parsed as HTML.
"use strict";
const token = new URLSearchParams(location.search).get("token") || "";
const SVG = "http://www.w3.org/2000/svg";
let info = null, current = null, frame = 0, timer = null;

function api(path, body) {
  const opts = {headers: {"X-Token": token}};
  if (body !== undefined) {
    opts.method = "POST";
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  return fetch(path, opts).then(async (r) => {
    const data = await r.json();
    if (!r.ok) throw new Error(data.error || r.statusText);
    return data;
  });
}

function el(tag, text) { const e = document.createElement(tag); if (text !== undefined) e.textContent = text; return e; }
function showError(e) { document.getElementById("error").textContent = e ? String(e.message || e) : ""; }

function bounds(ep) {  // the arena's, or (your own task's x/y) the episode's own, with a margin
  if (info.arena.bounds) return info.arena.bounds;
  if (!ep) return [0, 1, 0, 1];
  const [ix, iy] = info.arena.xy;
  const xs = ep.states.map((s) => s[ix]), ys = ep.states.map((s) => s[iy]);
  const pad = (lo, hi) => { const m = (hi - lo) * 0.05 || 0.5; return [lo - m, hi + m]; };
  return [...pad(Math.min(...xs), Math.max(...xs)), ...pad(Math.min(...ys), Math.max(...ys))];
}

function toView(ep, x, y) {  // arena coordinates -> SVG (y up)
  const [x0, x1, y0, y1] = bounds(ep);
  return [100 * (x - x0) / (x1 - x0), 100 - 100 * (y - y0) / (y1 - y0)];
}

function drawArena(svg, ep) {
  svg.replaceChildren();
  for (const [x0, x1, y0, y1, kind] of info.arena.zones) {
    const [ax, ay] = toView(ep, x0, y1), [bx, by] = toView(ep, x1, y0);
    const r = document.createElementNS(SVG, "rect");
    r.setAttribute("x", ax); r.setAttribute("y", ay);
    r.setAttribute("width", bx - ax); r.setAttribute("height", by - ay);
    r.setAttribute("class", "zone zone-" + kind.replace(/[^a-z]+/g, "-"));
    const t = document.createElementNS(SVG, "title"); t.textContent = kind; r.appendChild(t);
    svg.appendChild(r);
  }
  return svg;
}

// A task without an arena (your own task): each state dimension over time, one band per
// dimension (scaled to its range in this episode), with a cursor at the step shown.
const MAX_DIMS = 12;
function drawStates(svg, ep, at) {
  svg.replaceChildren();
  if (!ep) return;
  const dims = Math.min(ep.states[0].length, MAX_DIMS), band = 100 / dims, steps = ep.length;
  for (let d = 0; d < dims; d++) {
    const values = ep.states.map((s) => s[d]);
    const lo = Math.min(...values), hi = Math.max(...values), span = hi - lo || 1;
    const y = (v) => d * band + band * 0.9 - band * 0.8 * (v - lo) / span;
    const line = document.createElementNS(SVG, "polyline");
    line.setAttribute("class", "dim");
    line.setAttribute("points", values.map((v, t) => `${100 * t / Math.max(steps, 1)},${y(v)}`).join(" "));
    const t = document.createElementNS(SVG, "title");
    t.textContent = `state[${d}]: ${lo.toPrecision(3)} .. ${hi.toPrecision(3)}`;
    line.appendChild(t);
    const name = document.createElementNS(SVG, "text");
    name.setAttribute("x", 0.5); name.setAttribute("y", d * band + 3); name.setAttribute("class", "dim-name");
    name.textContent = `s[${d}] = ${values[Math.min(at, steps)].toPrecision(3)}`;
    svg.append(line, name);
  }
  const cursor = document.createElementNS(SVG, "line");
  const x = 100 * Math.min(at, steps) / Math.max(steps, 1);
  cursor.setAttribute("class", "cursor");
  cursor.setAttribute("x1", x); cursor.setAttribute("x2", x); cursor.setAttribute("y1", 0); cursor.setAttribute("y2", 100);
  svg.appendChild(cursor);
}

// Frames travel on a topic of their own and may arrive after their episode is offered: while the
// graph renders (frames_expected) and the episode's final step has no frame yet, ask again for its
// frames (every 0.5 s, up to 10 s; /frames takes nothing) and redraw.
async function awaitFrames(ep, redraw) {
  const missing = () => ep.frames_expected && (!ep.frames.length || ep.frames[ep.frames.length - 1] < ep.length);
  for (let i = 0; i < 20 && missing(); i++) {
    await new Promise((resolve) => setTimeout(resolve, 500));
    try { ep.frames = (await api(`/api/episode/${ep.episode}/frames`)).frames; } catch (e) { return; }
    redraw();
  }
}

// An episode with rendered frames plays them as a video: the frame of the latest step <= the one shown.
function drawFrame(img, ep, at) {
  const steps = ep ? ep.frames : [];
  img.hidden = !steps.length;
  if (!steps.length) return;
  let shown = steps[0];
  for (const s of steps) { if (s <= at) shown = s; else break; }
  const src = `/api/episode/${ep.episode}/frame/${shown}` + (token ? `?token=${encodeURIComponent(token)}` : "");
  if (img.getAttribute("src") !== src) img.setAttribute("src", src);
  img.dataset.step = shown;
}

function drawPath(svg, ep, at) {
  drawArena(svg, ep);
  if (!ep) return;
  const [ix, iy] = info.arena.xy;
  const shown = ep.states.slice(0, Math.min(at, ep.length) + 1);
  const path = document.createElementNS(SVG, "polyline");
  path.setAttribute("class", "path");
  path.setAttribute("points", shown.map((s) => toView(ep, s[ix], s[iy]).join(",")).join(" "));
  svg.appendChild(path);
  const [sx, sy] = toView(ep, ep.states[0][ix], ep.states[0][iy]);
  const start = document.createElementNS(SVG, "circle");
  start.setAttribute("class", "start"); start.setAttribute("cx", sx); start.setAttribute("cy", sy); start.setAttribute("r", 2.2);
  svg.appendChild(start);
  const [cx, cy] = toView(ep, shown[shown.length - 1][ix], shown[shown.length - 1][iy]);
  const dot = document.createElementNS(SVG, "circle");
  dot.setAttribute("class", "agent"); dot.setAttribute("cx", cx); dot.setAttribute("cy", cy); dot.setAttribute("r", 1.5);
  svg.appendChild(dot);
}

// One episode drawn into a view (a path over the arena, the state dimensions, the frames) at step `at`.
function drawView(view, ep, at) {
  if (info.arena) drawPath(view.querySelector(".arena"), ep, at);
  if (info.task.includes(":")) drawStates(view.querySelector(".dims"), ep, at);
  drawFrame(view.querySelector(".frame"), ep, at);
}

function drawEpisode() {
  drawView(document.getElementById("views"), current, frame);
  if (!current) return;
  document.getElementById("scrub").value = frame;
  document.getElementById("step").textContent = `step ${frame} / ${current.length}`;
}

function stop() { if (timer) { clearInterval(timer); timer = null; } }
function play() {
  stop();
  if (!current) return;
  if (frame >= current.length) frame = 0;
  timer = setInterval(() => { if (frame >= current.length) { stop(); return; } frame += 1; drawEpisode(); }, 40);
}

async function openEpisode(episode) {
  stop(); showError(null);
  current = await api(`/api/episode/${episode}`);
  frame = current.length;
  document.getElementById("title").textContent = `Episode ${current.episode} (${current.length} steps)`;
  const scrub = document.getElementById("scrub");
  scrub.max = current.length;
  document.getElementById("return").value = current.label === null ? "" : current.label;
  drawEpisode();
  awaitFrames(current, drawEpisode);
  refresh(false);
}

async function refresh(openFirst) {
  const [queue, labels] = await Promise.all([api("/api/queue"), api("/api/labels")]);
  const list = document.getElementById("queue");
  list.replaceChildren();
  for (const e of queue.episodes) {
    const li = el("li", `episode ${e.episode} (${e.length} steps) — ${e.why}`);
    li.dataset.episode = e.episode;
    if (current && current.episode === e.episode) li.className = "current";
    li.addEventListener("click", () => openEpisode(e.episode).catch(showError));
    list.appendChild(li);
  }
  document.getElementById("count").textContent = `(${queue.episodes.length})`;
  counts.returns = `${labels.labels.length} return(s) given, ${queue.episodes.length} episode(s) wait`;
  showCounts();
  const body = document.getElementById("history");
  body.replaceChildren();
  for (const l of labels.labels) {
    const tr = el("tr");
    tr.append(el("td", l.episode), el("td", l.return), el("td", l.corrections));
    const fix = el("button", "correct"); fix.type = "button";
    fix.addEventListener("click", () => openEpisode(l.episode).catch(showError));
    const td = el("td"); td.appendChild(fix); tr.appendChild(td);
    body.appendChild(tr);
  }
  if (openFirst && !current && queue.episodes.length) await openEpisode(queue.episodes[0].episode);
}

// A team: who labelled how much, each person's error on gold episodes, and how far people agree.
async function refreshTeam() {
  if (info.team.length < 2) return;
  const team = await api("/api/team");
  const body = document.getElementById("team");
  body.replaceChildren();
  for (const p of team.people) {
    const gold = team.gold && team.gold[p.person];
    const err = gold && gold.n ? `${gold.mae.toPrecision(3)} (${gold.n})` : "–";
    const tr = el("tr");
    tr.append(el("td", p.person === info.person ? `${p.person} (you)` : p.person), el("td", p.labels), el("td", err));
    body.appendChild(tr);
  }
  const a = team.agreement;
  document.getElementById("agreement").textContent = a.episodes
    ? `agreement: ${a.episodes} episode(s) labelled by two or more, mean difference ${a.mean_abs_diff.toPrecision(3)}`
    : "agreement: no episode labelled by two or more yet";
}

async function submit(ev) {
  ev.preventDefault();
  if (!current) return;
  const raw = document.getElementById("return").value;
  const value = Number(raw);
  try {
    if (raw.trim() === "" || !Number.isFinite(value)) throw new Error("enter a number");
    const res = await api("/api/label", {episode: current.episode, return: value});
    document.getElementById("status").textContent = `labelled episode ${res.episode}: ${res.return}`;
    current = null;
    await refresh(true);
  } catch (e) { showError(e); }
}

async function skip() {
  if (!current) return;
  if (document.activeElement) document.activeElement.blur();  // Space must not answer again
  try { await api("/api/skip", {episode: current.episode}); current = null; await refresh(true); }
  catch (e) { showError(e); }
}

// What a person judges: the task's instruction, a legend of what is drawn, the keyboard shortcuts.
const counts = {returns: "", comparisons: ""};
function showCounts() {
  document.getElementById("counts").textContent = ["returns", "comparisons"].map((k) => counts[k]).filter((t) => t).join(" · ");
}

function legendItem(swatchClass, text) {
  const li = el("li"), sw = el("span");
  sw.className = "swatch " + swatchClass;
  li.append(sw, document.createTextNode(text));
  return li;
}

function showTask() {
  document.getElementById("instruction").textContent = info.instruction ||
    "No instruction was written for this task: ask whoever started this page what a good episode is " +
    "(they can give one: labeller_web instruction:=FILE, or INSTRUCTION in the task's module).";
  const legend = document.getElementById("legend");
  legend.replaceChildren();
  const meaning = Object.fromEntries(info.legend || []);
  if (info.arena) {
    const kinds = [...new Set(info.arena.zones.map((z) => z[4]))];
    for (const kind of kinds) legend.appendChild(legendItem("zone-swatch zone-" + kind.replace(/[^a-z]+/g, "-"), meaning[kind] || kind));
    legend.append(legendItem("start-swatch", "where the episode starts"), legendItem("path-swatch", "the path so far"),
                  legendItem("agent-swatch", "where it is at the step shown"));
  }
  if (info.task.includes(":")) {
    legend.appendChild(legendItem("path-swatch", "plots: each state dimension over time, scaled to its range in the episode; the red line is the step shown"));
  }
  const keys = [];
  if (info.feedback !== "preferences") keys.push("Enter: give the return typed");
  keys.push(info.feedback === "preferences" ? "Space: play / pause both" : "Space: play / pause");
  if (info.feedback !== "returns") keys.push("←: left is better", "→: right is better", "=: equal", "s: can't tell");
  document.getElementById("shortcuts").textContent = "Keys — " + keys.join(" · ");
  // Space plays / pauses, also where a button has the focus (it would press that button again)
  document.addEventListener("keydown", (ev) => {
    if (ev.key !== " " || ev.target.tagName === "INPUT" || ev.ctrlKey || ev.metaKey || ev.altKey) return;
    ev.preventDefault();
    if (info.feedback === "preferences") { if (pairTimer) stopPair(); else playPair(); }
    else if (timer) stop(); else play();
  });
  document.addEventListener("keyup", (ev) => {
    if (ev.key === " " && ev.target.tagName === "BUTTON") ev.preventDefault();
  });
}

async function main() {
  info = await api("/api/info");
  showTask();
  document.getElementById("who").textContent = `${info.labeller} · task ${info.task}`;
  document.getElementById("ordering").textContent = `ordered: ${info.ordering}`;
  if (info.team.length > 1) {
    document.getElementById("team-panel").hidden = false;
    document.getElementById("assignment").textContent = info.assignment === "split"
      ? "each episode goes to one of you" : "everyone is asked about every episode";
  }
  const [lo, hi] = info.range;
  const input = document.getElementById("return");
  if (lo === null) {
    document.getElementById("range").textContent = "any number";
  } else {
    input.min = lo; input.max = hi;
    document.getElementById("range").textContent = `between ${lo} and ${hi}`;
  }
  document.getElementById("label-form").addEventListener("submit", submit);
  document.getElementById("skip").addEventListener("click", skip);
  document.getElementById("play").addEventListener("click", play);
  document.getElementById("pause").addEventListener("click", stop);
  document.getElementById("scrub").addEventListener("input", (e) => { stop(); frame = Number(e.target.value); drawEpisode(); });
  // SVG elements have no .hidden property: toggle the attribute
  for (const svg of document.querySelectorAll("svg.arena")) svg.toggleAttribute("hidden", !info.arena);
  for (const svg of document.querySelectorAll("svg.dims")) svg.toggleAttribute("hidden", !info.task.includes(":"));
  if (info.arena) for (const svg of document.querySelectorAll("svg.arena")) drawArena(svg, null);
  setupCompare();
  if (info.feedback !== "preferences") await refresh(true);
  await refreshTeam();
  setInterval(() => Promise.all([info.feedback !== "preferences" ? refresh(!current) : null,
                                 info.feedback !== "returns" ? refreshPairs(!pair) : null,
                                 refreshTeam()]).catch(showError), 2000);
}

// Comparisons (feedback preferences or both): two episodes side by side, played together; the
// person answers left / right / equal (published at once) or can't tell (not asked again).
let pair = null, pairFrame = 0, pairTimer = null;

function setupCompare() {
  const asks = info.feedback !== "returns";
  document.getElementById("compare").hidden = !asks;
  document.getElementById("viewer").hidden = info.feedback === "preferences";
  document.getElementById("queue-panel").hidden = info.feedback === "preferences";
  document.getElementById("history-panel").hidden = info.feedback === "preferences";
  if (!asks) return;
  document.getElementById("pair-ordering").textContent = `pairs: ${info.pair_ordering}`;
  for (const [id, answer] of [["left", "a"], ["right", "b"], ["equal", "equal"]]) {
    document.getElementById(id).addEventListener("click", () => answerPair(answer));
  }
  document.getElementById("cant-tell").addEventListener("click", () => cantTell());
  document.getElementById("pair-play").addEventListener("click", playPair);
  document.addEventListener("keydown", (ev) => {
    if (!pair || ev.target.tagName === "INPUT" || ev.ctrlKey || ev.metaKey || ev.altKey) return;
    const key = {ArrowLeft: "a", ArrowRight: "b", "=": "equal", s: "cant"}[ev.key];
    if (!key) return;
    ev.preventDefault();
    if (key === "cant") cantTell(); else answerPair(key);
  });
  refreshPairs(true).catch(showError);
}

function drawPair() {
  if (!pair) return;
  drawView(document.getElementById("view-a"), pair.a, pairFrame);
  drawView(document.getElementById("view-b"), pair.b, pairFrame);
  document.getElementById("pair-step").textContent =
    `step ${pairFrame} / ${Math.max(pair.a.length, pair.b.length)}`;
}

function stopPair() { if (pairTimer) { clearInterval(pairTimer); pairTimer = null; } }
function playPair() {
  stopPair();
  if (!pair) return;
  const end = Math.max(pair.a.length, pair.b.length);
  if (pairFrame >= end) pairFrame = 0;
  pairTimer = setInterval(() => { if (pairFrame >= end) { stopPair(); return; } pairFrame += 1; drawPair(); }, 40);
}

async function openPair(a, b, why) {
  stopPair(); showError(null);
  const [ea, eb] = await Promise.all([api(`/api/episode/${a}`), api(`/api/episode/${b}`)]);
  pair = {a: ea, b: eb};
  document.getElementById("pair-title").textContent = `Episode ${a} (left) or episode ${b} (right)?`;
  document.getElementById("pair-why").textContent = why;
  document.getElementById("title-a").textContent = `episode ${a} (${ea.length} steps)`;
  document.getElementById("title-b").textContent = `episode ${b} (${eb.length} steps)`;
  pairFrame = 0;
  drawPair();
  awaitFrames(ea, drawPair);
  awaitFrames(eb, drawPair);
  playPair();
}

async function refreshPairs(openFirst) {
  const [pairs, done] = await Promise.all([api("/api/pairs"), api("/api/comparisons")]);
  document.getElementById("pair-count").textContent = `(${pairs.pairs.length} waiting)`;
  counts.comparisons = `${done.comparisons.length} comparison(s) given, ${pairs.pairs.length} pair(s) wait`;
  showCounts();
  const body = document.getElementById("comparisons");
  body.replaceChildren();
  const words = {a: "left", b: "right", equal: "equal"};
  for (const c of done.comparisons) {
    const tr = el("tr");
    tr.append(el("td", c.a), el("td", c.b), el("td", words[c.preference]), el("td", c.corrections));
    body.appendChild(tr);
  }
  if (openFirst && !pair && pairs.pairs.length) {
    const first = pairs.pairs[0];
    await openPair(first.a, first.b, first.why);
  } else if (!pair) {
    document.getElementById("pair-title").textContent = "No pair to compare yet";
    for (const id of ["pair-why", "pair-step", "title-a", "title-b"]) document.getElementById(id).textContent = "";
    for (const side of ["view-a", "view-b"]) {
      const view = document.getElementById(side);
      if (info.arena) drawArena(view.querySelector(".arena"), null);
      view.querySelector(".dims").replaceChildren();
      view.querySelector(".frame").hidden = true;
    }
  }
  for (const id of ["left", "right", "equal", "cant-tell", "pair-play"]) document.getElementById(id).disabled = !pair;
}

async function answerPair(answer) {
  if (!pair) return;
  if (document.activeElement) document.activeElement.blur();  // Space must not answer again
  try {
    const res = await api("/api/compare", {a: pair.a.episode, b: pair.b.episode, preference: answer});
    const words = {a: "left better", b: "right better", equal: "equal"};
    document.getElementById("status").textContent = `episodes ${res.a} and ${res.b}: ${words[res.preference]}`;
    pair = null; stopPair();
    await refreshPairs(true);
  } catch (e) { showError(e); }
}

async function cantTell() {
  if (!pair) return;
  if (document.activeElement) document.activeElement.blur();  // Space must not answer again
  try {
    await api("/api/cant_tell", {a: pair.a.episode, b: pair.b.episode});
    document.getElementById("status").textContent = `episodes ${pair.a.episode} and ${pair.b.episode}: can't tell`;
    pair = null; stopPair();
    await refreshPairs(true);
  } catch (e) { showError(e); }
}

main().catch(showError);
