// lightsim view: the page. Plain JS, no libraries; frames are zlib-compressed uint16 log
// codes (see lightsim/view/encode.py) decompressed with the browser's DecompressionStream.
"use strict";

const V = window.lightsimView = {
  client: null, framesDrawn: 0, wallFrames: 0, cameraFrames: 0, latencies: [], drawMs: [], sentAt: {},
  token: 0, status: null, regulation: null, messages: [], lastHeader: null, plotRect: null,
  lastWallHeader: null,
  connected: false, reconnects: 0, hello: null,
};
const $ = (id) => document.getElementById(id);
const MARGIN = { left: 48, right: 86, top: 10, bottom: 34 };
const DISPLAY_DECADES = 4;
const ISOLUX = [0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500];
let ws = null, backoff = 250, tab = "wall";
let pending = { wall: null, camera: null }, busy = { wall: false, camera: false };
let lastWall = null;

// ---- colour map: black → blue → red → yellow → white (luminance rises monotonically) ----
const STOPS = [[0, 0, 0, 0], [0.25, 40, 0, 120], [0.5, 200, 30, 30], [0.75, 250, 200, 40],
  [1, 255, 255, 255]];
const LUT = new Uint8ClampedArray(256 * 3);
for (let i = 0; i < 256; i++) {
  const t = i / 255;
  let k = 0;
  while (k < STOPS.length - 2 && t > STOPS[k + 1][0]) k++;
  const a = STOPS[k], b = STOPS[k + 1], u = (t - a[0]) / (b[0] - a[0]);
  for (let c = 0; c < 3; c++) LUT[3 * i + c] = a[c + 1] + u * (b[c + 1] - a[c + 1]);
}

// ---- messages --------------------------------------------------------------------------
function showMessage(level, text) {
  const m = $("message");
  m.className = level;
  m.textContent = text;
  V.messages.push({ level, text, t: performance.now() });
}

// ---- connection (reconnects on its own: the session lives on the server) ---------------
function connect() {
  ws = new WebSocket(`ws://${location.host}/ws`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => {
    backoff = 250; V.connected = true;
    $("conn").textContent = "connected"; $("conn").className = "conn";
    if (tab === "camera") send({ type: "view", tab });
  };
  ws.onclose = () => {
    V.connected = false; V.reconnects++;
    $("conn").textContent = "connection lost: reconnecting…"; $("conn").className = "conn down";
    setTimeout(connect, backoff); backoff = Math.min(4000, backoff * 2);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") onJson(JSON.parse(ev.data));
    else onBinary(ev.data);
  };
}
function send(obj) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(obj)); }

function onJson(msg) {
  if (msg.type === "hello") { V.client = msg.client; V.hello = msg; buildControls(msg); }
  else if (msg.type === "controls") setControlValues(msg.controls);
  else if (msg.type === "status") showStatus(msg);
  else if (msg.type === "regulation") showRegulation(msg);
  else if (msg.type === "message") showMessage(msg.level, msg.text);
}

