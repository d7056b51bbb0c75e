// impact's live viewer: draws one world from its state stream, flashes its collision events,
// plots the server's stats. Fed by /stream (server-sent events, JSON messages as in PROTOCOL.md)
// and /api/state?tick=T (the state query, for rewinding through the rollback window).
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("view");
const ctx = canvas.getContext("2d");

// The world as the state stream describes it (PROTOCOL.md, "State streams").
const live = { bodies: new Map(), frame: null, synced: false, tick: 0, at: performance.now() };
let frozen = null; // { bodies, tick } while paused
let past = null; // { bodies, tick } while rewound (the state query's answer)
let selected = null; // entity id

const FLASH_S = 0.6;
const MAX_FLASHES = 3000;
const flashes = []; // { x, z, nx, nz, kind, born, drawn, a, b, phase }
const recent = []; // the last events, for a body's list: { key, tick, a, b, phase, status, toi }
const MAX_RECENT = 6000;
let eventsDrawn = 0;
const classColor = new Map();
const cam = { scale: 10, x: 0, z: 0, fitted: false };
const filters = { entity: null, cls: "", phase: "" };
const plot = { tick: [], stage: [], depth: [] };
let drawMs = 0;

// Body colours, by class in the order classes are first seen: hues away from the event colours
// (yellow, cyan, red, green) so a flash is never mistaken for a body.
const PALETTE = ["hsl(222 62% 63%)", "hsl(276 48% 68%)", "hsl(24 62% 56%)", "hsl(330 52% 64%)",
  "hsl(200 28% 62%)", "hsl(250 30% 72%)", "hsl(12 35% 66%)", "hsl(300 25% 60%)"];

function colorOf(cls) {
  let c = classColor.get(cls);
  if (!c) {
    c = PALETTE[classColor.size % PALETTE.length];
    classColor.set(cls, c);
    const opt = document.createElement("option");
    opt.textContent = cls;
    $("f-class").appendChild(opt);
  }
  return c;
}

function applyState(f) {
  const now = performance.now();
  if (f.full) {
    live.bodies.clear();
    live.synced = true;
  } else if (live.frame === null || ((live.frame + 1) >>> 0) !== f.frame) {
    live.synced = false; // a gap: wait for the next full frame
  }
  live.frame = f.frame;
  if (!live.synced) return;
  for (const e of f.left) live.bodies.delete(e);
  for (const i of f.entered) {
    colorOf(i.class);
    live.bodies.set(i.entity, { info: i, p: [0, 0, 0], v: [0, 0, 0], asleep: false, at: now });
  }
  // A frame carries only the bodies whose motion changed; the others fly on from their last
  // sample at its velocity (PROTOCOL.md, "State streams"), so each keeps when it was sampled.
  for (const [e, p, v, asleep] of f.moved) {
    const b = live.bodies.get(e);
    if (b) { b.p = p; b.v = v; b.asleep = asleep; b.at = now; }
  }
  live.tick = f.tick;
  live.at = now;
  if (!cam.fitted && live.bodies.size > 0) fit();
}

function eventKey(e) { return `${e.tick}:${e.a}:${e.b}:${e.phase}`; }

function remember(e, status) {
  const key = eventKey(e);
  for (let k = recent.length - 1; k >= Math.max(0, recent.length - 400); k--) {
    if (recent[k].key === key) { recent[k].status = status; recent[k].toi = e.toi; return; }
  }
  recent.push({ key, tick: e.tick, a: e.a, b: e.b, phase: e.phase, status, toi: e.toi });
  if (recent.length > MAX_RECENT) recent.splice(0, recent.length - MAX_RECENT);
}

function flash(e, kind) {
  if (frozen) return;
  flashes.push({ x: e.point[0], z: e.point[2], nx: e.normal[0], nz: e.normal[2], kind, born: performance.now(),
    drawn: false, a: e.a, b: e.b, phase: e.phase });
  if (flashes.length > MAX_FLASHES) flashes.splice(0, flashes.length - MAX_FLASHES);
}

