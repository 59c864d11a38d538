"use strict";
// smooth-attention viewer: reads the description (#viewer-data) and the packed arrays
// (#viewer-blob) of this page, decodes them and draws scenes, predictions and attention on
// canvases. Plain JavaScript, no libraries, no network. Layout of the arrays: the Python module
// pipeline/viewer/content.py; the view transform: docs/VIEWER.md.

const PAD_PX = 24; // free border around a scene's box [CSS px]
const MIN_EXTENT_M = 10; // a box narrower than this is widened around its centre [m]
const DOT_PX = 5; // radius of an agent drawn as a dot (data without a road) [CSS px]
const EDGE_MAX_PX = 14; // width of an attention edge of weight 1 [CSS px]
const PRED_COLOR = "#ff7f0e";
const EDGE_COLOR = "rgba(255, 176, 0, 0.8)";
const SELECT_COLOR = "#ffd400";
const OUTLINE_COLOR = "#111111";
const GRASS_COLOR = "#608050";
const ROAD_COLOR = "#46464a";
const MARKING_COLOR = "#ebebeb";
const PLAIN_COLOR = "#f4f4f4";
const GRID_COLOR = "#e2e2e2";
const INTERACTION_COLOR = "rgba(242, 215, 166, 0.7)";
const CURVE_COLORS = ["#1f77b4", "#d62728", "#9467bd", "#17becf", "#bcbd22"];
const MAX_CURVES = 4;
const UNIT_STEPS = 65534; // attention codes: weight = code / UNIT_STEPS; NAN_CODE: none
const NAN_CODE = 65535;
const TYPED = { float32: Float32Array, uint16: Uint16Array, int16: Int16Array, uint8: Uint8Array, int8: Int8Array };

// ---------------------------------------------------------------------------- decoding
function base64Bytes(text) {
  if (typeof Uint8Array.fromBase64 === "function") return Uint8Array.fromBase64(text);
  const chars = atob(text);
  const bytes = new Uint8Array(chars.length);
  for (let i = 0; i < chars.length; i++) bytes[i] = chars.charCodeAt(i);
  return bytes;
}

async function decodeArrays(header, blobText) {
  if (typeof DecompressionStream !== "function") {
    throw new Error("this browser cannot inflate the page's data (it needs DecompressionStream: " +
      "Chrome 80, Firefox 113, Safari 16.4 or later)");
  }
  const stream = new Blob([base64Bytes(blobText.trim())]).stream()
    .pipeThrough(new DecompressionStream("deflate"));
  const buffer = await new Response(stream).arrayBuffer();
  const arrays = {};
  for (const [name, entry] of Object.entries(header)) {
    const count = entry.shape.reduce((a, b) => a * b, 1);
    arrays[name] = { data: new TYPED[entry.type](buffer, entry.offset, count), shape: entry.shape };
  }
  return arrays;
}

// ---------------------------------------------------------------------------- small helpers
function el(tag, attrs = {}, text = "") {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, value);
  if (text) node.textContent = text;
  return node;
}

function fmt(value, digits = 3) {
  return value === null || value === undefined || Number.isNaN(value) ? "\u2013" : value.toFixed(digits);
}

function sizeCanvas(canvas) {
  // backing store in device pixels, drawing in CSS pixels
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth, height = canvas.clientHeight;
  if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  return { ctx, width, height };
}

// ---------------------------------------------------------------------------- the viewer
class Viewer {
  constructor(spec, arrays) {
    this.spec = spec;
    this.a = arrays;
    this.n = spec.shown;
    this.T = spec.num_steps;
    this.N = spec.num_agents;
    this.P = spec.num_steps - spec.num_observed;
    this.S = arrays.samples ? arrays.samples.shape[1] : 0;
    this.scene = 0;
    this.step = spec.num_observed - 1;
    this.selected = -1;
    this.playing = false;
    this.zoom = 1;
    this.pan = [0, 0];
    this.sort = { key: "index", descending: false };
    this.layers = { history: true, future: true, prediction: true, samples: true, edges: true, numbers: true, all: false };
    this.canvas = document.getElementById("scene-canvas");
    this.curve = document.getElementById("curve-canvas");
    this.slider = document.getElementById("slider");
  }