// ---- controls --------------------------------------------------------------------------
function buildControls(hello) {
  $("scene").textContent = hello.scene;
  const box = $("controls");
  box.innerHTML = "";
  for (const s of hello.specs) {
    const row = document.createElement("div");
    row.className = "ctl";
    const unit = s.unit ? ` (${s.unit})` : "";
    row.innerHTML = `<label for="r-${s.name}">${s.label}${unit}</label>` +
      `<input type="range" id="r-${s.name}" min="${s.lo}" max="${s.hi}" step="${s.step}">` +
      ` <input type="text" id="t-${s.name}" name="${s.name}">`;
    box.appendChild(row);
    const r = row.querySelector("input[type=range]"), t = row.querySelector("input[type=text]");
    r.addEventListener("input", () => { t.value = r.value; setControl(s.name, Number(r.value)); });
    // the text box sends what was typed: the server checks it (NaN, range) and says why
    t.addEventListener("change", () => setControl(s.name, t.value));
  }
  const sel = $("bulb");
  sel.innerHTML = hello.bulbs.map((b) => `<option>${b}</option>`).join("");
  setControlValues(hello.controls);
  $("tab-camera").disabled = !hello.camera;
}
function setControlValues(c) {
  for (const [k, v] of Object.entries(c)) {
    const r = $(`r-${k}`), t = $(`t-${k}`);
    if (r) r.value = v;
    if (t) t.value = v;
  }
  if (c.bulb !== undefined) $("bulb").value = c.bulb;
}
function setControl(name, value) {
  const r = $(`r-${name}`), t = $(`t-${name}`);  // show what was sent (scripts, bench)
  if (r && typeof value === "number") r.value = value;
  if (t && document.activeElement !== t) t.value = value;
  const n = ++V.token;
  V.sentAt[n] = performance.now();
  send({ type: "set", changes: { [name]: value }, token: n });
  return n;
}
V.setControl = setControl;
V.dropConnection = () => ws && ws.close();  // tests/bench: a dropped connection must resume
$("bulb").addEventListener("change", () => setControl("bulb", $("bulb").value));
$("save").addEventListener("click", () => send({ type: "save" }));
$("upload").addEventListener("change", async () => {
  const f = $("upload").files[0];
  if (!f) return;
  try {
    const r = await fetch("/upload", { method: "POST", body: f });
    const j = await r.json();
    showMessage(j.level, j.text);
  } catch (e) { showMessage("error", `upload failed: ${e}`); }
  $("upload").value = "";
});
for (const b of document.querySelectorAll(".tab")) {
  b.addEventListener("click", () => {
    tab = b.dataset.tab;
    for (const o of document.querySelectorAll(".tab")) o.classList.toggle("active", o === b);
    $("wall").hidden = tab !== "wall"; $("camera").hidden = tab !== "camera";
    send({ type: "view", tab });
  });
}
$("isolux").addEventListener("change", () => lastWall && drawWall(lastWall));
$("points").addEventListener("change", () => lastWall && drawWall(lastWall));

// ---- status and regulation ---------------------------------------------------------------
function pct(x) { return x === null || x === undefined ? "–" : `${(100 * x).toFixed(1)} %`; }
function showStatus(s) {
  const stale = V.regulation && (!V.status || V.status.edit !== s.edit);
  V.status = s;
  if (stale) showRegulation(V.regulation);  // mark the table as older than the pattern
  const h = V.lastWallHeader;  // what is on the canvas may be older than the status
  const shown = h ? ` · showing ${h.quality === "pooled" ? "pooled map" :
    "interleaved frame"} of ${h.photons.toLocaleString("en")} photons` : "";
  $("mode").textContent = `${s.mode}${shown}`;
  $("error").textContent = pct(s.rel_error) + (s.error_source ? ` (${s.error_source}` +
    (s.error_photons ? ` at ${s.error_photons.toLocaleString("en")} photons)` : ")") : "");
  $("photons").textContent = s.photons.toLocaleString("en");
  $("frame_s").textContent = `${(1000 * s.frame_s).toFixed(0)} ms`;
  $("error_text").textContent = s.error_text || "";
}
function fmt(x) { return x === null || x === undefined ? "–" : Math.round(x).toLocaleString("en"); }
function showRegulation(r) {
  V.regulation = r;
  $("reg-title").textContent = `regulation: ${r.title}` +
    (r.unevaluated ? ` (${r.unevaluated} rules not evaluated)` : "") +
    (V.status && V.status.edit > r.edit ? " — before the last change" : "");
  $("reg").querySelector("tbody").innerHTML = r.rows.map((row) =>
    `<tr><td>${row.name}</td><td>${row.limit}</td><td>${fmt(row.value)}</td>` +
    `<td>${row.interval ? fmt(row.interval[0]) + " … " + fmt(row.interval[1]) : "–"}</td>` +
    `<td class="${row.verdict}">${row.verdict}</td>` +
    `<td class="${row.decided ? "decided" : "open"}">${row.decided ? "decided" : "open"}</td></tr>`
  ).join("");
  if (lastWall) drawWall(lastWall);
}

