// The labelling page: the queue, an episode's animated path over the arena (or, for your own
// task, its state dimensions over time), the label form and the labels given. Every value from the server is written with textContent or as an SVG
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

function bounds() {  // the arena's, or (your own task's x/y) the episode's own, with a margin
  if (info.arena.bounds) return info.arena.bounds;
  if (!current) return [0, 1, 0, 1];
  const [ix, iy] = info.arena.xy;
  const xs = current.states.map((s) => s[ix]), ys = current.states.map((s) => s[iy]);
  const pad = (lo, hi) => { const m = (hi - lo) * 0.05 || 0.5; return [lo - m, hi + m]; };
  return [...pad(Math.min(...xs), Math.max(...xs)), ...pad(Math.min(...ys), Math.max(...ys))];
}

function toView(x, y) {  // arena coordinates -> SVG (y up)
  const [x0, x1, y0, y1] = bounds();
  return [100 * (x - x0) / (x1 - x0), 100 - 100 * (y - y0) / (y1 - y0)];
}

function drawArena() {
  const svg = document.getElementById("arena");
  svg.replaceChildren();
  for (const [x0, x1, y0, y1, kind] of info.arena.zones) {
    const [ax, ay] = toView(x0, y1), [bx, by] = toView(x1, y0);
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
function drawStates() {
  const svg = document.getElementById("dims");
  svg.replaceChildren();
  if (!current) return;
  const dims = Math.min(current.states[0].length, MAX_DIMS), band = 100 / dims, steps = current.length;
  for (let d = 0; d < dims; d++) {
    const values = current.states.map((s) => s[d]);
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
    name.textContent = `s[${d}] = ${values[frame].toPrecision(3)}`;
    svg.append(line, name);
  }
  const cursor = document.createElementNS(SVG, "line");
  const x = 100 * frame / Math.max(steps, 1);
  cursor.setAttribute("class", "cursor");
  cursor.setAttribute("x1", x); cursor.setAttribute("x2", x); cursor.setAttribute("y1", 0); cursor.setAttribute("y2", 100);
  svg.appendChild(cursor);
}

// An episode with rendered frames plays them as a video: the frame of the latest step <= the one shown.
function drawFrame() {
  const img = document.getElementById("frame");
  const steps = current ? current.frames : [];
  img.hidden = !steps.length;
  if (!steps.length) return;
  let shown = steps[0];
  for (const s of steps) { if (s <= frame) shown = s; else break; }
  const src = `/api/episode/${current.episode}/frame/${shown}` + (token ? `?token=${encodeURIComponent(token)}` : "");
  if (img.getAttribute("src") !== src) img.setAttribute("src", src);
  img.dataset.step = shown;
}

function drawEpisode() {
  if (info.arena) drawPath();
  if (info.task.includes(":")) drawStates();  // your own task: its state dimensions over time
  drawFrame();
  if (!current) return;
  document.getElementById("scrub").value = frame;
  document.getElementById("step").textContent = `step ${frame} / ${current.length}`;
}

function drawPath() {
  const svg = drawArena();
  if (!current) return;
  const [ix, iy] = info.arena.xy;
  const shown = current.states.slice(0, frame + 1);
  const path = document.createElementNS(SVG, "polyline");
  path.setAttribute("class", "path");
  path.setAttribute("points", shown.map((s) => toView(s[ix], s[iy]).join(",")).join(" "));
  svg.appendChild(path);
  const [cx, cy] = toView(shown[shown.length - 1][ix], shown[shown.length - 1][iy]);
  const dot = document.createElementNS(SVG, "circle");
  dot.setAttribute("class", "agent"); dot.setAttribute("cx", cx); dot.setAttribute("cy", cy); dot.setAttribute("r", 1.5);
  svg.appendChild(dot);
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
  try { await api("/api/skip", {episode: current.episode}); current = null; await refresh(true); }
  catch (e) { showError(e); }
}

async function main() {
  info = await api("/api/info");
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
  document.getElementById("arena").toggleAttribute("hidden", !info.arena);
  document.getElementById("dims").toggleAttribute("hidden", !info.task.includes(":"));
  if (info.arena) drawArena();
  await refresh(true);
  await refreshTeam();
  setInterval(() => Promise.all([refresh(!current), refreshTeam()]).catch(showError), 2000);
}

main().catch(showError);
