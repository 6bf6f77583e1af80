// The ADB panel: compose the per-source maps with the segments' levels (float32, in
// segment order, as lightsim.persource.compose does), draw them, and ask the server for the
// mask of the dragged road user. A segment is on (its level from the mask), off (0), or held
// at its dimming slider's level (0-1); off and held segments go to the server as fixed
// levels, so the mask works around them. window.adb exposes the state for tests.
"use strict";
const adb = window.adb = { ready: false, redraws: 0, masks: 0, lastRedrawMs: null,
                           levels: null, off: new Set(), held: new Map(), composed: null };
const canvas = document.getElementById("map");
const ctx = canvas.getContext("2d");
const status = document.getElementById("status");
const vehicle = { h_deg: -3.0 };

function fround32(x) { return Math.fround(x); }

function compose(levels) {
  const n = adb.width * adb.height;
  const out = new Float32Array(n);
  for (let g = 0; g < adb.names.length; g++) {
    const w = fround32(levels[g]);
    if (w === 0) continue;
    const m = adb.maps[g];
    if (w === 1) {
      for (let i = 0; i < n; i++) out[i] = out[i] + m[i];  // Float32Array stores round
    } else {
      for (let i = 0; i < n; i++) out[i] = out[i] + fround32(w * m[i]);
    }
  }
  return out;
}

function effectiveLevels() {
  return adb.levels.map((w, g) => {
    const name = adb.names[g];
    if (adb.off.has(name)) return 0;
    return adb.held.has(name) ? fround32(adb.held.get(name)) : w;
  });
}

function colour(t) {  // t in [0, 1] → a dark-to-bright ramp
  const r = Math.min(255, Math.round(255 * Math.min(1, 1.6 * t)));
  const g = Math.round(255 * Math.max(0, Math.min(1, 1.6 * t - 0.45)));
  const b = Math.round(255 * Math.max(0, Math.min(1, 2.5 * t - 1.5)) + 60 * (1 - t) * t);
  return [r, g, b];
}

function xOfH(h) {
  const [h0, h1] = adb.extent;
  return ((h - h0) / (h1 - h0)) * canvas.width;
}
function hOfX(x) {
  const [h0, h1] = adb.extent;
  return h0 + (x / canvas.width) * (h1 - h0);
}
function yOfV(v) {
  const [, , v0, v1] = adb.extent;
  return ((v1 - v) / (v1 - v0)) * canvas.height;
}

function draw(t0) {
  const lv = effectiveLevels();
  const lux = compose(lv);
  adb.composed = lux;
  adb.composedLevels = lv;
  const img = ctx.createImageData(adb.width, adb.height);
  const top = Math.log10(Math.max(adb.maxLx, 1e-9));
  for (let i = 0; i < lux.length; i++) {
    const t = lux[i] > 0 ? Math.max(0, (Math.log10(lux[i]) - top + 3) / 3) : 0;
    const [r, g, b] = colour(Math.min(1, t));
    img.data[4 * i] = r; img.data[4 * i + 1] = g; img.data[4 * i + 2] = b;
    img.data[4 * i + 3] = 255;
  }
  ctx.putImageData(img, 0, 0);
  drawVehicle();
  requestAnimationFrame(() => {  // drawn: the next frame shows it
    adb.lastRedrawMs = performance.now() - t0;
    adb.redraws += 1;
  });
}

function drawVehicle() {
  const d = Number(document.getElementById("distance").value);
  const w = Math.atan2(0.9, d) * 180 / Math.PI;
  const hm = 0.65;
  const x0 = xOfH(vehicle.h_deg - w), x1 = xOfH(vehicle.h_deg + w);
  const y0 = yOfV(Math.atan2(1.5 - hm, d) * 180 / Math.PI);
  const y1 = yOfV(Math.atan2(-hm, d) * 180 / Math.PI);
  ctx.strokeStyle = "cyan";
  ctx.lineWidth = 1;
  ctx.strokeRect(x0, y0, Math.max(2, x1 - x0), Math.max(2, y1 - y0));
}

function renderSegments() {  // once: a toggle and a dimming slider per segment
  const box = document.getElementById("segments");
  box.innerHTML = "";
  adb.names.forEach((name) => {
    const cell = document.createElement("span");
    cell.className = "seg";
    const b = document.createElement("button");
    b.id = "seg-" + name;
    b.innerHTML = `${name} <span class="lvl"></span>`;
    b.title = "on/off";
    b.addEventListener("click", () => toggle(name));
    const s = document.createElement("input");
    Object.assign(s, { type: "range", min: "0", max: "1", step: "0.01", id: "dim-" + name });
    s.title = "dimming level (0-1), held; double-click: back to the mask's level";
    s.addEventListener("input", () => dim(name, Number(s.value)));
    s.addEventListener("dblclick", () => release(name));
    cell.append(b, s);
    box.appendChild(cell);
  });
  updateSegments();
}