// ---- frames ------------------------------------------------------------------------------
function onBinary(buf) {
  const dv = new DataView(buf);
  const n = dv.getUint32(4, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 8, n)));
  const kind = head.kind;
  pending[kind] = { head, payload: new Uint8Array(buf, 8 + n), at: performance.now() };
  if (!busy[kind]) drain(kind);
}
async function drain(kind) {
  busy[kind] = true;
  while (pending[kind]) {  // only the newest waiting frame is drawn: a slow page skips
    const { head, payload, at } = pending[kind];
    pending[kind] = null;
    const t0 = performance.now();  // the page's share of a frame: inflate, decode, draw
    const stream = new Blob([payload]).stream().pipeThrough(new DecompressionStream("deflate"));
    // the page works on the codes themselves: they are logarithmic, so a colour or an
    // isolux level is a code threshold (no exp/log per pixel or per code value)
    const codes = new Uint16Array(await new Response(stream).arrayBuffer());
    const frame = { head, codes };
    if (kind === "wall") { lastWall = frame; drawWall(frame); V.wallFrames++; V.lastWallHeader = head; }
    else { drawCamera(frame); V.cameraFrames++; }
    V.framesDrawn++;
    V.lastHeader = head;
    if (kind === "wall") { V.drawMs.push(performance.now() - t0); if (V.drawMs.length > 1000) V.drawMs.shift(); }
    const tok = head.token || {};
    if (kind === "wall" && tok.client === V.client && tok.n) {
      const now = performance.now();
      for (const [k, t0] of Object.entries(V.sentAt)) {
        // ms: sent → drawn; arrived: sent → the frame's message received; draw: its share
        if (Number(k) <= tok.n) {
          V.latencies.push({ token: Number(k), ms: now - t0, arrived: at - t0, draw: now - at });
          delete V.sentAt[k];
        }
        if (V.latencies.length > 1000) V.latencies.shift();
      }
    }
  }
  busy[kind] = false;
}

// code c ≥ 1 ↔ lo·exp((c − 1)/65534 · ln(hi/lo)) (lightsim/view/encode.py); 0 = below lo
function codeOf(head, value) {
  return 1 + Math.log(value / head.lo) / Math.log(head.hi / head.lo) * 65534;
}

// the frame's pixels as RGBA (colour by code, isolux lines on top when asked): W·H
// table look-ups, the colour row of every code from a linear rule (the codes are log)
function paint(ctx, frame, x0, y0, s, levels = []) {
  const { head, codes } = frame, W = head.width, H = head.height;
  const hi = head.hi, lo = hi * Math.pow(10, -DISPLAY_DECADES), span = Math.log(hi / lo);
  const off = new OffscreenCanvas(W, H), octx = off.getContext("2d");
  const data = octx.createImageData(W, H);
  // display t = ln(v/lo)/span is linear in the code: t = a + b·(c − 1)
  const a = Math.log(head.lo / lo) / span, b = Math.log(head.hi / head.lo) / 65534 / span;
  const colour = new Uint16Array(65536);
  for (let c = 1; c < 65536; c++) {
    const t = a + b * (c - 1);
    colour[c] = Math.round((t > 0 ? Math.min(1, t) : 0) * 255) * 3;
  }
  const px = data.data;
  for (let i = 0; i < W * H; i++) {
    const j = colour[codes[i]];
    px[4 * i] = LUT[j]; px[4 * i + 1] = LUT[j + 1]; px[4 * i + 2] = LUT[j + 2];
    px[4 * i + 3] = 255;
  }
  if (levels.length) {  // iso-lux lines: pixels where the level index changes
    const thr = levels.map((l) => Math.ceil(codeOf(head, l)));
    const level = new Uint8Array(65536);
    for (let c = 1, k = 0; c < 65536; c++) { while (k < thr.length && c >= thr[k]) k++; level[c] = k; }
    for (let r = 0; r < H - 1; r++) for (let q = 0; q < W - 1; q++) {
      const i = r * W + q, k = level[codes[i]];
      if (k !== level[codes[i + 1]] || k !== level[codes[i + W]]) {
        // 80 % white over the colour, as the lines were drawn before
        for (let ch = 0; ch < 3; ch++) px[4 * i + ch] = 204 + 0.2 * px[4 * i + ch];
      }
    }
  }
  octx.putImageData(data, 0, 0);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(off, x0, y0, W * s, H * s);
  return { lo, hi, span };
}

function colourBar(ctx, x, y, h, lo, hi, unit) {
  const span = Math.log(hi / lo);
  for (let i = 0; i < h; i++) {
    const j = Math.round((1 - i / (h - 1)) * 255) * 3;
    ctx.fillStyle = `rgb(${LUT[j]},${LUT[j + 1]},${LUT[j + 2]})`;
    ctx.fillRect(x, y + i, 14, 1);
  }
  ctx.fillStyle = "#ddd"; ctx.font = "11px sans-serif";
  const first = Math.ceil(Math.log10(lo)), last = Math.floor(Math.log10(hi));
  for (let e = first; e <= last; e++) {
    const yy = y + (1 - Math.log(Math.pow(10, e) / lo) / span) * (h - 1);
    ctx.fillRect(x + 14, yy, 4, 1);
    ctx.fillText(Math.pow(10, e).toLocaleString("en", { maximumSignificantDigits: 3 }), x + 20, yy + 4);
  }
  ctx.fillText(unit, x, y + h + 14);
}

