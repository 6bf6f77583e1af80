// The provenance panel (lightsim/view/provenance_panel.py): the run's screen as coarse
// cells; a click picks the cell under it, a drag a box of cells; the server splits the
// region's light by path class and draws the lamp picture of the same box.
"use strict";

const canvas = document.getElementById("screen");
const ctx = canvas.getContext("2d");
const statusEl = document.getElementById("status");
const SCALE = 8; // canvas pixels per cell
const prov = { ready: false, breakdowns: 0, lamps: 0, last: null, error: null, box: null };
window.prov = prov;

function colour(t) { // black → red → yellow → white
  const r = Math.min(1, 3 * t), g = Math.min(1, Math.max(0, 3 * t - 1)),
    b = Math.min(1, Math.max(0, 3 * t - 2));
  return `rgb(${Math.round(255 * r)},${Math.round(255 * g)},${Math.round(255 * b)})`;
}

function cellAt(e) {
  const r = canvas.getBoundingClientRect();
  const nc = prov.screen.h_edges_deg.length - 1, nr = prov.screen.v_edges_deg.length - 1;
  const c = Math.floor(((e.clientX - r.left) / r.width) * nc);
  const w = Math.floor(((e.clientY - r.top) / r.height) * nr);
  return [Math.min(nc - 1, Math.max(0, c)), Math.min(nr - 1, Math.max(0, w))];
}

function draw(sel) {
  const s = prov.screen, nr = s.lx.length, nc = s.lx[0].length;
  const top = Math.log10(Math.max(s.max_lx, 1e-9));
  for (let i = 0; i < nr; i++) {
    for (let j = 0; j < nc; j++) {
      const v = s.lx[i][j];
      const t = v > 0 ? Math.max(0, (Math.log10(v) - top + 3) / 3) : 0;
      ctx.fillStyle = colour(Math.min(1, t));
      ctx.fillRect(j * SCALE, i * SCALE, SCALE, SCALE);
    }
  }
  // H-V cross
  const he = s.h_edges_deg, ve = s.v_edges_deg;
  const x0 = ((0 - he[0]) / (he[nc] - he[0])) * nc * SCALE;
  const y0 = ((ve[0] - 0) / (ve[0] - ve[nr])) * nr * SCALE;
  ctx.strokeStyle = "#4af"; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(x0, 0); ctx.lineTo(x0, canvas.height);
  ctx.moveTo(0, y0); ctx.lineTo(canvas.width, y0); ctx.stroke();
  if (sel) {
    const [c0, c1, r0, r1] = sel;
    ctx.strokeStyle = "#0f0"; ctx.lineWidth = 2;
    ctx.strokeRect(c0 * SCALE, r0 * SCALE, (c1 - c0 + 1) * SCALE, (r1 - r0 + 1) * SCALE);
  }
}

function boxOf(sel) { // the cells' box, a quarter cell inside their edges (deg)
  const [c0, c1, r0, r1] = sel, he = prov.screen.h_edges_deg, ve = prov.screen.v_edges_deg;
  return [he[c0] + 0.25 * (he[c0 + 1] - he[c0]), he[c1 + 1] - 0.25 * (he[c1 + 1] - he[c1]),
    ve[r1 + 1] + 0.25 * (ve[r1] - ve[r1 + 1]), ve[r0] - 0.25 * (ve[r0] - ve[r0 + 1])];
}

function fmt(x) { return Math.abs(x) < 1e4 ? x.toPrecision(4) : Math.round(x).toLocaleString(); }

function show(b) {
  const [h0, h1, v0, v1] = b.covered_deg;
  document.getElementById("title").textContent =
    `H ${h0.toFixed(2)}..${h1.toFixed(2)}°, V ${v0.toFixed(2)}..${v1.toFixed(2)}°: ` +
    `${fmt(b.value_lx)} lx [${fmt(b.interval_lx[0])}, ${fmt(b.interval_lx[1])}], ` +
    `classes add up to ${fmt(b.sum_lx)} lx`;
  const t = document.getElementById("classes");
  t.innerHTML = "";
  const head = t.insertRow();
  for (const h of ["path class", "lx", "interval (lx)", "share"]) {
    const th = document.createElement("th"); th.textContent = h; head.appendChild(th);
  }
  for (const c of b.classes) {
    const row = t.insertRow();
    row.className = "class-row";
    const name = c.class + (c.classes ? ` (${c.classes} classes)` : "");
    for (const text of [name, fmt(c.value_lx),
      `[${fmt(c.interval_lx[0])}, ${fmt(c.interval_lx[1])}]`,
      (100 * c.share).toFixed(1) + " %"]) {
      row.insertCell().textContent = text;
    }
  }
}

async function ask(sel) {
  draw(sel);
  const box = boxOf(sel).map((x) => x.toFixed(6)).join(",");
  prov.box = box;
  statusEl.textContent = "breaking the region down…";
  statusEl.className = "";
  const r = await fetch(`breakdown?box=${box}`);
  const b = await r.json();
  if (!r.ok) {
    prov.error = b.text; statusEl.textContent = b.text; statusEl.className = "error";
    return;
  }
  prov.last = b; prov.error = null; prov.breakdowns += 1;
  show(b);
  statusEl.textContent = `${b.classes.length} path classes over ${b.sets} interleave sets`;
  const img = document.getElementById("lamp");
  img.onload = () => { prov.lamps += 1; };
  img.src = `lamp.png?box=${box}`;
}

let start = null;
canvas.addEventListener("pointerdown", (e) => { start = cellAt(e); });
canvas.addEventListener("pointermove", (e) => {
  if (!start) return;
  const [c, w] = cellAt(e);
  draw([Math.min(start[0], c), Math.max(start[0], c), Math.min(start[1], w),
    Math.max(start[1], w)]);
});
window.addEventListener("pointerup", (e) => {
  if (!start) return;
  const [c, w] = cellAt(e);
  const sel = [Math.min(start[0], c), Math.max(start[0], c), Math.min(start[1], w),
    Math.max(start[1], w)];
  start = null;
  ask(sel);
});

async function load() {
  prov.screen = await (await fetch("screen")).json();
  const nc = prov.screen.h_edges_deg.length - 1, nr = prov.screen.v_edges_deg.length - 1;
  canvas.width = nc * SCALE; canvas.height = nr * SCALE;
  canvas.style.width = Math.min(1280, nc * SCALE) + "px";
  draw(null);
  statusEl.textContent = `${prov.screen.run}: ${nc} × ${nr} cells; ` +
    `max ${fmt(prov.screen.max_lx)} lx`;
  prov.ready = true;
}
load();
