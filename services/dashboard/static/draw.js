// Canvas drawing for the tiplog dashboard: the tip path, the 30 mm inset, the envelope.
// Only canvas calls: nothing from the bus ever becomes HTML.
"use strict";

(function () {
  const COLORS = { est: "#ff9a1f", ref: "#3d8bff", vis: "#37c871", grid: "#263040", text: "#9aa4b1" };
  const AXIS_NAMES = ["x", "y", "z"];

  // A ring of rows (Float64, NaN for missing) that keeps its newest `cap` rows.
  class Trail {
    constructor(cap, width) {
      this.cap = cap; this.width = width;
      this.data = new Float64Array(cap * width);
      this.n = 0; this.head = 0;  // head: next write slot
    }
    clear() { this.n = 0; this.head = 0; }
    push(row) {
      const o = this.head * this.width;
      for (let k = 0; k < this.width; k++) { const v = row[k]; this.data[o + k] = v === null || v === undefined ? NaN : v; }
      this.head = (this.head + 1) % this.cap;
      if (this.n < this.cap) this.n++;
    }
    // value of column c in the i-th oldest row
    get(i, c) { return this.data[((this.head - this.n + i + this.cap) % this.cap) * this.width + c]; }
    last(c) { return this.n ? this.get(this.n - 1, c) : NaN; }
  }

  function fitCanvas(canvas) {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(50, Math.round(canvas.clientWidth * dpr));
    const h = Math.max(50, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    return { ctx, w, h, dpr };
  }

  // Equal-aspect mapping of the box [a0,a1]x[b0,b1] (mm) into the canvas with a margin.
  function mapper(box, w, h, margin) {
    const sa = (w - 2 * margin) / Math.max(1e-9, box.a1 - box.a0);
    const sb = (h - 2 * margin) / Math.max(1e-9, box.b1 - box.b0);
    const s = Math.min(sa, sb);
    const ca = (box.a0 + box.a1) / 2, cb = (box.b0 + box.b1) / 2;
    return { s, X: (a) => w / 2 + (a - ca) * s, Y: (b) => h / 2 - (b - cb) * s };
  }

  // The box holding the trails, robust to a brief excursion (a filter's start-up transient):
  // the 0.5th to 99.5th percentile of up to ~4000 sampled points on each axis.
  function bounds(trails, axes, cols) {
    const as = [], bs = [];
    trails.forEach((t, j) => {
      const [ca, cb] = cols[j];
      const step = Math.max(1, Math.floor(t.n / 2000));
      for (let i = t.n - 1; i >= 0; i -= step) {
        const a = t.get(i, ca + axes[0]), b = t.get(i, cb + axes[1]);
        if (a === a && b === b) { as.push(a); bs.push(b); }
      }
    });
    if (!as.length) return null;
    const q = (v, p) => v[Math.min(v.length - 1, Math.max(0, Math.round(p * (v.length - 1))))];
    as.sort((x, y) => x - y); bs.sort((x, y) => x - y);
    const a0 = q(as, 0.005), a1 = q(as, 0.995), b0 = q(bs, 0.005), b1 = q(bs, 0.995);
    const pad = Math.max(5, 0.08 * Math.max(a1 - a0, b1 - b0));
    return { a0: a0 - pad, a1: a1 + pad, b0: b0 - pad, b1: b1 + pad };
  }

  // A trail is drawn as a line only where the tip could have moved so: consecutive rows further
  // apart than MAX_SPEED_MM_PER_MS over their interval (plus JUMP_SLACK_MM), or more than
  // MAX_GAP_MS apart in time, are a reset, a re-acquisition or an outage, and the line breaks
  // there instead of drawing a straight segment the tip never travelled. (2 m/s: fusion's own
  // bound for a diverged state; a hand-held tip moves well under 1 m/s.)
  const MAX_SPEED_MM_PER_MS = 2.0, JUMP_SLACK_MM = 2.0, MAX_GAP_MS = 250;

  // Does the line break between rows i - 1 and i? (column 0: time in ms; col0..col0+2: x, y, z in mm)
  function breaksBefore(trail, i, col0) {
    if (i <= 0) return true;
    const dt = trail.get(i, 0) - trail.get(i - 1, 0);
    if (!(dt >= 0) || dt > MAX_GAP_MS) return true;
    const d = Math.hypot(trail.get(i, col0) - trail.get(i - 1, col0), trail.get(i, col0 + 1) - trail.get(i - 1, col0 + 1),
      trail.get(i, col0 + 2) - trail.get(i - 1, col0 + 2));
    return !(d <= MAX_SPEED_MM_PER_MS * dt + JUMP_SLACK_MM);
  }

  // The runs of rows drawn as one line each: [[first, last], ...] (for tests and the curious).
  function segments(trail, col0, from) {
    const out = [];
    for (let i = from || 0; i < trail.n; i++) {
      if (trail.get(i, col0) !== trail.get(i, col0)) continue;
      if (i === (from || 0) || !out.length || breaksBefore(trail, i, col0) || out[out.length - 1][1] !== i - 1) out.push([i, i]);
      else out[out.length - 1][1] = i;
    }
    return out;
  }

  function polyline(ctx, trail, col0, axes, m, color, width, from) {
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.beginPath();
    let pen = false;
    for (let i = from || 0; i < trail.n; i++) {
      const a = trail.get(i, col0 + axes[0]), b = trail.get(i, col0 + axes[1]);
      if (a !== a || b !== b) { pen = false; continue; }
      const x = m.X(a), y = m.Y(b);
      if (pen && !breaksBefore(trail, i, col0)) ctx.lineTo(x, y); else { ctx.moveTo(x, y); pen = true; }
    }
    ctx.stroke();
  }

  function dots(ctx, trail, col0, axes, m, color, r, box) {
    ctx.fillStyle = color;
    for (let i = 0; i < trail.n; i++) {
      const a = trail.get(i, col0 + axes[0]), b = trail.get(i, col0 + axes[1]);
      if (a !== a || b !== b) continue;
      if (box && (a < box.a0 || a > box.a1 || b < box.b0 || b > box.b1)) continue;
      ctx.fillRect(m.X(a) - r, m.Y(b) - r, 2 * r, 2 * r);
    }
  }

  // Shaft segment from the tip back to the port: tip - L u .. tip (mm).
  function shaft(ctx, tip, u, depthMm, axes, m, color, width) {
    if (!tip || !u || !(depthMm > 0)) return;
    const a0 = tip[axes[0]] - depthMm * u[axes[0]], b0 = tip[axes[1]] - depthMm * u[axes[1]];
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.beginPath();
    ctx.moveTo(m.X(a0), m.Y(b0)); ctx.lineTo(m.X(tip[axes[0]]), m.Y(tip[axes[1]])); ctx.stroke();
    ctx.fillStyle = color; ctx.beginPath(); ctx.arc(m.X(tip[axes[0]]), m.Y(tip[axes[1]]), 4 * (window.devicePixelRatio || 1), 0, 2 * Math.PI); ctx.fill();
  }

  // The present (fusion/predicted): a hollow ring, so the held-back estimate stays visible.
  function ring(ctx, p, axes, m, color, dpr) {
    if (!p) return;
    ctx.strokeStyle = color; ctx.lineWidth = 2 * dpr; ctx.beginPath();
    ctx.arc(m.X(p[axes[0]]), m.Y(p[axes[1]]), 7 * dpr, 0, 2 * Math.PI); ctx.stroke();
  }

  function scaleBar(ctx, m, w, h, dpr) {
    const steps = [1, 2, 5, 10, 20, 50, 100, 200];
    const target = w / 5 / m.s;
    const mm = steps.find((s) => s >= target) || 200;
    const x0 = 10 * dpr, y0 = h - 12 * dpr;
    ctx.strokeStyle = COLORS.text; ctx.lineWidth = 2 * dpr; ctx.beginPath();
    ctx.moveTo(x0, y0); ctx.lineTo(x0 + mm * m.s, y0); ctx.stroke();
    ctx.fillStyle = COLORS.text; ctx.font = `${11 * dpr}px sans-serif`;
    ctx.fillText(`${mm} mm`, x0, y0 - 5 * dpr);
  }

  function axisLabels(ctx, axes, w, h, dpr) {
    ctx.fillStyle = COLORS.text; ctx.font = `${11 * dpr}px sans-serif`;
    ctx.fillText(`${AXIS_NAMES[axes[0]]} \u2192`, w - 34 * dpr, h - 8 * dpr);
    ctx.fillText(`${AXIS_NAMES[axes[1]]} \u2191`, 6 * dpr, 14 * dpr);
  }

  // scene: {est, ref, vis: Trail; axes; tip, u, depth (estimate), refTip, refU, refDepth}
  function drawPath(canvas, scene) {
    const { ctx, w, h, dpr } = fitCanvas(canvas);
    ctx.clearRect(0, 0, w, h);
    const box = bounds([scene.est, scene.ref], scene.axes, [[1, 1], [1, 1]]);
    axisLabels(ctx, scene.axes, w, h, dpr);
    if (!box) return;
    const m = mapper(box, w, h, 14 * dpr);
    polyline(ctx, scene.ref, 1, scene.axes, m, COLORS.ref, 1.5 * dpr);
    polyline(ctx, scene.est, 1, scene.axes, m, COLORS.est, 1.5 * dpr);
    dots(ctx, scene.vis, 1, scene.axes, m, COLORS.vis, 2 * dpr);
    shaft(ctx, scene.refTip, scene.refU, scene.refDepth, scene.axes, m, COLORS.ref, 3 * dpr);
    shaft(ctx, scene.tip, scene.u, scene.depth, scene.axes, m, COLORS.est, 3 * dpr);
    ring(ctx, scene.predicted, scene.axes, m, COLORS.est, dpr);
    scaleBar(ctx, m, w, h, dpr);
  }

  function drawInset(canvas, scene, sizeMm) {
    const { ctx, w, h, dpr } = fitCanvas(canvas);
    ctx.clearRect(0, 0, w, h);
    if (!scene.tip) return;
    const half = sizeMm / 2, a = scene.axes;
    const box = { a0: scene.tip[a[0]] - half, a1: scene.tip[a[0]] + half, b0: scene.tip[a[1]] - half, b1: scene.tip[a[1]] + half };
    const m = mapper(box, w, h, 0);
    ctx.strokeStyle = COLORS.grid; ctx.lineWidth = 1;
    for (let k = -15; k <= 15; k += 5) {
      ctx.beginPath(); ctx.moveTo(m.X(box.a0 + half + k), 0); ctx.lineTo(m.X(box.a0 + half + k), h); ctx.stroke();
      ctx.beginPath(); ctx.moveTo(0, m.Y(box.b0 + half + k)); ctx.lineTo(w, m.Y(box.b0 + half + k)); ctx.stroke();
    }
    const recent = (t) => Math.max(0, t.n - 2000);  // the last 10 s at 200 Hz
    polyline(ctx, scene.ref, 1, a, m, COLORS.ref, 1.5 * dpr, recent(scene.ref));
    polyline(ctx, scene.est, 1, a, m, COLORS.est, 1.5 * dpr, recent(scene.est));
    dots(ctx, scene.vis, 1, a, m, COLORS.vis, 2.5 * dpr, box);
    if (scene.refTip) {
      ctx.fillStyle = COLORS.ref; ctx.beginPath();
      ctx.arc(m.X(scene.refTip[a[0]]), m.Y(scene.refTip[a[1]]), 4 * dpr, 0, 2 * Math.PI); ctx.fill();
    }
    ctx.fillStyle = COLORS.est; ctx.beginPath(); ctx.arc(w / 2, h / 2, 4 * dpr, 0, 2 * Math.PI); ctx.fill();
    ring(ctx, scene.predicted, a, m, COLORS.est, dpr);
    // The caption on a backing of its own: the trail and the grid never run through it.
    const caption = `${sizeMm} mm \u00d7 ${sizeMm} mm, grid 5 mm`;
    ctx.font = `${11 * dpr}px sans-serif`;
    ctx.fillStyle = "rgba(12, 15, 18, 0.85)";
    ctx.fillRect(2 * dpr, h - 20 * dpr, ctx.measureText(caption).width + 8 * dpr, 18 * dpr);
    ctx.fillStyle = COLORS.text;
    ctx.fillText(caption, 6 * dpr, h - 6 * dpr);
  }

  // env: {depth_bins_mm: [lo, hi, step], tilt_bins_deg: [lo, hi, step], cells: [[i, j, count]]}
  function drawEnvelope(canvas, env) {
    const { ctx, w, h, dpr } = fitCanvas(canvas);
    ctx.clearRect(0, 0, w, h);
    if (!env) return;
    const [d0, d1, db] = env.depth_bins_mm, [t0, t1, tb] = env.tilt_bins_deg;
    const left = 40 * dpr, bottom = 26 * dpr, pw = w - left - 6 * dpr, ph = h - bottom - 6 * dpr;
    const nx = Math.round((d1 - d0) / db), ny = Math.round((t1 - t0) / tb);
    let max = 1;
    for (const c of env.cells) if (c[2] > max) max = c[2];
    for (const [i, j, n] of env.cells) {
      const v = Math.log1p(n) / Math.log1p(max);
      ctx.fillStyle = `rgba(255, 154, 31, ${0.25 + 0.75 * v})`;
      ctx.fillRect(left + (i / nx) * pw, 6 * dpr + ph - ((j + 1) / ny) * ph, pw / nx + 0.5, ph / ny + 0.5);
    }
    ctx.strokeStyle = COLORS.grid; ctx.strokeRect(left, 6 * dpr, pw, ph);
    ctx.fillStyle = COLORS.text; ctx.font = `${11 * dpr}px sans-serif`;
    // Ticks centred on their value, the last one ending at the plot's edge (it was cut off).
    for (let d = d0; d <= d1; d += 20) {
      ctx.textAlign = d + 20 > d1 ? "right" : "center";
      ctx.fillText(String(d), d + 20 > d1 ? left + pw : left + ((d - d0) / (d1 - d0)) * pw, h - 12 * dpr);
    }
    ctx.textAlign = "left";
    for (let t = t0; t <= t1; t += 10) ctx.fillText(String(t), 20 * dpr, 6 * dpr + ph - ((t - t0) / (t1 - t0)) * ph + 4 * dpr);
    ctx.fillText("insertion depth L (mm)", left + pw / 2 - 50 * dpr, h - 1 * dpr);
    ctx.save(); ctx.translate(10 * dpr, 6 * dpr + ph / 2 + 30 * dpr); ctx.rotate(-Math.PI / 2);
    ctx.fillText("tilt (deg)", 0, 0); ctx.restore();
  }

  window.TiplogDraw = { Trail, drawPath, drawInset, drawEnvelope, segments, breaksBefore };
})();