  // ---- array access (row-major, as numpy wrote them)
  valid(s, t, i) { return this.a.valid.data[(s * this.T + t) * this.N + i] === 1; }
  x(s, t, i) { return this.a.xy.data[((s * this.T + t) * this.N + i) * 2]; }
  y(s, t, i) { return this.a.xy.data[((s * this.T + t) * this.N + i) * 2 + 1]; }
  role(s, i) { return this.a.roles.data[s * this.N + i]; }
  focal(s, i) { return this.a.focal.data[s * this.N + i] === 1; }
  label(s, t, i) { return this.a.label.data[(s * this.T + t) * this.N + i]; }
  interaction(s, t) { return this.a.interaction.data[s * this.T + t] === 1; }
  predicted(s, i) { return this.valid(s, this.spec.num_observed - 1, i); }
  predX(s, k, i) { return this.a.pred.data[((s * this.P + k) * this.N + i) * 2]; }
  predY(s, k, i) { return this.a.pred.data[((s * this.P + k) * this.N + i) * 2 + 1]; }
  hasAttention() { return Boolean(this.a.attention); }
  weight(s, t, i, j) { // attention of i on j computed at step t; NaN where none
    if (!this.a.attention || t >= this.T - 1) return NaN;
    const code = this.a.attention.data[((s * (this.T - 1) + t) * this.N + i) * this.N + j];
    return code === NAN_CODE ? NaN : code / UNIT_STEPS;
  }
  heading(s, t, i) {
    if (this.a.heading) return this.a.heading.data[(s * this.T + t) * this.N + i];
    for (const [u, v] of [[t, t + 1], [t - 1, t]]) { // direction of motion where there is one
      if (u >= 0 && v < this.T && this.valid(s, u, i) && this.valid(s, v, i)) {
        const dx = this.x(s, v, i) - this.x(s, u, i), dy = this.y(s, v, i) - this.y(s, u, i);
        if (Math.hypot(dx, dy) > 1e-3) return Math.atan2(dy, dx);
      }
    }
    return 0;
  }
  roleName(s, i) { return this.spec.role_names[this.role(s, i)]; }
  roleColor(s, i) { return this.spec.role_colors[this.role(s, i)]; }

  // ---- the view transform: the scene's box fitted in the canvas, then zoom and pan
  box(s) {
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (let t = 0; t < this.T; t++) {
      for (let i = 0; i < this.N; i++) {
        if (!this.valid(s, t, i)) continue;
        const x = this.x(s, t, i), y = this.y(s, t, i);
        x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
      }
    }
    if (!Number.isFinite(x0)) { x0 = 0; x1 = 0; y0 = 0; y1 = 0; }
    const road = this.spec.road;
    if (road && !road.lanes) { y0 = Math.min(y0, 0); y1 = Math.max(y1, road.num_lanes * road.lane_width_m); }
    const widen = (lo, hi) => (hi - lo >= MIN_EXTENT_M ? [lo, hi] : [(lo + hi - MIN_EXTENT_M) / 2, (lo + hi + MIN_EXTENT_M) / 2]);
    [x0, x1] = widen(x0, x1);
    [y0, y1] = widen(y0, y1);
    return { x0, x1, y0, y1 };
  }
  view(width, height) {
    const b = this.box(this.scene);
    const fit = Math.min((width - 2 * PAD_PX) / (b.x1 - b.x0), (height - 2 * PAD_PX) / (b.y1 - b.y0));
    return { k: fit * this.zoom, cx: (b.x0 + b.x1) / 2, cy: (b.y0 + b.y1) / 2, width, height, pan: this.pan };
  }
  static toPixel(v, x, y) {
    return [v.width / 2 + v.pan[0] + (x - v.cx) * v.k, v.height / 2 + v.pan[1] - (y - v.cy) * v.k];
  }

  // ---- building the page
  start() {
    this.fillHeader();
    this.buildToggles();
    this.buildLegend();
    this.buildScenes();
    this.slider.max = String(this.T - 1);
    this.bindControls();
    this.openScene(0);
    window.addEventListener("resize", () => this.draw());
  }

  fillHeader() {
    const spec = this.spec, src = spec.source;
    document.getElementById("title").textContent = spec.title;
    const parts = [`dataset ${src.data}`, `${src.split} split`, `${spec.shown} of ${spec.available} scenes`,
      `${spec.num_agents} agent slots`, `dt ${spec.dt} s`, `${spec.num_observed} observed steps of ${spec.num_steps}`];
    if (src.predictions) parts.push(`predictions ${src.predictions} (${src.predictor})`);
    else if (src.predictor) parts.push(`predictions of ${src.predictor}`);
    else parts.push("no predictions");
    document.getElementById("source").textContent = parts.join(" \u00b7 ");
    const head = document.getElementById("headline");
    head.textContent = spec.headline ? `over these scenes: ${spec.headline}` + (src.run ? ` \u00b7 ${src.run}` : "") : (src.run || "");
    if (spec.left_out) {
      const note = document.getElementById("left-out");
      note.hidden = false;
      note.textContent = `This page ${spec.left_out}.`;
    }
  }

  buildToggles() {
    const box = document.getElementById("toggles");
    const entries = [["history", "h", "observed history"], ["future", "f", "true future"]];
    if (this.a.pred) entries.push(["prediction", "p", "predicted mean"]);
    if (this.a.samples) entries.push(["samples", "s", "samples"]);
    if (this.a.attention) entries.push(["edges", "a", "attention edges"]);
    entries.push(["numbers", "n", "agent numbers"], ["all", "m", "trails of every agent (else main and chosen)"]);
    this.toggleKeys = {};
    for (const [layer, key, text] of entries) {
      const input = el("input", { type: "checkbox", id: `layer-${layer}` });
      input.checked = this.layers[layer];
      input.addEventListener("change", () => { this.layers[layer] = input.checked; this.draw(); });
      const label = el("label");
      label.append(input, ` [${key}] ${text}`);
      box.append(label);
      this.toggleKeys[key] = input;
    }
  }