function onMessage(m) {
  switch (m.type) {
    case "state": applyState(m); break;
    case "events": for (const e of m.events) { remember(e, "provisional"); flash(e, "provisional"); } break;
    case "corrections":
      for (const e of m.retracted) { remember(e, "retracted"); flash(e, "retracted"); }
      for (const e of m.amended.concat(m.added)) { remember(e, "corrected"); flash(e, "corrected"); }
      break;
    case "confirmed": for (const e of m.events) remember(e, "confirmed"); break;
    case "stats": onStats(m); break;
  }
  if (selected !== null) listSelected();
}

function onStats(s) {
  for (const t of s.tick_ms || []) plot.tick.push(t);
  if (plot.tick.length > 320) plot.tick.splice(0, plot.tick.length - 320);
  const stages = s.stage_ms || [];
  plot.stage.push(stages.reduce((a, [, ms]) => a + ms, 0));
  plot.depth.push(s.rollback_depth_max);
  for (const p of [plot.stage, plot.depth]) if (p.length > 90) p.shift();
  $("v-tick").textContent = `p50 ${s.tick_ms_p50.toFixed(2)} · p99 ${s.tick_ms_p99.toFixed(2)}`;
  $("v-stage").textContent = `${plot.stage[plot.stage.length - 1].toFixed(3)}`;
  $("v-depth").textContent = `${s.rollbacks} rollbacks, max ${s.rollback_depth_max}`;
  $("stages").textContent = stages.filter(([, ms]) => ms >= 0.0005).map(([n, ms]) => `${n} ${ms.toFixed(3)}`).join(" · ");
  drawPlot($("p-tick"), plot.tick, "#8ab4f8");
  drawPlot($("p-stage"), plot.stage, "#ce93d8");
  drawPlot($("p-depth"), plot.depth, "#ffb74d", true);
}

function drawPlot(c, data, color, bars) {
  const g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (data.length === 0) return;
  const max = Math.max(1e-9, ...data);
  g.fillStyle = g.strokeStyle = color;
  const w = c.width / Math.max(1, data.length - (bars ? 0 : 1));
  g.beginPath();
  data.forEach((v, i) => {
    const y = c.height - 2 - (v / max) * (c.height - 6);
    if (bars) g.fillRect(i * w, y, Math.max(1, w - 1), c.height - y);
    else if (i === 0) g.moveTo(0, y); else g.lineTo(i * w, y);
  });
  if (!bars) g.stroke();
  g.fillStyle = "#7f8b99";
  g.font = "10px system-ui";
  g.fillText(max.toFixed(max < 10 ? 2 : 0), 2, 10);
}

// --- the view -------------------------------------------------------------------------------

// Where body `b` of `src` is drawn at `t` (ms): a live body carried from its sample at its
// velocity, at most 150 ms past the newest frame; a paused or rewound one where it was.
function placed(b, src, t = performance.now()) {
  if (src !== live || b.asleep || b.at === undefined) return b.p;
  const s = (Math.min(t, live.at + 150) - b.at) / 1000;
  return [b.p[0] + b.v[0] * s, b.p[1] + b.v[1] * s, b.p[2] + b.v[2] * s];
}

function fit() {
  let lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
  for (const b of live.bodies.values()) {
    const p = placed(b, live);
    const c = [p[0] + b.info.offset_m[0], p[2] + b.info.offset_m[2]];
    const h = [b.info.half_extents_m[0], b.info.half_extents_m[2]];
    lo = [Math.min(lo[0], c[0] - h[0]), Math.min(lo[1], c[1] - h[1])];
    hi = [Math.max(hi[0], c[0] + h[0]), Math.max(hi[1], c[1] + h[1])];
  }
  const r = canvas.getBoundingClientRect();
  cam.x = (lo[0] + hi[0]) / 2;
  cam.z = (lo[1] + hi[1]) / 2;
  cam.scale = 0.92 * Math.min(r.width / Math.max(1, hi[0] - lo[0]), r.height / Math.max(1, hi[1] - lo[1]));
  cam.fitted = true;
}

