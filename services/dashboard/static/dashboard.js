// tiplog dashboard: websocket client, numbers, tables and recorder controls.
// Everything received is written with textContent or drawn on canvas: never parsed as HTML.
"use strict";

(function () {
  const D = window.TiplogDraw;
  const $ = (id) => document.getElementById(id);
  const view = {
    hello: null, est: null, ref: null, vis: null, axes: [0, 1], dirty: true,
    current: null, status: null, lastSent: 0, skipped: 0, received: 0,
  };
  window.tiplog = view;  // for tests and the curious: the page's own state, read only
  // The badge stays "locked" this long after the last gated vision frame: the filter's own lock
  // window is shorter than the gaps between accepted frames on a loaded host, and a badge that
  // flickers every half second tells nothing.
  const LOCK_HOLD_S = 1.0;
  // Numbers older than this (no new state, no new ToF sample) are dimmed and said to be stale.
  const STALE_S = 1.0;

  function text(id, value) { const el = $(id); if (el && el.textContent !== value) el.textContent = value; }
  function fmt(v, digits) { return typeof v === "number" && isFinite(v) ? v.toFixed(digits) : "\u2013"; }
  function vec(v, digits, scale) {
    if (!v) return "\u2013";
    const s = scale || 1;
    return [v.x, v.y, v.z].map((c) => fmt((c || 0) * s, digits)).join(" / ");
  }
  function bytes(n) {
    if (typeof n !== "number") return "\u2013";
    const u = ["B", "KiB", "MiB", "GiB", "TiB"]; let k = 0;
    while (n >= 1024 && k < u.length - 1) { n /= 1024; k++; }
    return `${n.toFixed(k ? 1 : 0)} ${u[k]}`;
  }
  function setClass(el, cls) { if (el && el.className !== cls) el.className = cls; }

  // ---- websocket ---------------------------------------------------------------------------
  let ws = null, backoff = 250;
  function connect() {
    const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`;
    ws = new WebSocket(url);
    ws.onopen = () => { backoff = 250; text("conn", "connected"); setClass($("conn"), "pill ok"); };
    ws.onmessage = (ev) => onMessage(JSON.parse(ev.data));
    ws.onclose = () => {
      text("conn", "reconnecting");
      setClass($("conn"), "pill bad");
      setTimeout(connect, backoff);
      backoff = Math.min(2000, backoff * 2);
    };
  }

  function onMessage(msg) {
    if (msg.type === "hello") {
      view.hello = msg;
      const cols = msg.columns;
      view.cols = Object.fromEntries(cols.state.map((c, i) => [c, i]));
      view.est = new D.Trail(msg.trail_samples, cols.state.length);
      view.ref = new D.Trail(msg.trail_samples, cols.reference.length);
      view.vis = new D.Trail(2000, cols.vision.length);
      view.received = 0; view.skipped = 0;
      text("role", msg.role);
      const viewer = msg.role !== "operator";
      for (const id of ["rec-start", "rec-stop", "rec-mark"]) {
        $(id).disabled = viewer;
        $(id).title = viewer ? "operators only" : "";
      }
      return;
    }
    if (msg.type !== "batch" || !view.est) return;
    for (const r of msg.state) view.est.push(r);
    for (const r of msg.reference) view.ref.push(r);
    for (const r of msg.vision) if (r[4] === 1) view.vis.push(r);
    if (msg.state.length) view.stateAt = performance.now();
    view.received += msg.state.length;
    view.skipped += msg.skipped;
    view.lastSent = msg.sent_ns;
    if (msg.current) view.current = msg.current;
    if (msg.predicted !== undefined) view.predicted = msg.predicted;
    if (msg.status) { view.status = msg.status; view.statusAt = performance.now(); updateStatus(msg.status); }
    view.dirty = true;
  }

  // ---- numbers -------------------------------------------------------------------------------
  function updateNumbers() {
    const cur = view.current, c = view.cols;
    if (!cur || !cur.state) return;
    const s = cur.state;
    text("v-depth", fmt(s.depth_mm, 2));
    text("v-tilt", fmt(s.tilt_deg, 2));
    text("v-roll", fmt(s.roll_deg, 2));
    text("v-tof-offset", fmt(s.tof_offset_mm, 2));
    text("v-tip", vec(s.tip_m, 2, 1000));
    text("v-sigma", vec(s.tip_sigma_mm, 2, 1));
    text("v-fusion-lag", fmt(s.lag_ms, 1));
    const tNewest = view.est.last(0);
    const sentMs = (view.lastSent - view.hello.t0_ns) / 1e6;
    text("v-display-lag", fmt(sentMs - tNewest, 1));
    const locked = lockShown(s);
    text("lock", locked ? "vision: locked" : lockLost(s));
    setClass($("lock"), (locked ? "pill ok" : "pill bad") + (view.stale ? " stale" : ""));
    text("e-now", fmt(view.est.last(c.err_mm), 2));
    text("e-radial", fmt(view.est.last(c.err_radial_mm), 2));
    text("e-tangential", fmt(view.est.last(c.err_tangential_mm), 2));
    const t0 = view.est.n ? view.est.get(0, 0) : NaN;
    text("trail-count", String(view.est.n));
    text("trail-span", fmt((tNewest - t0) / 1000, 1));
    text("trail-skipped", String(view.skipped));
  }

  // How long the estimate has run without vision: without it only the gyro carries the
  // heading and the error grows with the time (docs/fusion.md), so the time tells how far to
  // trust the tip. (No vision frame in this filter's state, e.g. after a reset: no time.)
  function lockShown(s) {
    const last = Number(s.last_vision_stamp_ns || 0), stamp = Number((s.header && s.header.stamp_ns) || 0);
    return !!s.vision_locked || (last > 0 && stamp >= last && stamp - last < LOCK_HOLD_S * 1e9);
  }

  function lockLost(s) {
    const last = Number(s.last_vision_stamp_ns || 0), stamp = Number((s.header && s.header.stamp_ns) || 0);
    return last > 0 && stamp >= last ? `vision: no lock for ${fmt((stamp - last) / 1e9, 1)} s` : "vision: no lock";
  }

  function fillTable(tbody, rows) {
    // rows: [[cells...], cssClassOfSecondCell]; rebuilt with textContent only
    while (tbody.rows.length > rows.length) tbody.deleteRow(-1);
    rows.forEach(([cells, cls], i) => {
      const tr = tbody.rows[i] || tbody.insertRow();
      while (tr.cells.length < cells.length) tr.insertCell();
      cells.forEach((v, k) => { if (tr.cells[k].textContent !== String(v)) tr.cells[k].textContent = String(v); });
      if (cls !== undefined) setClass(tr.cells[1], cls);
    });
  }

  function updateStatus(st) {
    const h = st.health || {};
    fillTable($("health").tBodies[0], Object.entries(h).map(([name, v]) =>
      [[name, v.state, v.last_data_age_s === null || v.last_data_age_s === undefined ? "\u2013" : fmt(v.last_data_age_s, 2),
        v.run_state === "failed" && v.last_error ? `failed: ${v.last_error}` : v.run_state || "\u2013",
        v.restarts === undefined ? "\u2013" : String(v.restarts)], `state-${v.state}`]));
    text("supervisor-event", st.supervisor_event ? `tiplog up: ${st.supervisor_event}` : "");
    const tof = st.tof;
    text("v-tof-smoothed", tof ? (tof.smoothed_valid ? fmt(tof.range_smoothed_mm, 1) : "not valid") : "\u2013");
    const streams = st.streams || {};
    fillTable($("streams").tBodies[0], Object.entries(streams).map(([topic, v]) =>
      [[topic, fmt(v.rate_hz, 1), String(v.dropped), String(v.count)]]));
    const rec = st.recorder;
    text("rec-state", rec ? String(rec.state).replace("RECORDER_STATE_", "").toLowerCase() : "no recorder");
    text("rec-file", rec && rec.path ? rec.path : "\u2013");
    text("rec-size", rec ? bytes(rec.bytes_written) : "\u2013");
    text("rec-duration", rec ? `${fmt(rec.duration_s, 1)} s` : "\u2013");
    text("rec-free", rec ? bytes(rec.free_bytes) : "\u2013");
    text("rec-alarm", rec && rec.alarm ? rec.alarm : "none");
    setClass($("rec-alarm"), rec && rec.alarm ? "pill bad" : "");
    const e = st.error || {};
    text("e-rms", fmt(e.rms_mm, 2));
    text("e-radial-rms", fmt(e.radial_rms_mm, 2));
    text("e-tangential-rms", fmt(e.tangential_rms_mm, 2));
    text("e-count", String(e.samples || 0));
    const diag = st.diagnostics;
    const vlat = diag && diag.vision_latency_ms ? diag.vision_latency_ms : (view.vis && view.vis.n ? view.vis.last(5) : NaN);
    text("v-vision-latency", fmt(vlat, 1));
    const load = st.load || {};
    const vl = load.vision, bl = load.bench;
    text("v-vision-load", vl ? `${fmt(vl.achieved_hz, 1)} of ${fmt(vl.target_hz, 1)}, ${(vl.counts || {}).frames_dropped_stale || 0} dropped` : "\u2013");
    text("v-camera-load", bl ? `${fmt(bl.achieved_hz, 1)} of ${fmt(bl.target_hz, 0)}, ${(bl.counts || {}).frames_skipped_late || 0} skipped` : "\u2013");
    $("camera-row").classList.toggle("warn", !!(bl && bl.behind));
    $("camera-row").title = bl && bl.note ? bl.note : "the bench's pixel tier: frames rendered per second against the camera's rate";
    const drows = [];
    if (diag) {
      drows.push([["mode", diag.mode || "\u2013"]], [["initialised", diag.initialised ? "yes" : "no"]],
        [["resets", String(diag.resets || 0)]], [["inputs dropped (filter behind)", String(diag.queue_drops || 0)]],
        [["rewinds", String(diag.rewinds)]], [["max rewind (ms)", fmt(diag.max_rewind_ms, 1)]]);
      for (const [k, v] of Object.entries(diag.reset_reasons || {})) drows.push([[`resets: ${k}`, String(v)]]);
      for (const [k, v] of Object.entries(diag.updates || {})) drows.push([[`updates ${k}`, String(v)]]);
      for (const [k, v] of Object.entries(diag.rejected || {})) drows.push([[`rejected ${k}`, String(v)]]);
      for (const [k, v] of Object.entries(diag.deferred || {})) drows.push([[`deferred ${k}`, String(v)]]);
      for (const [k, v] of Object.entries(diag.innovation_nis || {})) drows.push([[`NIS ${k}`, fmt(v, 2)]]);
      const aside = new Set(diag.aside || []);
      for (const [k, v] of Object.entries(diag.noise_scale || {}))
        drows.push([[`noise factor ${k}`, fmt(v, 1) + (aside.has(k) ? " (set aside)" : "")]]);
      for (const [k, v] of Object.entries(diag.set_aside || {})) drows.push([[`set aside ${k}`, String(v)]]);
      for (const [k, v] of Object.entries(diag.held_up || {})) drows.push([[`held up ${k} (host stalled)`, String(v)]]);
      for (const [k, v] of Object.entries(diag.clock_restarts || {})) drows.push([[`device clock restarts ${k}`, String(v)]]);
    } else drows.push([["diagnostics", "none received"]]);
    fillTable($("diagnostics").tBodies[0], drows);
    const env = st.envelope;
    text("env-depth", env && env.depth_min_mm !== null ? `${fmt(env.depth_min_mm, 1)}\u2013${fmt(env.depth_max_mm, 1)}` : "\u2013");
    text("env-tilt", env ? fmt(env.tilt_max_deg, 1) : "\u2013");
    view.envelope = env;
    if (st.preview_seq && st.preview_seq !== view.previewSeq) {
      view.previewSeq = st.preview_seq;
      $("preview").src = `/api/preview?seq=${st.preview_seq}`;
      $("preview").classList.remove("hidden");
      $("preview-none").classList.add("hidden");
    }
    text("clock", `t = ${fmt(st.t_ms / 1000, 1)} s`);
  }

  // ---- staleness -----------------------------------------------------------------------------
  // What stopped coming stays in place, dimmed, with how long it has been: the state (numbers,
  // lock, path, error) when no state came for STALE_S, the ToF when its sample is that old.
  function ageS(at, base) { return at ? base + (performance.now() - at) / 1000 : NaN; }
  function markStale() {
    if (!view.current) return;
    const stateAge = ageS(view.stateAt, 0);
    const stale = stateAge > STALE_S;
    view.stale = stale;
    for (const id of ["state-panel", "error-panel", "path", "inset", "lock"]) $(id).classList.toggle("stale", stale);
    const said = stale ? `stale: no new state for ${fmt(stateAge, 1)} s` : "";
    text("state-stale", said);
    text("stale", stale ? `fusion: ${said}` : "");
    $("stale").classList.toggle("hidden", !stale);
    const tof = view.status && view.status.tof;
    const tofAge = tof && typeof tof.age_s === "number" ? ageS(view.statusAt, tof.age_s) : NaN;
    $("tof-row").classList.toggle("stale", tofAge > STALE_S);
  }
  setInterval(markStale, 250);

  // ---- drawing ------------------------------------------------------------------------------
  function scene() {
    const s = view.current && view.current.state;
    const robot = view.status && view.status.robot;
    const v3 = (v, k) => (v ? [(v.x || 0) * k, (v.y || 0) * k, (v.z || 0) * k] : null);
    let refU = null;
    if (robot && robot.tip_m && robot.rcm_m) {
      const t = v3(robot.tip_m, 1000), r = v3(robot.rcm_m, 1000);
      const d = [t[0] - r[0], t[1] - r[1], t[2] - r[2]], n = Math.hypot(...d);
      refU = n > 0 ? d.map((x) => x / n) : null;
    }
    return {
      est: view.est, ref: view.ref, vis: view.vis, axes: view.axes,
      tip: s ? v3(s.tip_m, 1000) : null, u: s ? v3(s.shaft_direction, 1) : null, depth: s ? s.depth_mm : 0,
      predicted: view.predicted || null,
      refTip: robot ? v3(robot.tip_m, 1000) : null, refU, refDepth: robot ? robot.depth_mm : 0,
    };
  }

  // The last 600 frames: [time since the previous frame, time spent drawing] in ms.
  view.frames = [];
  let lastFrame = 0;
  function frame(now) {
    if (view.dirty && view.est) {
      view.dirty = false;
      const t0 = performance.now();
      updateNumbers();
      const sc = scene();
      D.drawPath($("path"), sc);
      D.drawInset($("inset"), sc, 30);
      D.drawEnvelope($("envelope"), view.envelope);
      view.frames.push([lastFrame ? now - lastFrame : 0, performance.now() - t0]);
      if (view.frames.length > 600) view.frames.shift();
    }
    lastFrame = now;
    requestAnimationFrame(frame);
  }

  // ---- controls ------------------------------------------------------------------------------
  async function recorder(action, body) {
    const out = $("rec-result");
    out.textContent = `${action}\u2026`;
    try {
      const r = await fetch(`/api/recorder/${action}`, {
        method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
        credentials: "same-origin",
      });
      const j = await r.json().catch(() => ({}));
      if (r.ok) out.textContent = `${action}: ${j.ok ? "ok" : "refused"} \u2013 ${j.message || ""}`;
      else out.textContent = `${action}: refused (${r.status}) \u2013 ${typeof j.detail === "string" ? j.detail : r.statusText}`;
    } catch (e) {
      out.textContent = `${action}: failed (${e})`;
    }
  }

  function wire() {
    $("rec-start").addEventListener("click", () => recorder("start", { reason: "dashboard" }));
    $("rec-stop").addEventListener("click", () => recorder("stop", { reason: "dashboard" }));
    $("rec-mark").addEventListener("click", () => {
      const label = $("mark-label").value.trim() || "mark";
      recorder("mark", { label });
    });
    for (const b of $("projection").querySelectorAll("button[data-axes]")) {
      b.addEventListener("click", () => {
        view.axes = b.dataset.axes.split(",").map(Number);
        for (const o of $("projection").querySelectorAll("button[data-axes]")) o.classList.toggle("on", o === b);
        view.dirty = true;
      });
    }
    $("clear-trail").addEventListener("click", () => { if (view.est) { view.est.clear(); view.ref.clear(); view.vis.clear(); view.dirty = true; } });
    window.addEventListener("resize", () => { view.dirty = true; });
  }

  wire();
  connect();
  requestAnimationFrame(frame);
})();