  buildLegend() {
    const legend = document.getElementById("legend");
    this.spec.role_names.forEach((name, k) => {
      const swatch = el("span", { class: "swatch" });
      swatch.style.background = this.spec.role_colors[k];
      legend.append(swatch, name);
    });
    const keys = [["solid", "#333", "observed"], ["dashed", "#333", "true future"]];
    if (this.a.pred) keys.push(["solid", PRED_COLOR, "predicted mean (outline: at this step)"]);
    if (this.a.attention) keys.push(["solid", "#ffb000", "attention of the chosen car (width = weight)"]);
    for (const [style, color, text] of keys) {
      const line = el("span", { class: "line-key" });
      line.style.borderTopStyle = style;
      line.style.borderTopColor = color;
      legend.append(line, text);
    }
  }

  buildScenes() {
    const body = document.querySelector("#scenes tbody"), sc = this.spec.scenes;
    this.rows = [];
    for (let k = 0; k < this.n; k++) {
      const tr = el("tr", { "data-index": String(k) });
      const cells = [String(k), String(sc.row[k]), this.spec.case_names[sc.case[k]],
        fmt(sc.ade && sc.ade[k]), fmt(sc.fde && sc.fde[k]), fmt(sc.accuracy && sc.accuracy[k], 2)];
      for (const text of cells) tr.append(el("td", {}, text));
      tr.addEventListener("click", () => this.openScene(k));
      body.append(tr);
      this.rows.push(tr);
    }
    for (const th of document.querySelectorAll("#scenes th")) {
      th.addEventListener("click", () => this.sortBy(th.dataset.key));
    }
  }

  sortValue(key, k) {
    const sc = this.spec.scenes;
    if (key === "index") return k;
    if (key === "row") return sc.row[k];
    if (key === "case") return sc.case[k];
    return sc[key] ? sc[key][k] : null;
  }

  sortBy(key) {
    // a new column sorts worst first (largest error, lowest accuracy), a second click reverses;
    // scenes without a value go last, ties keep the file order
    const worstFirst = { ade: true, fde: true, accuracy: false };
    const descending = this.sort.key === key ? !this.sort.descending : Boolean(worstFirst[key]);
    this.sort = { key, descending };
    const order = [...Array(this.n).keys()].sort((p, q) => {
      const u = this.sortValue(key, p), v = this.sortValue(key, q);
      if (u === null || v === null) return (u === null) - (v === null) || p - q;
      return (descending ? v - u : u - v) || p - q;
    });
    const body = document.querySelector("#scenes tbody");
    for (const k of order) body.append(this.rows[k]);
    for (const th of document.querySelectorAll("#scenes th")) {
      th.classList.toggle("sorted-asc", th.dataset.key === key && !descending);
      th.classList.toggle("sorted-desc", th.dataset.key === key && descending);
    }
  }

  listOrder() { return [...document.querySelectorAll("#scenes tbody tr")].map((tr) => Number(tr.dataset.index)); }

  bindControls() {
    document.getElementById("play").addEventListener("click", (e) => { e.currentTarget.blur(); this.togglePlay(); });
    document.getElementById("back").addEventListener("click", (e) => { e.currentTarget.blur(); this.setStep(this.step - 1); });
    document.getElementById("forward").addEventListener("click", (e) => { e.currentTarget.blur(); this.setStep(this.step + 1); });
    this.slider.addEventListener("input", () => this.setStep(Number(this.slider.value)));
    document.addEventListener("keydown", (e) => this.onKey(e));
    this.bindMouse();
    this.curve.addEventListener("click", (e) => {
      const r = this.curve.getBoundingClientRect();
      const frame = this.curveFrame(r.width, r.height);
      this.setStep(Math.round((e.clientX - r.left - frame.left) / frame.dx));
    });
  }