function updateSegments() {  // the shown levels; a slider being dragged keeps its value
  const lv = effectiveLevels();
  adb.names.forEach((name, g) => {
    const b = document.getElementById("seg-" + name);
    b.className = adb.off.has(name) ? "off" : adb.held.has(name) ? "held" : "";
    b.querySelector(".lvl").textContent = lv[g].toFixed(2);
    const s = document.getElementById("dim-" + name);
    if (!adb.held.has(name)) s.value = String(lv[g]);
  });
}

function toggle(name) {
  const t0 = performance.now();
  if (adb.off.has(name)) adb.off.delete(name); else adb.off.add(name);
  draw(t0);  // re-composed at once; the new mask follows from the server
  updateSegments();
  requestMask();
}

function dim(name, level) {
  const t0 = performance.now();
  adb.held.set(name, Math.min(1, Math.max(0, level)));
  draw(t0);  // the weighted sum with the slider's level, before the server answers
  updateSegments();
  requestMask();
}

function release(name) {
  adb.held.delete(name);
  draw(performance.now());
  updateSegments();
  requestMask();
}

let pending = null, inflight = false;
function requestMask() {
  pending = {
    vehicles: [{ kind: document.getElementById("kind").value,
                 distance_m: Number(document.getElementById("distance").value),
                 h_deg: vehicle.h_deg }],
    fixed: Object.fromEntries([...adb.held, ...[...adb.off].map((n) => [n, 0])]),
  };
  if (!inflight) sendMask();
}

async function sendMask() {
  if (!pending) return;
  const body = JSON.stringify(pending);
  pending = null;
  inflight = true;
  try {
    const r = await fetch("mask", { method: "POST", body,
                                    headers: { "content-type": "application/json" } });
    const res = await r.json();
    if (!r.ok) { status.textContent = res.text; return; }
    adb.levels = Float32Array.from(res.levels_list);
    adb.lastMask = res;
    adb.masks += 1;
    draw(performance.now());
    updateSegments();
    showVerdicts(res);
  } finally {
    inflight = false;
    if (pending) sendMask();
  }
}

function showVerdicts(res) {
  const lines = res.positions.map((p) =>
    `<span class="${p.verdict}">${p.position}: ${p.cd.toFixed(0)} cd ` +
    `[${p.interval_cd[0].toFixed(0)}, ${p.interval_cd[1].toFixed(0)}] ≤ ${p.max_cd} ` +
    `(${p.line}) ${p.verdict}</span>`);
  res.residual.forEach((r) => lines.push(
    `residual in the outline: ${r.mean_cd.toFixed(0)} cd [${r.interval_cd[0].toFixed(0)}, ` +
    `${r.interval_cd[1].toFixed(0)}]`));
  document.getElementById("verdicts").innerHTML = lines.join("\n");
  status.textContent = adb.lastRedrawMs === null ? "" :
    `last redraw ${adb.lastRedrawMs.toFixed(1)} ms after the input`;
}

let dragging = false;
canvas.addEventListener("pointerdown", (e) => { dragging = true; moveTo(e); });
canvas.addEventListener("pointermove", (e) => { if (dragging) moveTo(e); });
window.addEventListener("pointerup", () => { dragging = false; });
function moveTo(e) {
  const r = canvas.getBoundingClientRect();
  vehicle.h_deg = hOfX((e.clientX - r.left) * canvas.width / r.width);
  draw(performance.now());
  requestMask();
}
document.getElementById("distance").addEventListener("input", (e) => {
  document.getElementById("distance-text").textContent = e.target.value + " m";
  requestMask();
});
document.getElementById("kind").addEventListener("change", requestMask);

async function load() {
  const buf = await (await fetch("maps")).arrayBuffer();
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  adb.names = head.names; adb.width = head.width; adb.height = head.height;
  adb.extent = head.extent_deg; adb.maxLx = head.max_lx;
  const px = head.width * head.height;
  adb.maps = head.names.map((_, g) => new Float32Array(buf, 4 + n + 4 * g * px, px));
  adb.levels = new Float32Array(head.names.length).fill(1);
  canvas.width = head.width; canvas.height = head.height;
  canvas.style.width = Math.min(1280, 2 * head.width) + "px";
  renderSegments();
  draw(performance.now());
  status.textContent = `${head.names.length} segments, ${head.photons.toLocaleString()} photons`;
  adb.ready = true;
  requestMask();
}
load();