const toScreen = (x, z, r) => [r.width / 2 + (x - cam.x) * cam.scale, r.height / 2 + (z - cam.z) * cam.scale];
const toWorld = (sx, sz, r) => [cam.x + (sx - r.width / 2) / cam.scale, cam.z + (sz - r.height / 2) / cam.scale];

function shown() {
  if (past) return past;
  if (frozen) return frozen;
  return live;
}

function passes(b) {
  return !filters.cls || b.info.class === filters.cls;
}

function draw() {
  const t0 = performance.now();
  const dpr = window.devicePixelRatio || 1;
  const r = canvas.getBoundingClientRect();
  if (canvas.width !== Math.round(r.width * dpr) || canvas.height !== Math.round(r.height * dpr)) {
    canvas.width = Math.round(r.width * dpr);
    canvas.height = Math.round(r.height * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#11151c";
  ctx.fillRect(0, 0, r.width, r.height);
  const src = shown();
  let n = 0;
  // Static bodies first, then the moving ones over them.
  for (const pass of [true, false]) {
    for (const [e, b] of src.bodies) {
      if (b.info.fixed !== pass) continue;
      n++;
      const on = passes(b);
      const p = placed(b, src, t0);
      const x = p[0] + b.info.offset_m[0];
      const z = p[2] + b.info.offset_m[2];
      const [sx, sz] = toScreen(x, z, r);
      const hx = b.info.half_extents_m[0] * cam.scale, hz = b.info.half_extents_m[2] * cam.scale;
      if (sx + hx < 0 || sz + hz < 0 || sx - hx > r.width || sz - hz > r.height) continue;
      const base = b.info.fixed ? "#3a4656" : colorOf(b.info.class);
      ctx.globalAlpha = !on ? 0.12 : b.asleep ? 0.35 : b.info.fixed ? 0.55 : 0.9;
      ctx.fillStyle = base;
      ctx.beginPath();
      switch (b.info.shape) {
        case "sphere": ctx.arc(sx, sz, Math.max(1, hx), 0, 2 * Math.PI); break;
        case "capsule": ctx.roundRect(sx - hx, sz - hz, 2 * hx, 2 * hz, Math.min(hx, hz)); break;
        case "ellipsoid": case "convex": ctx.ellipse(sx, sz, Math.max(1, hx), Math.max(1, hz), 0, 0, 2 * Math.PI); break;
        default: ctx.rect(sx - hx, sz - hz, 2 * hx, 2 * hz);
      }
      ctx.fill();
      if (b.info.owner !== null || e === selected || e === filters.entity) {
        ctx.globalAlpha = 1;
        ctx.lineWidth = e === selected || e === filters.entity ? 2.5 : 1;
        ctx.strokeStyle = e === selected || e === filters.entity ? "#ffffff" : "#e0e0e0";
        ctx.stroke();
      }
    }
  }
  ctx.globalAlpha = 1;
  // Contacts: a ring at the point and its normal, fading.
  const now = performance.now();
  let keep = 0;
  for (const f of flashes) {
    const age = (now - f.born) / 1000;
    if (age > FLASH_S) continue;
    flashes[keep++] = f;
    if (filters.entity !== null && f.a !== filters.entity && f.b !== filters.entity) continue;
    if (filters.phase && f.phase !== filters.phase) continue;
    if (filters.cls && !touches(f, filters.cls)) continue;
    if (!f.drawn) { f.drawn = true; eventsDrawn++; }
    const [sx, sz] = toScreen(f.x, f.z, r);
    const a = 1 - age / FLASH_S;
    const color = f.kind === "provisional" ? "#ffd54a" : f.kind === "corrected" ? "#4dd0e1" : "#ff5252";
    ctx.globalAlpha = a;
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    if (f.kind === "retracted") {
      const k = 5;
      ctx.moveTo(sx - k, sz - k); ctx.lineTo(sx + k, sz + k);
      ctx.moveTo(sx + k, sz - k); ctx.lineTo(sx - k, sz + k);
    } else {
      ctx.arc(sx, sz, 3 + 9 * (1 - a), 0, 2 * Math.PI);
      ctx.moveTo(sx, sz);
      ctx.lineTo(sx + f.nx * 1.5 * cam.scale, sz + f.nz * 1.5 * cam.scale);
    }
    ctx.stroke();
  }
  flashes.length = keep;
  ctx.globalAlpha = 1;
  drawMs = 0.9 * drawMs + 0.1 * (performance.now() - t0);
  canvas.dataset.eventsDrawn = String(eventsDrawn);
  canvas.dataset.bodiesDrawn = String(n);
  canvas.dataset.drawMs = drawMs.toFixed(2);
  if (src.synced !== false && n > 0) {
    const what = past ? " · rewound" : frozen ? " · paused" : "";
    $("status").textContent = `tick ${src.tick} · ${n} bodies${what}`;
  }
  requestAnimationFrame(draw);
}

function touches(f, cls) {
  const a = live.bodies.get(f.a), b = live.bodies.get(f.b);
  return (a && a.info.class === cls) || (b && b.info.class === cls);
}

// --- input ----------------------------------------------------------------------------------

let drag = null;
canvas.addEventListener("mousedown", (ev) => { drag = { x: ev.clientX, y: ev.clientY, moved: false }; });
window.addEventListener("mouseup", (ev) => {
  if (drag && !drag.moved) pick(ev);
  drag = null;
});
window.addEventListener("mousemove", (ev) => {
  if (!drag) return;
  const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
  if (Math.abs(dx) + Math.abs(dy) > 2) drag.moved = true;
  cam.x -= dx / cam.scale;
  cam.z -= dy / cam.scale;
  drag.x = ev.clientX;
  drag.y = ev.clientY;
});
canvas.addEventListener("wheel", (ev) => {
  ev.preventDefault();
  const r = canvas.getBoundingClientRect();
  const [wx, wz] = toWorld(ev.clientX - r.left, ev.clientY - r.top, r);
  cam.scale *= Math.exp(-ev.deltaY * 0.0015);
  const [nx, nz] = toWorld(ev.clientX - r.left, ev.clientY - r.top, r);
  cam.x += wx - nx;
  cam.z += wz - nz;
}, { passive: false });

function pick(ev) {
  const r = canvas.getBoundingClientRect();
  const [x, z] = toWorld(ev.clientX - r.left, ev.clientY - r.top, r);
  let best = null, bestD = Infinity;
  const src = shown();
  for (const [e, b] of src.bodies) {
    if (b.info.fixed) continue;
    const p = placed(b, src);
    const d = Math.hypot(p[0] - x, p[2] - z) - b.info.half_extents_m[0];
    if (d < bestD) { bestD = d; best = e; }
  }
  selected = bestD < 1.0 ? best : null;
  listSelected();
}

function listSelected() {
  const list = $("sel-events");
  if (selected === null) { $("selected").textContent = "click a body"; list.replaceChildren(); return; }
  const b = shown().bodies.get(selected) || live.bodies.get(selected);
  $("selected").textContent = b
    ? `entity ${selected} · ${b.info.class}${b.info.owner !== null ? ` · client ${b.info.owner}` : ""} · ` +
      `(${placed(b, shown().bodies.has(selected) ? shown() : live).map((v) => v.toFixed(1)).join(", ")})` +
      `${b.asleep ? " · asleep" : ""}`
    : `entity ${selected} (gone)`;
  const items = [];
  for (let k = recent.length - 1; k >= 0 && items.length < 40; k--) {
    const e = recent[k];
    if (e.a !== selected && e.b !== selected) continue;
    const li = document.createElement("li");
    li.className = e.status;
    li.textContent = `tick ${e.tick} +${e.toi.toFixed(3)} ${e.phase} with ${e.a === selected ? e.b : e.a} · ${e.status}`;
    items.push(li);
  }
  list.replaceChildren(...items);
}

$("pause").addEventListener("click", () => {
  if (frozen) {
    frozen = null;
    past = null;
    $("pause").textContent = "Pause";
    $("scrub").disabled = true;
    $("scrub").value = 0;
    $("scrub-label").textContent = "live";
    return;
  }
  const copy = new Map();
  for (const [e, b] of live.bodies) copy.set(e, { info: b.info, p: placed(b, live), v: b.v.slice(), asleep: b.asleep });
  frozen = { bodies: copy, tick: live.tick, synced: true };
  $("pause").textContent = "Resume";
  $("scrub").value = 0;
  $("scrub").disabled = false;
  $("scrub-label").textContent = `tick ${frozen.tick}`;
});

// Rewinding: the server's state query at a tick inside its rollback window.
let scrubSeq = 0;
$("scrub").addEventListener("input", async () => {
  if (!frozen) return;
  const back = -Number($("scrub").value);
  if (back === 0) { past = null; $("scrub-label").textContent = `tick ${frozen.tick}`; return; }
  // The server keeps only its rollback window, which moves on while the page is paused: count
  // back from the newest tick the stream has told of.
  let tick = live.tick - back;
  const seq = ++scrubSeq;
  const query = (t) => fetch(`/api/state?tick=${t}`).then((r) => r.json()).catch((e) => ({ type: "query_error", detail: String(e) }));
  let answer = await query(tick);
  // The stream lags the server (a frame every 50 ms, more under load): when that tick has left
  // the window already, count back once more from the present the server's answer names.
  const gone = answer.type !== "snapshot" && /oldest (\d+), now (\d+)/.exec(answer.detail || "");
  if (gone && tick < Number(gone[1])) {
    tick = Number(gone[2]) - back;
    answer = await query(tick);
  }
  if (seq !== scrubSeq || !frozen) return;
  if (answer.type === "snapshot") {
    const bodies = new Map();
    // The query has every dynamic body; the static ones do not move.
    for (const [e, b] of frozen.bodies) if (b.info.fixed) bodies.set(e, b);
    for (const s of answer.bodies) {
      const known = frozen.bodies.get(s.entity) || live.bodies.get(s.entity);
      const info = known ? known.info : { entity: s.entity, class: s.class, owner: s.owner, shape: "sphere",
        half_extents_m: [0.5, 0.5, 0.5], offset_m: [0, 0, 0], fixed: false };
      bodies.set(s.entity, { info, p: s.position, v: s.velocity, asleep: false });
    }
    past = { bodies, tick: answer.tick, synced: true };
    $("scrub-label").textContent = `tick ${answer.tick} (${back} back from ${tick + back})`;
  } else {
    // "... outside the history (oldest A, now B)": let the slider reach no further than that.
    const held = /oldest (\d+), now (\d+)/.exec(answer.detail || "");
    if (held) $("scrub").min = String(-Math.max(1, Number(held[2]) - Number(held[1]) - 2));
    $("scrub-label").textContent = answer.detail || "no answer";
  }
});

$("f-entity").addEventListener("input", (ev) => {
  const v = ev.target.value.trim();
  filters.entity = v === "" ? null : Number(v);
});
$("f-class").addEventListener("change", (ev) => { filters.cls = ev.target.value; });
$("f-phase").addEventListener("change", (ev) => { filters.phase = ev.target.value; });

// --- the stream -----------------------------------------------------------------------------

function connect() {
  const es = new EventSource("/stream");
  es.onopen = () => { $("conn").textContent = ""; };
  es.onmessage = (m) => onMessage(JSON.parse(m.data));
  es.onerror = () => { $("conn").textContent = "reconnecting…"; };
}

connect();
requestAnimationFrame(draw);