function drawWall(frame) {
  const c = $("wall"), ctx = c.getContext("2d");
  const { head } = frame, W = head.width, H = head.height, w = head.wall;
  const s = Math.min((c.width - MARGIN.left - MARGIN.right) / W, (c.height - MARGIN.top - MARGIN.bottom) / H);
  const x0 = MARGIN.left, y0 = MARGIN.top;
  ctx.fillStyle = "#111"; ctx.fillRect(0, 0, c.width, c.height);
  const lo0 = head.hi * Math.pow(10, -DISPLAY_DECADES);  // the colour scale's bottom
  const levels = $("isolux").checked ? ISOLUX.filter((l) => l > lo0 && l < head.hi) : [];
  const { lo, hi } = paint(ctx, frame, x0, y0, s, levels);
  V.plotRect = { x: x0, y: y0, w: W * s, h: H * s };
  const [h0, h1] = w.h_range_m, [v0, v1] = w.v_range_m, D = w.distance_m;
  const X = (hdeg) => x0 + (D * Math.tan(hdeg * Math.PI / 180) - h0) / (h1 - h0) * W * s;
  const Y = (vdeg) => y0 + (v1 - D * Math.tan(vdeg * Math.PI / 180)) / (v1 - v0) * H * s;
  // axes in degrees: H every 5°, V every 2°
  ctx.strokeStyle = "#888"; ctx.fillStyle = "#ccc"; ctx.font = "11px sans-serif";
  const hmin = Math.atan2(h0, D) * 180 / Math.PI, hmax = Math.atan2(h1, D) * 180 / Math.PI;
  const vmin = Math.atan2(v0, D) * 180 / Math.PI, vmax = Math.atan2(v1, D) * 180 / Math.PI;
  for (let hd = Math.ceil(hmin / 5) * 5; hd <= hmax; hd += 5) {
    const x = X(hd);
    ctx.fillRect(x, y0 + H * s, 1, 4); ctx.fillText(`${hd}°`, x - 8, y0 + H * s + 15);
  }
  for (let vd = Math.ceil(vmin / 2) * 2; vd <= vmax; vd += 2) {
    const y = Y(vd);
    ctx.fillRect(x0 - 4, y, 4, 1); ctx.fillText(`${vd}°`, x0 - 30, y + 4);
  }
  ctx.fillText("H (deg)", x0 + W * s / 2 - 20, y0 + H * s + 29);
  ctx.save(); ctx.translate(12, y0 + H * s / 2 + 20); ctx.rotate(-Math.PI / 2); ctx.fillText("V (deg)", 0, 0); ctx.restore();
  ctx.strokeStyle = "rgba(255,255,255,0.35)";  // H–H and V–V
  ctx.beginPath(); ctx.moveTo(x0, Y(0)); ctx.lineTo(x0 + W * s, Y(0)); ctx.moveTo(X(0), y0); ctx.lineTo(X(0), y0 + H * s); ctx.stroke();
  if ($("points").checked && V.regulation) {
    const col = { pass: "#3e3", fail: "#f33", uncertain: "#ee3" };
    for (const p of V.regulation.points) {
      ctx.fillStyle = col[p.verdict] || "#aaa"; ctx.strokeStyle = "#000";
      ctx.beginPath(); ctx.arc(X(p.h_deg), Y(p.v_deg), 4, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      ctx.fillStyle = "#fff"; ctx.fillText(p.name, X(p.h_deg) + 5, Y(p.v_deg) - 4);
    }
  }
  colourBar(ctx, x0 + W * s + 12, y0, H * s, lo, hi, "lx");
}

function drawCamera(frame) {
  const c = $("camera"), ctx = c.getContext("2d");
  const W = frame.head.width, H = frame.head.height;
  const s = Math.min((c.width - MARGIN.right - 10) / W, (c.height - 36) / H);
  ctx.fillStyle = "#111"; ctx.fillRect(0, 0, c.width, c.height);
  const { lo, hi } = paint(ctx, frame, 10, 10, s);
  colourBar(ctx, 10 + W * s + 12, 10, H * s, lo, hi, "cd/m²");
}

connect();