  bindMouse() {
    let drag = null;
    this.canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: [...this.pan], moved: false }; });
    window.addEventListener("mousemove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
      if (Math.hypot(dx, dy) > 4) drag.moved = true;
      if (drag.moved) { this.pan = [drag.pan[0] + dx, drag.pan[1] + dy]; this.draw(); }
    });
    window.addEventListener("mouseup", (e) => {
      if (drag && !drag.moved) this.clickAt(e);
      drag = null;
    });
    this.canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      const r = this.canvas.getBoundingClientRect();
      this.zoomAt(e.deltaY < 0 ? 1.25 : 0.8, e.clientX - r.left, e.clientY - r.top);
    }, { passive: false });
  }

  zoomAt(factor, px, py) {
    // keep the world point under (px, py) where it is
    const r = this.canvas.getBoundingClientRect();
    const zoom = Math.min(64, Math.max(0.125, this.zoom * factor));
    const f = zoom / this.zoom;
    const ox = px - r.width / 2, oy = py - r.height / 2;
    this.pan = [ox - (ox - this.pan[0]) * f, oy - (oy - this.pan[1]) * f];
    this.zoom = zoom;
    this.draw();
  }

  clickAt(e) {
    const r = this.canvas.getBoundingClientRect();
    const px = e.clientX - r.left, py = e.clientY - r.top;
    const v = this.view(r.width, r.height);
    const reach = Math.max(12, this.spec.road ? this.spec.road.car_length_m * v.k / 2 : DOT_PX + 4);
    let best = -1, bestDistance = reach;
    for (let i = 0; i < this.N; i++) {
      if (!this.valid(this.scene, this.step, i)) continue;
      const [c, rr] = Viewer.toPixel(v, this.x(this.scene, this.step, i), this.y(this.scene, this.step, i));
      const d = Math.hypot(c - px, rr - py);
      if (d <= bestDistance) { best = i; bestDistance = d; }
    }
    this.select(best);
  }

  onKey(e) {
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    const big = e.shiftKey ? 10 : 1;
    const handled = {
      " ": () => this.togglePlay(),
      ArrowRight: () => this.setStep(this.step + big),
      ArrowLeft: () => this.setStep(this.step - big),
      Home: () => this.setStep(0),
      End: () => this.setStep(this.T - 1),
      ArrowDown: () => this.nextScene(1),
      ArrowUp: () => this.nextScene(-1),
      Escape: () => this.select(-1),
      0: () => { this.zoom = 1; this.pan = [0, 0]; this.draw(); },
      "+": () => this.zoomAt(1.25, this.canvas.clientWidth / 2, this.canvas.clientHeight / 2),
      "-": () => this.zoomAt(0.8, this.canvas.clientWidth / 2, this.canvas.clientHeight / 2),
    }[e.key];
    const toggle = this.toggleKeys[e.key.toLowerCase()];
    if (handled) handled();
    else if (toggle) { toggle.checked = !toggle.checked; toggle.dispatchEvent(new Event("change")); }
    else return;
    e.preventDefault();
  }

  nextScene(delta) {
    const order = this.listOrder();
    const at = order.indexOf(this.scene);
    const next = order[Math.min(order.length - 1, Math.max(0, at + delta))];
    this.openScene(next);
    this.rows[next].scrollIntoView({ block: "nearest" });
  }

  togglePlay() {
    this.playing = !this.playing;
    document.getElementById("play").textContent = this.playing ? "pause" : "play";
    if (!this.playing) return;
    if (this.step >= this.T - 1) this.setStep(0);
    let last = performance.now();
    const tick = (now) => {
      if (!this.playing) return;
      if (now - last >= this.spec.dt * 1000) {
        last = now;
        if (this.step >= this.T - 1) { this.togglePlay(); return; }
        this.setStep(this.step + 1);
      }
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  }

  openScene(k) {
    this.scene = k;
    this.selected = -1;
    this.zoom = 1;
    this.pan = [0, 0];
    for (const tr of this.rows) tr.classList.toggle("current", Number(tr.dataset.index) === k);
    this.setStep(this.spec.num_observed - 1);
  }

  select(i) { this.selected = i; this.draw(); }

  setStep(t) {
    this.step = Math.min(this.T - 1, Math.max(0, t));
    this.slider.value = String(this.step);
    const phase = this.step < this.spec.num_observed ? "observed" : "predicted";
    const inter = this.interaction(this.scene, this.step) ? ", interaction" : "";
    document.getElementById("clock").textContent =
      `t = ${(this.step * this.spec.dt).toFixed(2)} s, step ${this.step} of ${this.T - 1} (${phase}${inter})`;
    this.draw();
  }

  state() { return { scene: this.scene, step: this.step, selected: this.selected, order: this.listOrder() }; }

  // ---- drawing
  draw() {
    const { ctx, width, height } = sizeCanvas(this.canvas);
    const v = this.view(width, height);
    this.drawGround(ctx, v);
    this.drawTrails(ctx, v);
    this.drawEdges(ctx, v);
    this.drawAgents(ctx, v);
    this.drawScaleBar(ctx, v);
    this.fillAttentionPanel();
    this.drawCurve();
    this.drawInfluence();
  }

  drawGround(ctx, v) {
    const road = this.spec.road;
    ctx.fillStyle = road ? GRASS_COLOR : PLAIN_COLOR;
    ctx.fillRect(0, 0, v.width, v.height);
    if (!road) { this.drawGrid(ctx, v); return; }
    if (road.lanes) { this.drawLanes(ctx, v, road.lanes); return; }
    const top = road.num_lanes * road.lane_width_m;
    const [c0, r0] = Viewer.toPixel(v, 0, top), [c1, r1] = Viewer.toPixel(v, road.road_length_m, 0);
    ctx.fillStyle = ROAD_COLOR;
    ctx.fillRect(c0, r0, c1 - c0, r1 - r0);
    ctx.strokeStyle = MARKING_COLOR;
    ctx.lineWidth = Math.max(1, 0.15 * v.k);
    for (let lane = 0; lane <= road.num_lanes; lane++) {
      const y = lane * road.lane_width_m;
      const edge = lane === 0 || lane === road.num_lanes;
      ctx.setLineDash(edge ? [] : [3 * v.k, 6 * v.k]); // 3 m marks, 6 m gaps
      const [a, ra] = Viewer.toPixel(v, 0, y), [b] = Viewer.toPixel(v, road.road_length_m, y);
      ctx.beginPath(); ctx.moveTo(a, ra); ctx.lineTo(b, ra); ctx.stroke();
    }
    ctx.setLineDash([]);
  }

  // a junction layout: every lane is a polygon [x0, y0, x1, y1, ...] [m]; the road is their
  // union. Each outline is stroked wide in the marking colour, then all are filled: only the
  // union's boundary keeps a (half-width) edge line.
  drawLanes(ctx, v, lanes) {
    const trace = (flat) => {
      ctx.beginPath();
      for (let p = 0; p < flat.length; p += 2) {
        const [c, r] = Viewer.toPixel(v, flat[p], flat[p + 1]);
        if (p === 0) ctx.moveTo(c, r); else ctx.lineTo(c, r);
      }
      ctx.closePath();
    };
    ctx.strokeStyle = MARKING_COLOR;
    ctx.lineWidth = Math.max(2, 0.3 * v.k);
    ctx.lineJoin = "round";
    for (const flat of lanes) { trace(flat); ctx.stroke(); }
    ctx.fillStyle = ROAD_COLOR;
    for (const flat of lanes) { trace(flat); ctx.fill(); }
  }

  drawGrid(ctx, v) {
    const step = this.niceStep(80 / v.k);
    const [wx0, wy1] = this.toWorld(v, 0, 0), [wx1, wy0] = this.toWorld(v, v.width, v.height);
    ctx.strokeStyle = GRID_COLOR;
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let x = Math.ceil(wx0 / step) * step; x <= wx1; x += step) {
      const [c] = Viewer.toPixel(v, x, 0); ctx.moveTo(c, 0); ctx.lineTo(c, v.height);
    }
    for (let y = Math.ceil(wy0 / step) * step; y <= wy1; y += step) {
      const [, r] = Viewer.toPixel(v, 0, y); ctx.moveTo(0, r); ctx.lineTo(v.width, r);
    }
    ctx.stroke();
  }

  toWorld(v, c, r) { return [v.cx + (c - v.width / 2 - v.pan[0]) / v.k, v.cy - (r - v.height / 2 - v.pan[1]) / v.k]; }

  niceStep(metres) {
    const base = 10 ** Math.floor(Math.log10(metres));
    return [1, 2, 5, 10].map((m) => m * base).find((s) => s >= metres);
  }

  drawScaleBar(ctx, v) {
    const metres = this.niceStep(60 / v.k), px = metres * v.k;
    const x = 10, y = v.height - 10;
    ctx.fillStyle = "rgba(255, 255, 255, 0.85)";
    ctx.fillRect(x - 4, y - 18, px + 8, 22);
    ctx.strokeStyle = "#111"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(x, y - 3); ctx.lineTo(x + px, y - 3); ctx.stroke();
    ctx.fillStyle = "#111"; ctx.font = "11px system-ui, sans-serif";
    ctx.fillText(`${metres} m`, x, y - 7);
  }

  showsTrail(i) { return this.layers.all || this.focal(this.scene, i) || i === this.selected; }

  polyline(ctx, v, points) {
    // points: [x, y] or null for a gap
    let open = false;
    ctx.beginPath();
    for (const p of points) {
      if (!p) { open = false; continue; }
      const [c, r] = Viewer.toPixel(v, p[0], p[1]);
      if (open) ctx.lineTo(c, r); else { ctx.moveTo(c, r); open = true; }
    }
    ctx.stroke();
  }

  truePath(i, from, to) {
    const s = this.scene, points = [];
    for (let t = from; t <= to; t++) points.push(this.valid(s, t, i) ? [this.x(s, t, i), this.y(s, t, i)] : null);
    return points;
  }

  predictedPath(i, xs, ys) {
    // from the last observed position through the predicted steps where the agent is present
    const s = this.scene, obs = this.spec.num_observed, points = [[this.x(s, obs - 1, i), this.y(s, obs - 1, i)]];
    for (let k = 0; k < this.P; k++) points.push(this.valid(s, obs + k, i) ? [xs(k), ys(k)] : null);
    return points;
  }

  drawTrails(ctx, v) {
    const s = this.scene, obs = this.spec.num_observed;
    ctx.lineJoin = "round";
    for (let i = 0; i < this.N; i++) {
      if (!this.showsTrail(i)) continue;
      const color = this.roleColor(s, i);
      if (this.layers.history) {
        ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.setLineDash([]);
        this.polyline(ctx, v, this.truePath(i, 0, obs - 1));
      }
      if (this.layers.future) {
        ctx.strokeStyle = color; ctx.lineWidth = 1.5; ctx.setLineDash([6, 4]);
        this.polyline(ctx, v, this.truePath(i, obs - 1, this.T - 1));
        ctx.setLineDash([]);
      }
      if (!this.a.pred || !this.predicted(s, i)) continue;
      if (this.a.samples && this.layers.samples) {
        const d = this.a.samples.data;
        ctx.strokeStyle = "rgba(255, 127, 14, 0.25)"; ctx.lineWidth = 1;
        for (let m = 0; m < this.S; m++) {
          const at = (k) => ((((s * this.S + m) * this.P + k) * this.N + i) * 2);
          this.polyline(ctx, v, this.predictedPath(i, (k) => d[at(k)], (k) => d[at(k) + 1]));
        }
      }
      if (this.layers.prediction) {
        ctx.strokeStyle = PRED_COLOR; ctx.lineWidth = 2;
        this.polyline(ctx, v, this.predictedPath(i, (k) => this.predX(s, k, i), (k) => this.predY(s, k, i)));
      }
    }
  }

  drawEdges(ctx, v) {
    const s = this.scene, t = this.step, i = this.selected;
    if (i < 0 || !this.layers.edges || !this.hasAttention() || !this.valid(s, t, i)) return;
    const [ci, ri] = Viewer.toPixel(v, this.x(s, t, i), this.y(s, t, i));
    ctx.strokeStyle = EDGE_COLOR; ctx.lineCap = "round";
    for (let j = 0; j < this.N; j++) {
      const w = this.weight(s, t, i, j);
      if (j === i || !this.valid(s, t, j) || !(w * EDGE_MAX_PX >= 0.25)) continue;
      const [cj, rj] = Viewer.toPixel(v, this.x(s, t, j), this.y(s, t, j));
      ctx.lineWidth = w * EDGE_MAX_PX;
      ctx.beginPath(); ctx.moveTo(ci, ri); ctx.lineTo(cj, rj); ctx.stroke();
    }
    ctx.lineCap = "butt";
  }

  agentShape(ctx, v, x, y, heading, grow = 0) {
    const road = this.spec.road;
    const [c, r] = Viewer.toPixel(v, x, y);
    ctx.beginPath();
    if (!road) { ctx.arc(c, r, DOT_PX + grow, 0, 2 * Math.PI); return; }
    const length = Math.max(2, road.car_length_m * v.k) + 2 * grow, width = Math.max(2, road.car_width_m * v.k) + 2 * grow;
    const cos = Math.cos(heading), sin = Math.sin(heading);
    const corners = [[1, 1], [-1, 1], [-1, -1], [1, -1]].map(([a, b]) => [
      c + (a * length / 2) * cos - (b * width / 2) * sin,
      r - ((a * length / 2) * sin + (b * width / 2) * cos),
    ]);
    ctx.moveTo(...corners[0]);
    for (const p of corners.slice(1)) ctx.lineTo(...p);
    ctx.closePath();
  }

  drawAgents(ctx, v) {
    const s = this.scene, t = this.step, obs = this.spec.num_observed;
    if (this.a.pred && this.layers.prediction && t >= obs) { // where the prediction has it now
      ctx.strokeStyle = PRED_COLOR; ctx.lineWidth = 1.5;
      for (let i = 0; i < this.N; i++) {
        if (!this.valid(s, t, i) || !this.predicted(s, i) || !this.showsTrail(i)) continue;
        this.agentShape(ctx, v, this.predX(s, t - obs, i), this.predY(s, t - obs, i), this.heading(s, t, i));
        ctx.stroke();
      }
    }
    for (let i = 0; i < this.N; i++) {
      if (!this.valid(s, t, i)) continue;
      this.agentShape(ctx, v, this.x(s, t, i), this.y(s, t, i), this.heading(s, t, i));
      ctx.fillStyle = this.roleColor(s, i); ctx.fill();
      ctx.strokeStyle = OUTLINE_COLOR; ctx.lineWidth = 1; ctx.stroke();
    }
    const i = this.selected;
    if (i >= 0 && this.valid(s, t, i)) {
      this.agentShape(ctx, v, this.x(s, t, i), this.y(s, t, i), this.heading(s, t, i), 3);
      ctx.strokeStyle = SELECT_COLOR; ctx.lineWidth = 2; ctx.stroke();
      const target = this.label(s, t, i);
      if (target >= 0 && this.valid(s, t, target)) { // the labelled one: a dashed ring
        const [c, r] = Viewer.toPixel(v, this.x(s, t, target), this.y(s, t, target));
        const radius = this.spec.road ? this.spec.road.car_length_m * v.k * 0.75 + 4 : DOT_PX + 6;
        ctx.setLineDash([4, 3]); ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 2;
        ctx.beginPath(); ctx.arc(c, r, radius, 0, 2 * Math.PI); ctx.stroke(); ctx.setLineDash([]);
      }
    }
    if (!this.layers.numbers) return;
    ctx.font = "bold 11px system-ui, sans-serif"; ctx.lineWidth = 3;
    ctx.strokeStyle = "rgba(0, 0, 0, 0.75)"; ctx.fillStyle = "#ffffff";
    for (let j = 0; j < this.N; j++) {
      if (!this.valid(s, t, j)) continue;
      const [c, r] = Viewer.toPixel(v, this.x(s, t, j), this.y(s, t, j));
      const lift = this.spec.road ? this.spec.road.car_width_m * v.k / 2 + 3 : DOT_PX + 3;
      ctx.strokeText(String(j), c + 3, r - lift); ctx.fillText(String(j), c + 3, r - lift);
    }
  }

  // ---- the chosen agent's attention: weights at this step, curve over time, influence
  fillAttentionPanel() {
    const panel = document.getElementById("attention-panel");
    const s = this.scene, t = this.step, i = this.selected;
    panel.replaceChildren();
    if (i < 0) { panel.append(el("p", { class: "hint" }, "Click a car to see its attention.")); return; }
    const kind = this.focal(s, i) ? "main" : "other";
    panel.append(el("h3", {}, `agent ${i} (${this.roleName(s, i)}, ${kind}) at step ${t}, t = ${(t * this.spec.dt).toFixed(2)} s`));
    if (!this.valid(s, t, i)) { panel.append(el("p", {}, "not present at this step")); return; }
    const target = this.label(s, t, i);
    const labelText = !this.spec.labels_recorded ? "the dataset records no attention labels"
      : target >= 0 ? `labelled: attends to agent ${target} (${this.roleName(s, target)})` : "labelled: attends to no one";
    panel.append(el("p", { id: "attention-label", "data-label": String(target) }, labelText));
    if (!this.hasAttention()) { panel.append(el("p", { class: "hint" }, "no predictions, so no attention")); return; }
    if (t >= this.T - 1) { panel.append(el("p", { class: "hint" }, `attention is computed at steps 0 to ${this.T - 2} (none at the last step)`)); return; }
    const others = [];
    for (let j = 0; j < this.N; j++) {
      const w = this.weight(s, t, i, j);
      if (j !== i && this.valid(s, t, j) && !Number.isNaN(w)) others.push([j, w]);
    }
    if (!others.length) { panel.append(el("p", { class: "hint" }, "no attention at this step (this predictor computes none)")); return; }
    others.sort((p, q) => q[1] - p[1] || p[0] - q[0]);
    panel.append(el("p", {}, "attention computed at this step (to predict the next):"));
    const table = el("table", { id: "attention-table" });
    for (const [j, w] of others) {
      const tr = el("tr", { "data-agent": String(j) });
      if (j === target) tr.classList.add("labelled");
      const bar = el("div", { class: "bar" });
      bar.style.width = `${Math.round(w * 100)}px`;
      const barCell = el("td"); barCell.append(bar);
      tr.append(el("td", {}, `agent ${j}`), el("td", {}, this.roleName(s, j)), el("td", { class: "weight" }, w.toFixed(3)),
        barCell, el("td", {}, j === target ? "label" : ""));
      table.append(tr);
    }
    panel.append(table);
  }

  curveTargets() {
    // labelled targets first, then the largest mean weights, at most MAX_CURVES
    const s = this.scene, i = this.selected, chosen = [];
    for (let t = 0; t < this.T; t++) {
      const j = this.label(s, t, i);
      if (j >= 0 && !chosen.includes(j)) chosen.push(j);
    }
    if (this.hasAttention()) {
      const mean = [];
      for (let j = 0; j < this.N; j++) {
        if (j === i) continue;
        let sum = 0, count = 0;
        for (let t = 0; t < this.T - 1; t++) {
          const w = this.weight(s, t, i, j);
          if (!Number.isNaN(w) && this.valid(s, t, j)) { sum += w; count++; }
        }
        if (count) mean.push([j, sum / count]);
      }
      mean.sort((p, q) => q[1] - p[1] || p[0] - q[0]);
      for (const [j] of mean) if (!chosen.includes(j)) chosen.push(j);
    }
    return chosen.slice(0, MAX_CURVES);
  }

  curveFrame(width, height) {
    const left = 34, right = 8, top = 8, bottom = 20;
    const dx = (width - left - right) / Math.max(1, this.T - 2);
    return { left, top, bottom, dx, h: height - top - bottom };
  }

  drawCurve() {
    const { ctx, width, height } = sizeCanvas(this.curve);
    const legend = document.getElementById("curve-legend");
    ctx.clearRect(0, 0, width, height);
    legend.replaceChildren();
    const s = this.scene, i = this.selected, f = this.curveFrame(width, height);
    const px = (t) => f.left + t * f.dx, py = (w) => f.top + (1 - w) * f.h;
    ctx.fillStyle = INTERACTION_COLOR;
    for (let t = 0; t < this.T - 1; t++) if (this.interaction(s, t)) ctx.fillRect(px(t - 0.5), f.top, f.dx, f.h);
    ctx.strokeStyle = "#999"; ctx.lineWidth = 1; ctx.fillStyle = "#444"; ctx.font = "10px system-ui, sans-serif";
    for (const w of [0, 0.5, 1]) {
      ctx.beginPath(); ctx.moveTo(f.left, py(w)); ctx.lineTo(width - 8, py(w)); ctx.stroke();
      ctx.fillText(w.toFixed(1), 6, py(w) + 3);
    }
    ctx.fillText("step", width - 30, height - 4);
    for (let t = 0; t < this.T - 1; t += Math.max(1, Math.round(this.T / 10))) ctx.fillText(String(t), px(t) - 3, height - 6);
    ctx.setLineDash([2, 3]); ctx.strokeStyle = "#000";
    const obs = px(this.spec.num_observed - 1);
    ctx.beginPath(); ctx.moveTo(obs, f.top); ctx.lineTo(obs, f.top + f.h); ctx.stroke(); ctx.setLineDash([]);
    if (i < 0) { legend.textContent = "attention of the chosen car over time (shaded: interaction period; dotted: last observed step)"; }
    else {
      const targets = this.curveTargets();
      targets.forEach((j, n) => {
        const main = this.focal(s, j);
        const color = main ? this.roleColor(s, j) : CURVE_COLORS[n % CURVE_COLORS.length];
        for (let t = 0; t < this.T - 1; t++) { // the label strip: when i is labelled to attend j
          if (this.label(s, t, i) === j) { ctx.fillStyle = color; ctx.fillRect(px(t - 0.5), f.top - 6, f.dx, 4); }
        }
        if (this.hasAttention()) {
          ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.beginPath();
          let open = false;
          for (let t = 0; t < this.T - 1; t++) {
            const w = this.weight(s, t, i, j);
            if (Number.isNaN(w)) { open = false; continue; }
            if (open) ctx.lineTo(px(t), py(w)); else { ctx.moveTo(px(t), py(w)); open = true; }
          }
          ctx.stroke();
        }
        const key = el("span", { class: "line-key" }); key.style.borderTopColor = color;
        legend.append(key, `agent ${j} (${this.roleName(s, j)})`);
      });
      legend.append(el("span", {}, ` \u2014 attention of agent ${i} over time; bar above: labelled; shaded: interaction; dotted: last observed step`));
    }
    ctx.strokeStyle = "#000"; ctx.lineWidth = 2; // the current step
    const now = px(Math.min(this.step, this.T - 2));
    ctx.beginPath(); ctx.moveTo(now, f.top - 6); ctx.lineTo(now, f.top + f.h); ctx.stroke();
  }

  drawInfluence() {
    // influence[s, t, i, j]: of j on i at step t, where the predictions hold such a matrix
    const panel = document.getElementById("influence-panel");
    if (!this.a.influence) return;
    panel.hidden = false;
    const { ctx, width } = sizeCanvas(document.getElementById("influence-canvas"));
    const t = Math.min(this.step, this.T - 2), s = this.scene, cell = width / this.N, d = this.a.influence.data;
    const at = (i, j) => d[((s * (this.T - 1) + t) * this.N + i) * this.N + j];
    let top = 0;
    for (let i = 0; i < this.N; i++) for (let j = 0; j < this.N; j++) top = Math.max(top, Math.abs(at(i, j)) || 0);
    for (let i = 0; i < this.N; i++) {
      for (let j = 0; j < this.N; j++) {
        const level = top > 0 ? Math.abs(at(i, j)) / top : 0;
        ctx.fillStyle = `rgba(31, 119, 180, ${Number.isNaN(level) ? 0 : level})`;
        ctx.fillRect(j * cell, i * cell, cell, cell);
      }
    }
    if (this.selected >= 0) { ctx.strokeStyle = SELECT_COLOR; ctx.lineWidth = 2; ctx.strokeRect(0, this.selected * cell, width, cell); }
  }
}

function showError(error) {
  const message = `The viewer could not start: ${error && error.message ? error.message : error}`;
  window.viewerError = message;
  const header = document.getElementById("header");
  header.append(el("p", { id: "error" }, message));
}

(async function main() {
  const spec = JSON.parse(document.getElementById("viewer-data").textContent);
  const arrays = await decodeArrays(spec.arrays, document.getElementById("viewer-blob").textContent);
  const viewer = new Viewer(spec, arrays);
  viewer.start();
  window.viewer = viewer;
  window.viewerLoadMs = performance.now(); // since the navigation started: parse, inflate, first drawing
  window.viewerReady = true;
})().catch(showError);
