// swarm-sitl's page: draws the frames of one document (swarm_sitl/view/replay.py says what is in
// it). A finished run's document comes whole; a live run's comes as it grows (/frames.json).
"use strict";

const DOWN = 1, FAILSAFE = 2;             // a follower's state bits (replay.py)
const TRAIL_S = 2.0;                      // a follower's trail on the maps [s]
const POLL_MS = 200;                      // live: how often the page asks for new frames [ms]
const COLOURS = { ok: "#2a2", old: "#e90", stale: "#c33", fault: "#c0c", none: "#bbb" };

let doc = null;          // the document
let cur = 0;             // the frame shown
let playing = false;
let following = true;    // live: show the newest frame as it comes
let lastWall = null;     // play: the wall clock at the last step [ms]
let simAtWall = 0;       // play: the simulated time to show [s]
const el = (id) => document.getElementById(id);

function say(text) { el("message").textContent = text; }

function colourOf(i, n) { return `hsl(${Math.round((360 * (i - 1)) / Math.max(n, 1))}, 65%, 42%)`; }

async function getJSON(url) {
  const r = await fetch(url, { cache: "no-store" });
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await r.text()}`);
  return r.json();
}

async function start() {
  try {
    doc = await getJSON("/document.json");
  } catch (e) {
    say(`cannot load the run: ${e.message}`);
    return;
  }
  el("title").textContent = `swarm-sitl: ${doc.name}`;
  el("followers").innerHTML = doc.followers
    .map((i) => `<li class="follower" data-id="${i}" data-state="flying" style="border-left: 6px solid ${colourOf(i, doc.followers.length)}; padding-left: 4px">${i} <span class="err"></span></li>`)
    .join("");
  el("edges").querySelector("tbody").innerHTML = doc.edges
    .map((e) => `<tr data-edge="${e.src}->${e.dst}"><td>${e.src}&rarr;${e.dst}</td><td></td><td></td><td>${e.delivered_frac === null ? "" : (100 * e.delivered_frac).toFixed(1) + " %"}</td></tr>`)
    .join("");
  if (doc.live) {
    el("follow").hidden = false;
    if (doc.lockstep) { el("pause-run").hidden = false; el("step-run").hidden = false; }
    setTimeout(poll, 250);
  }
  frameCount();
  cur = doc.live ? nFrames() - 1 : 0;
  show();
}

function nFrames() { return doc.frames.t_s.length; }

function frameCount() {
  const s = el("slider");
  s.max = Math.max(0, nFrames() - 1);
  if (!doc.live || following) s.value = cur;
}

// new frames after the ones we have, column by column, by the names the document declares
// (swarm_sitl/view/frames.py): a list is a column, an object holds columns by key
function appendColumns(to, more) {
  for (const [k, v] of Object.entries(more)) {
    if (Array.isArray(v)) (to[k] = to[k] || []).push(...v);
    else appendColumns((to[k] = to[k] || {}), v);
  }
}

// live: what came since the frames we have
async function poll() {
  let more;
  try {
    more = await getJSON(`/frames.json?from=${nFrames()}&events=${doc.events.length}`);
  } catch (e) {
    say(doc.done ? "the run has ended" : "the run is not answering (ended?)");
    setTimeout(poll, 2000);
    return;
  }
  appendColumns(doc.frames, more.frames);
  doc.events.push(...more.events);
  doc.done = more.done;
  el("rtf").textContent = more.rtf ? `${more.rtf.toFixed(1)}x real time` : "";
  showHold(more);
  frameCount();
  if (following && nFrames()) cur = nFrames() - 1;
  show();
  if (!more.done) setTimeout(poll, POLL_MS);
}

// live, lockstep: the run paused (held at one tick once every follower is there) or flying
function showHold(more) {
  const held = more.paused && more.held_s !== null && !more.done;
  el("pause-run").textContent = more.paused ? "resume run" : "pause run";
  el("pause-run").disabled = more.done;
  el("step-run").disabled = !held;
  el("pause-run").dataset.state = more.done ? "over" : held ? "held" : more.paused ? "pausing" : "flying";
  if (more.done) say("the run has ended");
  else if (held) say(`the run is held at t = ${more.held_s.toFixed(2)} s`);
  else say(more.paused ? "pausing the run..." : "");
}

// -- drawing ------------------------------------------------------------------------------------
const boxes = {};        // each map's box, and the frame count it was made for
function bounds(axes) {
  // the box around the leader's path and every follower's positions (equal scale on both axes),
  // made again only when frames have come
  const key = axes.join(""), n = nFrames();
  if (!boxes[key] || boxes[key].n !== n) boxes[key] = { n, box: box(axes) };
  return boxes[key].box;
}

function box(axes) {
  let lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
  const take = (p) => {
    if (!p || p[0] === null) return;
    for (let k = 0; k < 2; k++) { lo[k] = Math.min(lo[k], p[axes[k]]); hi[k] = Math.max(hi[k], p[axes[k]]); }
  };
  doc.frames.leader.forEach(take);
  for (const a of Object.values(doc.frames.followers)) a.p.forEach(take);
  for (const off of Object.values(doc.offsets_m)) {
    doc.frames.leader.forEach((p) => take([p[0] + off[0], p[1] + off[1], p[2] + off[2]]));
  }
  if (!isFinite(lo[0])) { lo = [-1, -1]; hi = [1, 1]; }
  return { lo, hi };
}

function mapper(canvas, b) {
  const pad = 24, w = canvas.width - 2 * pad, h = canvas.height - 2 * pad;
  const span = Math.max((hi0(b, 0) - b.lo[0]) / w, (hi0(b, 1) - b.lo[1]) / h, 1e-6);
  const cx = (b.lo[0] + b.hi[0]) / 2, cy = (b.lo[1] + b.hi[1]) / 2;
  return (x, y) => [canvas.width / 2 + (x - cx) / span, canvas.height / 2 - (y - cy) / span];
}
function hi0(b, k) { return Math.max(b.hi[k], b.lo[k] + 1e-3); }

function drawMap(id, axes) {
  const c = el(id), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  const to = mapper(c, bounds(axes));
  const F = doc.frames, n = doc.followers.length;
  g.strokeStyle = "#999"; g.lineWidth = 1; g.beginPath();
  F.leader.forEach((p, k) => { const [x, y] = to(p[axes[0]], p[axes[1]]); k ? g.lineTo(x, y) : g.moveTo(x, y); });
  g.stroke();
  const L = F.leader[cur];
  if (!L) return;
  const [lx, ly] = to(L[axes[0]], L[axes[1]]);
  g.fillStyle = "#000"; g.beginPath(); g.arc(lx, ly, 5, 0, 7); g.fill();
  const back = Math.max(0, cur - Math.round(TRAIL_S / frameDt()));
  doc.followers.forEach((i) => {
    const a = F.followers[i], col = colourOf(i, n), off = doc.offsets_m[i];
    const [tx, ty] = to(L[axes[0]] + off[axes[0]], L[axes[1]] + off[axes[1]]);
    g.strokeStyle = col; g.strokeRect(tx - 4, ty - 4, 8, 8);            // its target place
    g.beginPath();
    let pen = false;
    for (let k = back; k <= cur; k++) {
      const p = a.p[k];
      if (!p || p[0] === null) { pen = false; continue; }
      const [x, y] = to(p[axes[0]], p[axes[1]]);
      pen ? g.lineTo(x, y) : g.moveTo(x, y); pen = true;
    }
    g.stroke();
    const p = a.p[cur];
    if (!p || p[0] === null) return;
    const [x, y] = to(p[axes[0]], p[axes[1]]);
    g.fillStyle = a.state[cur] & DOWN ? "#aaa" : col;
    g.beginPath(); g.arc(x, y, 4, 0, 7); g.fill();
    if (n <= 16) { g.fillStyle = "#222"; g.font = "10px sans-serif"; g.fillText(String(i), x + 5, y - 5); }
  });
}

function frameDt() { const t = doc.frames.t_s; return t.length > 1 ? t[1] - t[0] : doc.period_s; }

function drawErrors() {
  const c = el("err"), g = c.getContext("2d"), F = doc.frames, n = doc.followers.length;
  g.clearRect(0, 0, c.width, c.height);
  const pad = 30, w = c.width - pad - 8, h = c.height - pad - 8;
  const tEnd = doc.live ? Math.max(F.t_s[F.t_s.length - 1] || 0, 1) : doc.duration_s;
  let top = 0.01;
  for (const a of Object.values(F.followers)) for (let k = 0; k <= cur; k++) if (a.err[k] !== null) top = Math.max(top, a.err[k]);
  const X = (t) => pad + (w * t) / tEnd, Y = (e) => 8 + h - (h * e) / top;
  g.strokeStyle = "#888"; g.strokeRect(pad, 8, w, h);
  g.fillStyle = "#444"; g.font = "10px sans-serif";
  g.fillText(top.toPrecision(2), 2, 14); g.fillText("0", 2, 8 + h); g.fillText(`${tEnd.toFixed(0)} s`, pad + w - 24, c.height - 4);
  doc.followers.forEach((i) => {
    const a = F.followers[i];
    g.strokeStyle = colourOf(i, n); g.beginPath();
    let pen = false;
    for (let k = 0; k <= cur; k++) {
      if (a.err[k] === null) { pen = false; continue; }
      const x = X(F.t_s[k]), y = Y(a.err[k]);
      pen ? g.lineTo(x, y) : g.moveTo(x, y); pen = true;
    }
    g.stroke();
  });
  g.strokeStyle = "#000"; g.beginPath(); g.moveTo(X(F.t_s[cur] || 0), 8); g.lineTo(X(F.t_s[cur] || 0), 8 + h); g.stroke();
}

// an edge's health at the frame shown: a fault of the plan acting, else the age of its newest
function edgeState(e, t) {
  if (e.faults.some((f) => f.from_s <= t && t < f.until_s)) return "fault";
  const ages = doc.frames.edge_age_s[`${e.src}->${e.dst}`];
  if (!ages) return "none";
  const age = ages[cur];
  if (age === null || age === undefined || age > doc.staleness_s) return "stale";
  return age > 2.0001 * doc.period_s ? "old" : "ok";
}

function drawGraph(t) {
  const c = el("graph"), g = c.getContext("2d"), N = doc.graph.nodes;
  g.clearRect(0, 0, c.width, c.height);
  const rows = el("edges").querySelector("tbody").rows;
  doc.edges.forEach((e, k) => {
    const s = edgeState(e, t), a = N[e.src], b = N[e.dst];
    g.strokeStyle = COLOURS[s]; g.lineWidth = s === "fault" ? 2.5 : 1.2;
    g.setLineDash(s === "none" ? [3, 3] : []);
    const dx = b[0] - a[0], dy = b[1] - a[1], len = Math.hypot(dx, dy) || 1, ux = dx / len, uy = dy / len;
    const x1 = a[0] + 8 * ux, y1 = a[1] + 8 * uy, x2 = b[0] - 9 * ux, y2 = b[1] - 9 * uy;
    g.beginPath(); g.moveTo(x1, y1); g.lineTo(x2, y2); g.stroke(); g.setLineDash([]);
    g.fillStyle = COLOURS[s]; g.beginPath();
    g.moveTo(x2, y2); g.lineTo(x2 - 6 * ux + 3 * uy, y2 - 6 * uy - 3 * ux); g.lineTo(x2 - 6 * ux - 3 * uy, y2 - 6 * uy + 3 * ux); g.fill();
    const row = rows[k], ages = doc.frames.edge_age_s[`${e.src}->${e.dst}`];
    row.dataset.state = s; row.cells[1].textContent = s;
    row.cells[2].textContent = ages && ages[cur] !== null && ages[cur] !== undefined ? ages[cur].toFixed(3) : "";
  });
  g.font = "9px sans-serif"; g.textAlign = "center"; g.textBaseline = "middle";
  for (const [node, [x, y]] of Object.entries(N)) {
    const st = node === "0" ? 0 : (doc.frames.followers[node] || { state: [] }).state[cur] || 0;
    g.fillStyle = node === "0" ? "#000" : st & DOWN ? "#ccc" : st & FAILSAFE ? "#f93" : "#fff";
    g.strokeStyle = "#333"; g.lineWidth = 1;
    g.beginPath(); g.arc(x, y, 8, 0, 7); g.fill(); g.stroke();
    g.fillStyle = node === "0" ? "#fff" : "#000"; g.fillText(node === "0" ? "L" : node, x, y + 0.5);
  }
  g.textAlign = "start"; g.textBaseline = "alphabetic";
}

function showLists(t) {
  for (const li of el("followers").children) {
    const a = doc.frames.followers[li.dataset.id], st = a.state[cur] || 0, e = a.err[cur];
    li.dataset.state = st & DOWN ? "down" : st & FAILSAFE ? "failsafe" : "flying";
    li.querySelector(".err").textContent = e === null || e === undefined ? li.dataset.state : `${e.toFixed(3)} m` + (st & FAILSAFE ? " failsafe" : "");
  }
  const ol = el("events");
  if (ol.children.length !== doc.events.length) {
    ol.innerHTML = doc.events.map((e) => `<li data-t="${e.t_s}">${e.t_s.toFixed(2)} s ${e.kind} <small>${e.source} ${e.text}</small></li>`).join("");
  }
  for (const li of ol.children) li.classList.toggle("future", Number(li.dataset.t) > t);
}

function show() {
  if (!doc || !nFrames()) { el("time").textContent = "waiting for the run's first frame"; return; }
  cur = Math.min(Math.max(0, cur), nFrames() - 1);
  const t = doc.frames.t_s[cur];
  el("time").textContent = `t = ${t.toFixed(2)} s of ${doc.duration_s} s`;
  el("slider").value = cur;
  drawMap("top", [0, 1]); drawMap("side", [0, 2]); drawErrors(); drawGraph(t); showLists(t);
}

// -- controls -----------------------------------------------------------------------------------
// play: one step per animation frame, and none asked for while paused (an idle page costs nothing)
function tick(now) {
  if (!playing || !doc) return;
  if (lastWall !== null) {
    simAtWall += ((now - lastWall) / 1000) * Number(el("speed").value);
    const T = doc.frames.t_s;
    while (cur < T.length - 1 && T[cur + 1] <= simAtWall) cur++;
    if (cur >= T.length - 1 && !doc.live) playing = false, el("play").textContent = "play";
    show();
  }
  lastWall = now;
  requestAnimationFrame(tick);
}

el("play").onclick = () => {
  playing = !playing; following = false; lastWall = null;
  if (playing && cur >= nFrames() - 1 && !doc.live) cur = 0;
  simAtWall = doc.frames.t_s[cur] || 0;
  el("play").textContent = playing ? "pause" : "play";
  if (playing) requestAnimationFrame(tick);
};
el("slider").oninput = () => { cur = Number(el("slider").value); following = false; simAtWall = doc.frames.t_s[cur] || 0; show(); };
el("follow").onclick = () => { following = true; playing = false; cur = nFrames() - 1; show(); };
async function control(what) {
  try {
    // the server's token (server.py): a control request must come from this page
    const token = document.querySelector('meta[name="control-token"]').content;
    const r = await fetch(`/control?${what}`, { method: "POST", headers: { "X-Swarm-Sitl-Token": token } });
    if (!r.ok) say(await r.text());
  } catch (e) { say(`the run did not answer: ${e.message}`); }
}
el("pause-run").onclick = () => control("pause=toggle");
el("step-run").onclick = () => control("step=1");
document.addEventListener("keydown", (e) => { if (e.key === " " && e.target === document.body) { e.preventDefault(); el("play").click(); } });
start();
