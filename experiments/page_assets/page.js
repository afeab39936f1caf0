/* configpose run page: replays drawn on <canvas>, no external library, no network.
 *
 * experiments/page.py inlines this file and a JSON payload (<script id="cp-data">):
 *   gps:    replay sources (a sweep's cells with saved epochs, or a recording run), each
 *           {title, note, axes, fixed, tracks, noise, cells}; float arrays are base64 float32
 *           (little endian), positions relative to the track's origin, times to its t0.
 *   flight: the ultrasonic flight (receivers, both transmitters, raw vs gated ranges) or null.
 * window.configpose exposes each player's state() for the browser test.
 */
"use strict";
(function () {
  const DATA = JSON.parse(document.getElementById("cp-data").textContent);
  const API = { gps: [], flight: null, ready: false };
  window.configpose = API;

  // ------------------------------------------------------------------ decoding
  function bytes(s) {
    const bin = atob(s), u8 = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
    return u8;
  }
  function f32(s) { return s == null ? null : new Float32Array(bytes(s).buffer); }
  function u8(s) { return s == null ? null : bytes(s); }
  const fin = Number.isFinite;
  const DEG = 180 / Math.PI;
  function wrapPi(a) { return a - 2 * Math.PI * Math.floor((a + Math.PI) / (2 * Math.PI)); }

  // ------------------------------------------------------------------ drawing helpers
  function el(tag, attrs, parent) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "text") e.textContent = v; else if (k === "html") e.innerHTML = v;
      else e.setAttribute(k, v);
    }
    if (parent) parent.appendChild(e);
    return e;
  }
  function canvasCtx(cv) {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(50, cv.clientWidth), h = Math.max(50, cv.clientHeight);
    if (cv.width !== Math.round(w * dpr) || cv.height !== Math.round(h * dpr)) {
      cv.width = Math.round(w * dpr); cv.height = Math.round(h * dpr);
    }
    const ctx = cv.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    return { ctx, w, h };
  }
  function niceStep(span, n) {
    const raw = span / Math.max(1, n), mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const r = raw / mag;
    return (r < 1.5 ? 1 : r < 3 ? 2 : r < 7 ? 5 : 10) * mag;
  }
  function ticks(lo, hi, n) {
    if (!(hi > lo)) return { step: 1, v: [lo] };
    const step = niceStep(hi - lo, n), v = [];
    for (let x = Math.ceil(lo / step - 1e-9) * step; x <= hi + step * 1e-9; x += step)
      v.push(Math.abs(x) < step * 1e-9 ? 0 : x);
    return { step, v };
  }
  function fmt(v, step) {
    const d = Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
    return v.toFixed(d);
  }
  function range(arrs, pad) {
    let lo = Infinity, hi = -Infinity;
    for (const a of arrs) if (a) for (let i = 0; i < a.length; i++) {
      const v = a[i]; if (fin(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
    }
    if (!fin(lo)) return [-1, 1];
    if (hi - lo < 1e-9) { lo -= 0.5; hi += 0.5; }
    const p = (hi - lo) * (pad || 0);
    return [lo - p, hi + p];
  }

  /* A rectangle of the canvas mapped to data coordinates, with labelled axes. */
  class Frame {
    constructor(ctx, box, xr, yr, equal) {
      this.ctx = ctx; this.box = box; this.xr = xr.slice(); this.yr = yr.slice();
      if (equal) {        // same metres per pixel on both axes, centred
        const sx = (xr[1] - xr[0]) / box.w, sy = (yr[1] - yr[0]) / box.h, s = Math.max(sx, sy);
        const cx = (xr[0] + xr[1]) / 2, cy = (yr[0] + yr[1]) / 2;
        this.xr = [cx - s * box.w / 2, cx + s * box.w / 2];
        this.yr = [cy - s * box.h / 2, cy + s * box.h / 2];
      }
    }
    X(x) { return this.box.x + (x - this.xr[0]) / (this.xr[1] - this.xr[0]) * this.box.w; }
    Y(y) { return this.box.y + this.box.h - (y - this.yr[0]) / (this.yr[1] - this.yr[0]) * this.box.h; }
    invX(px) { return this.xr[0] + (px - this.box.x) / this.box.w * (this.xr[1] - this.xr[0]); }
    clip() {
      const c = this.ctx; c.save(); c.beginPath();
      c.rect(this.box.x, this.box.y, this.box.w, this.box.h); c.clip();
    }
    axes(xlabel, ylabel, opts) {
      const c = this.ctx, b = this.box, o = opts || {};
      c.save();
      c.strokeStyle = "#e3e7eb"; c.fillStyle = "#444"; c.lineWidth = 1;
      c.font = "11px system-ui, sans-serif";
      const tx = ticks(this.xr[0], this.xr[1], Math.max(2, b.w / 80));
      const ty = ticks(this.yr[0], this.yr[1], Math.max(2, b.h / 45));
      c.textAlign = "center"; c.textBaseline = "top";
      for (const v of tx.v) {
        const px = this.X(v); c.beginPath(); c.moveTo(px, b.y); c.lineTo(px, b.y + b.h); c.stroke();
        c.fillText(fmt(v, tx.step), px, b.y + b.h + 3);
      }
      c.textAlign = "right"; c.textBaseline = "middle";
      for (const v of ty.v) {
        const py = this.Y(v); c.beginPath(); c.moveTo(b.x, py); c.lineTo(b.x + b.w, py); c.stroke();
        c.fillText(fmt(v, ty.step), b.x - 4, py);
      }
      if (o.zero) {
        c.strokeStyle = "#9aa3ab"; const py = this.Y(0);
        c.beginPath(); c.moveTo(b.x, py); c.lineTo(b.x + b.w, py); c.stroke();
      }
      c.strokeStyle = "#8a949e"; c.strokeRect(b.x, b.y, b.w, b.h);
      c.font = "12px system-ui, sans-serif"; c.fillStyle = "#222";
      c.textAlign = "center"; c.textBaseline = "bottom";
      c.fillText(xlabel, b.x + b.w / 2, b.y + b.h + 32);
      c.save(); c.translate(b.x - 42, b.y + b.h / 2); c.rotate(-Math.PI / 2);
      c.textBaseline = "top"; c.fillText(ylabel, 0, -4); c.restore();
      if (o.title) { c.textAlign = "left"; c.textBaseline = "bottom"; c.fillText(o.title, b.x, b.y - 3); }
      c.restore();
    }
    line(xs, ys, style, from, to) {      // NaN breaks the line
      const c = this.ctx; let down = false;
      c.save(); c.strokeStyle = style.color; c.lineWidth = style.width || 1.2;
      c.globalAlpha = style.alpha || 1; if (style.dash) c.setLineDash(style.dash);
      c.beginPath();
      const a = from || 0, z = Math.min(to == null ? xs.length : to, xs.length);
      for (let i = a; i < z; i++) {
        const x = xs[i], y = ys[i];
        if (!fin(x) || !fin(y)) { down = false; continue; }
        // style.wrap: an angle series; a jump of more than half a turn is a wrap, not a line
        if (down && style.wrap && Math.abs(y - ys[i - 1]) > style.wrap / 2) down = false;
        if (down) c.lineTo(this.X(x), this.Y(y)); else { c.moveTo(this.X(x), this.Y(y)); down = true; }
      }
      c.stroke(); c.restore();
    }
    dots(xs, ys, style, from, to) {
      const c = this.ctx, r = style.r || 1.5;
      c.save(); c.fillStyle = style.color; c.globalAlpha = style.alpha || 1;
      const a = from || 0, z = Math.min(to == null ? xs.length : to, xs.length);
      for (let i = a; i < z; i++) {
        if (!fin(xs[i]) || !fin(ys[i])) continue;
        c.fillRect(this.X(xs[i]) - r, this.Y(ys[i]) - r, 2 * r, 2 * r);
      }
      c.restore();
    }
    bands(t, flags) {                    // shade spans where flags[i] is set
      if (!flags) return;
      const c = this.ctx; c.save(); c.fillStyle = getComputedStyle(document.body).getPropertyValue("--turn");
      let s = -1;
      for (let i = 0; i <= flags.length; i++) {
        const on = i < flags.length && flags[i];
        if (on && s < 0) s = i;
        if (!on && s >= 0) {
          const x0 = this.X(t[Math.max(0, s - 1)] * 0.5 + t[s] * 0.5);
          const x1 = this.X(i < t.length ? t[i - 1] * 0.5 + t[i] * 0.5 : t[i - 1]);
          c.fillRect(x0, this.box.y, Math.max(1, x1 - x0), this.box.h); s = -1;
        }
      }
      c.restore();
    }
    cursor(x) {
      const c = this.ctx, px = this.X(x);
      c.save(); c.strokeStyle = "#1f5fa8"; c.lineWidth = 1.5;
      c.beginPath(); c.moveTo(px, this.box.y); c.lineTo(px, this.box.y + this.box.h); c.stroke(); c.restore();
    }
  }
  function plotBox(w, h) { return { x: 58, y: 18, w: w - 58 - 14, h: h - 18 - 38 }; }

  /* Antenna layout with heading arrow at a pose. The outline is tr.outline: the indices of
     the layout's convex hull from page.py (experiments/outline.py), never an order by angle
     (an antenna at the body origin has no angle and crossed the polygon). Returns
     { cg: [px, py], outline: [[px, py], ...] } (what was drawn) or null. */
  function drawPlatform(F, cx, cy, yaw, tr, style, dead) {
    if (!fin(cx) || !fin(cy) || !fin(yaw)) return null;
    const body = tr.body, c = F.ctx, co = Math.cos(yaw), si = Math.sin(yaw);
    const pts = body.map(([bx, by]) => [cx + co * bx - si * by, cy + si * bx + co * by]);
    const poly = (tr.outline || []).map((i) => [F.X(pts[i][0]), F.Y(pts[i][1])]);
    c.save(); c.strokeStyle = style.color; c.fillStyle = style.fill; c.lineWidth = 1.6;
    c.setLineDash(style.dash || []);
    if (poly.length >= 2) {
      c.beginPath();
      poly.forEach(([x, y], k) => { if (k) c.lineTo(x, y); else c.moveTo(x, y); });
      c.closePath(); c.fill(); c.stroke();
    }
    c.setLineDash([]);
    const pxPerM = Math.abs(F.X(1) - F.X(0));
    const r = Math.max(2.5, Math.min(6, pxPerM * 0.07));
    pts.forEach((p, i) => {
      c.beginPath(); c.arc(F.X(p[0]), F.Y(p[1]), r, 0, 2 * Math.PI);
      if (dead && dead[i]) { c.fillStyle = "#fff"; c.fill(); c.stroke(); } else { c.fillStyle = style.color; c.fill(); }
    });
    // heading arrow from the CG, as long as the platform
    let len = 0; for (const [bx, by] of body) len = Math.max(len, Math.hypot(bx, by));
    len = Math.max(len * 1.3, 28 / pxPerM);
    const x0 = F.X(cx), y0 = F.Y(cy), x1 = F.X(cx + co * len), y1 = F.Y(cy + si * len);
    c.lineWidth = 2.2; c.strokeStyle = style.color; c.fillStyle = style.color;
    c.beginPath(); c.moveTo(x0, y0); c.lineTo(x1, y1); c.stroke();
    const a = Math.atan2(y1 - y0, x1 - x0), hl = 9;
    c.beginPath(); c.moveTo(x1, y1);
    c.lineTo(x1 - hl * Math.cos(a - 0.4), y1 - hl * Math.sin(a - 0.4));
    c.lineTo(x1 - hl * Math.cos(a + 0.4), y1 - hl * Math.sin(a + 0.4)); c.closePath(); c.fill();
    c.beginPath(); c.arc(x0, y0, 3, 0, 2 * Math.PI); c.fill();
    c.restore();
    return { cg: [x0, y0], outline: poly };
  }

  function legend(parent, items) {
    const d = el("div", { class: "legend" }, parent);
    for (const [label, color, kind] of items) {
      const s = el("span", { text: label, class: kind || "" }, d); s.style.setProperty("--c", color);
    }
    return d;
  }

  // ------------------------------------------------------------------ player base
  /* Slider, play button and speed; subclasses implement draw() over this.t (s from t0). */
  class Player {
    constructor(root) {
      this.root = root; this.i = 0; this.playing = false; this.plots = [];
      const bar = el("div", { class: "timebar" });   // placed by the subclass
      this.bar = bar;
      this.playBtn = el("button", { text: "\u25B6 play", class: "play", type: "button" }, bar);
      this.speedSel = el("select", { class: "speed", title: "playback speed (simulated seconds per second)" }, bar);
      this.slider = el("input", { type: "range", min: "0", max: "0", value: "0", step: "1", class: "slider",
                                  "aria-label": "time" }, bar);
      this.tlabel = el("span", { class: "tlabel" }, bar);
      this.playBtn.addEventListener("click", () => this.toggle());
      this.slider.addEventListener("input", () => { this.seek(+this.slider.value); });
      this.speedSel.addEventListener("change", () => { this.speed = +this.speedSel.value; });
      window.addEventListener("resize", () => this.draw());
    }
    setSpeeds(list, dflt) {
      this.speedSel.innerHTML = "";
      for (const s of list) el("option", { value: String(s), text: s + "\u00D7" }, this.speedSel);
      this.speedSel.value = String(dflt); this.speed = dflt;
    }
    setTimes(t) {
      this.t = t; this.slider.max = String(t.length - 1);
      this.i = Math.min(this.i, t.length - 1); this.slider.value = String(this.i);
    }
    indexOf(time) {       // last index with t <= time
      const t = this.t; let lo = 0, hi = t.length - 1;
      if (time <= t[0]) return 0; if (time >= t[hi]) return hi;
      while (hi - lo > 1) { const m = (lo + hi) >> 1; if (t[m] <= time) lo = m; else hi = m; }
      return lo;
    }
    seek(i) {
      this.i = Math.max(0, Math.min(this.t.length - 1, i | 0));
      this.slider.value = String(this.i); this.draw();
    }
    toggle() {
      this.playing = !this.playing;
      this.playBtn.textContent = this.playing ? "\u275A\u275A pause" : "\u25B6 play";
      if (!this.playing) return;
      if (this.i >= this.t.length - 1) this.i = 0;
      let last = performance.now(), tsim = this.t[this.i];
      const step = (now) => {
        if (!this.playing) return;
        tsim += (now - last) / 1000 * this.speed; last = now;
        const j = this.indexOf(tsim);
        if (j !== this.i) this.seek(j);
        if (this.i >= this.t.length - 1) { this.toggle(); return; }
        requestAnimationFrame(step);
      };
      requestAnimationFrame(step);
    }
    addPlot(parent) {
      const cv = el("canvas", {}, parent);
      cv.addEventListener("click", (ev) => {      // click a time plot to jump there
        const F = cv._frame; if (!F) return;
        const r = cv.getBoundingClientRect();
        this.seek(this.indexOf(F.invX(ev.clientX - r.left)));
      });
      this.plots.push(cv);
      return cv;
    }
  }
  function timePlot(cv, t, series, opts) {
    const { ctx, w, h } = canvasCtx(cv);
    const ys = series.map((s) => s.y);
    const yr = opts.yr || range(ys, 0.05);
    const F = new Frame(ctx, plotBox(w, h), [t[0], t[t.length - 1] > t[0] ? t[t.length - 1] : t[0] + 1], yr);
    F.clip(); F.bands(t, opts.bands); ctx.restore();
    F.axes(opts.xlabel || "time (s)", opts.ylabel, { zero: yr[0] < 0 && yr[1] > 0, title: opts.title });
    F.clip();
    for (const s of series) (s.dots ? F.dots : F.line).call(F, t, s.y, s);
    F.cursor(t[opts.i]);
    ctx.restore();
    cv._frame = F;
    return F;
  }

  // ------------------------------------------------------------------ GPS replay
  class GpsReplay extends Player {
    constructor(root, src, n) {
      super(root);
      this.src = src; this.n = n;
      this.tracks = src.tracks.map((tr) => ({
        ...tr, tt: f32(tr.t),
        tx: tr.truth ? f32(tr.truth.x) : null, ty: tr.truth ? f32(tr.truth.y) : null,
        tyaw: tr.truth ? f32(tr.truth.yaw) : null, turn: u8(tr.turning),
      }));
      this.noise = src.noise.map((g) => ({ ...g, o: f32(g.obs) }));
      const ctl = el("div", { class: "controls" }, root);
      this.sel = {};
      for (const ax of src.axes) {
        const lab = el("label", { text: ax }, ctl);
        const s = el("select", { name: ax, "data-axis": ax }, lab);
        const vals = [...new Set(src.cells.map((c) => c.axes[ax]))];
        const num = vals.every((v) => v !== "" && fin(+v));
        vals.sort((a, b) => num ? +a - +b : a < b ? -1 : a > b ? 1 : 0);
        for (const v of vals) el("option", { value: v, text: (src.labels && src.labels[ax] && src.labels[ax][v]) || v }, s);
        s.addEventListener("change", () => this.pick(ax));
        this.sel[ax] = s;
      }
      for (const [ax, v] of Object.entries(src.fixed || {}))
        el("div", { class: "fixed", text: v }, el("label", { text: ax }, ctl));
      const zl = el("label", { text: "close-up half-width" }, ctl);
      this.zoomSel = el("select", { class: "zoom" }, zl);
      for (const z of [2, 5, 10, 25]) el("option", { value: String(z), text: z + " m" }, this.zoomSel);
      this.zoomSel.value = "5";
      this.zoomSel.addEventListener("change", () => this.draw());
      this.stats = el("div", { class: "stats" }, root);
      legend(root, [["true path / true pose", "#111"], ["estimate (pose: antenna layout + heading)", "#d62728"],
                    ["observed antennas (this epoch)", "#9467bd", "dot"], ["turning (controller flag)", "rgba(255,190,60,0.6)", "band"]]);
      const views = el("div", { class: "views" }, root);
      this.cvOver = el("canvas", { class: "overview" }, views);
      this.cvClose = el("canvas", { class: "closeup" }, views);
      root.appendChild(this.bar);
      const plots = el("div", { class: "plots" }, root);
      this.cvPos = this.addPlot(plots); this.cvHead = this.addPlot(plots);
      this.setSpeeds([5, 20, 50, 200, 1000], 50);
      this.select(src.cells[src.default || 0]);   // page.py picks a plain cell first
    }
    pick(changed) {
      // the cell that keeps the changed axis and matches most other choices (earlier axes first)
      const want = {}; for (const ax of this.src.axes) want[ax] = this.sel[ax].value;
      let best = null, bestScore = -1;
      for (const c of this.src.cells) {
        if (c.axes[changed] !== want[changed]) continue;
        let s = 0; this.src.axes.forEach((ax, k) => { if (c.axes[ax] === want[ax]) s += 1 << (this.src.axes.length - k); });
        if (s > bestScore) { best = c; bestScore = s; }
      }
      if (best) this.select(best);
    }
    select(cell) {
      this.cell = cell;
      if (!cell._d) cell._d = { x: f32(cell.x), y: f32(cell.y), yaw: f32(cell.yaw) };
      const tr = this.tracks[cell.track], d = cell._d;
      if (!d.ex && tr.tx) {
        const n = tr.tt.length;
        d.ex = new Float32Array(n); d.ey = new Float32Array(n); d.eh = new Float32Array(n);
        for (let i = 0; i < n; i++) {
          d.ex[i] = d.x[i] - tr.tx[i]; d.ey[i] = d.y[i] - tr.ty[i]; d.eh[i] = wrapPi(d.yaw[i] - tr.tyaw[i]) * DEG;
        }
      }
      for (const ax of this.src.axes) this.sel[ax].value = cell.axes[ax];
      this.tr = tr; this.setTimes(tr.tt);
      const st = (cell.stats || []).map(([k, v]) => k + " " + v).join(" \u00B7 ");
      this.stats.textContent = "cell " + cell.key + (st ? " \u2014 " + st : "") +
        (tr.step > 1 ? " \u2014 replay shows one epoch in " + tr.step + " (of " + tr.n_full + ")" : "");
      this.draw();
    }
    draw() {
      if (!this.cell) return;
      const tr = this.tr, d = this.cell._d, i = this.i, t = tr.tt;
      const obs = this.cell.noise >= 0 ? this.noise[this.cell.noise] : null;
      const m = tr.names.length, dead = obs ? obs.dead : null;
      const org = tr.origin, xoff = org[0], yoff = org[1];
      const xl = xoff ? "x east \u2212 " + xoff + " (m)" : "x east (m)", yl = yoff ? "y north \u2212 " + yoff + " (m)" : "y north (m)";
      const hasT = !!tr.tx;
      const cx = hasT ? tr.tx[i] : d.x[i], cy = hasT ? tr.ty[i] : d.y[i];
      // overview: the whole track
      {
        const { ctx, w, h } = canvasCtx(this.cvOver);
        const F = new Frame(ctx, plotBox(w, h), range([tr.tx || d.x], 0.04), range([tr.ty || d.y], 0.04), true);
        F.axes(xl, yl, { title: "whole run" });
        F.clip();
        if (hasT) F.line(tr.tx, tr.ty, { color: "#111", width: 1.2, alpha: 0.55 });
        F.line(d.x, d.y, { color: "#d62728", width: 1, alpha: 0.25 });
        F.line(d.x, d.y, { color: "#d62728", width: 1.3 }, 0, i + 1);
        const z = +this.zoomSel.value;
        if (fin(cx) && fin(cy)) {
          ctx.strokeStyle = "#1f5fa8"; ctx.lineWidth = 1.5;
          ctx.strokeRect(F.X(cx - z), F.Y(cy + z), F.X(cx + z) - F.X(cx - z), F.Y(cy - z) - F.Y(cy + z));
        }
        const ov = drawPlatform(F, d.x[i], d.y[i], d.yaw[i], tr, { color: "#d62728", fill: "rgba(214,39,40,0.15)" });
        this.overPx = ov && ov.cg;
        if (hasT) drawPlatform(F, tr.tx[i], tr.ty[i], tr.tyaw[i], tr, { color: "#111", fill: "rgba(0,0,0,0.08)" });
        ctx.restore();
      }
      // close-up, centred on the true pose (the estimate when there is no reference)
      {
        const { ctx, w, h } = canvasCtx(this.cvClose);
        const z = +this.zoomSel.value, c0 = [fin(cx) ? cx : 0, fin(cy) ? cy : 0];
        const F = new Frame(ctx, plotBox(w, h), [c0[0] - z, c0[0] + z], [c0[1] - z, c0[1] + z], true);
        F.axes(xl, yl, { title: "close-up at t = " + (t[i] + tr.t0).toFixed(1) + " s" });
        F.clip();
        const a = Math.max(0, i - 400);
        if (hasT) F.line(tr.tx, tr.ty, { color: "#111", width: 1.2, alpha: 0.5 }, a, i + 1);
        F.line(d.x, d.y, { color: "#d62728", width: 1.2, alpha: 0.6 }, a, i + 1);
        if (obs) {
          const xs = [], ys = [];
          for (let j = 0; j < m; j++) { xs.push(obs.o[(i * m + j) * 2]); ys.push(obs.o[(i * m + j) * 2 + 1]); }
          F.dots(xs, ys, { color: "#9467bd", r: 3.5 });
        }
        let tp = null;
        if (hasT) tp = drawPlatform(F, tr.tx[i], tr.ty[i], tr.tyaw[i], tr, { color: "#111", fill: "rgba(0,0,0,0.08)" }, dead);
        const ep = drawPlatform(F, d.x[i], d.y[i], d.yaw[i], tr, { color: "#d62728", fill: "rgba(214,39,40,0.15)", dash: [5, 3] }, dead);
        if (!ep) { ctx.fillStyle = "#444"; ctx.font = "13px system-ui"; ctx.fillText("no estimate at this epoch", F.box.x + 8, F.box.y + 18); }
        this.px = { est: ep && ep.cg, truth: tp && tp.cg, estOutline: ep && ep.outline, truthOutline: tp && tp.outline };
        ctx.restore();
      }
      // error over time
      const bands = tr.turn, tl = "time (s)" + (tr.t0 ? " \u2212 " + tr.t0 : "");
      if (hasT) {
        timePlot(this.cvPos, t, [{ y: d.ex, color: "#1f77b4", width: 1 }, { y: d.ey, color: "#2ca02c", width: 1 }],
                 { i, bands, ylabel: "error (m)", title: "CG error, estimate \u2212 truth: x (blue), y (green)", xlabel: tl });
        timePlot(this.cvHead, t, [{ y: d.eh, color: "#d62728", width: 1, wrap: 360 }],
                 { i, bands, ylabel: "error (deg)", title: "heading error, estimate \u2212 truth (wrapped)", yr: [-180, 180], xlabel: tl });
      } else {
        timePlot(this.cvPos, t, [{ y: d.x, color: "#1f77b4" }, { y: d.y, color: "#2ca02c" }],
                 { i, bands, xlabel: tl, ylabel: "position (m)" + (xoff || yoff ? " \u2212 origin" : ""),
                   title: "estimate x (blue), y (green); this source has no reference, so no error" });
        const hd = d.yaw.map((v) => v * DEG);
        timePlot(this.cvHead, t, [{ y: hd, color: "#d62728", width: 1, wrap: 360 }], { i, bands, xlabel: tl, ylabel: "heading (deg)", title: "estimated heading", yr: [-180, 180] });
      }
      const e = fin(d.x[i]) ? `estimate (${(d.x[i] + xoff).toFixed(2)}, ${(d.y[i] + yoff).toFixed(2)}) m, ${(d.yaw[i] * DEG).toFixed(1)}\u00B0` : "no estimate";
      const tt = hasT ? ` \u00B7 error x ${d.ex[i].toFixed(2)} m, y ${d.ey[i].toFixed(2)} m, heading ${d.eh[i].toFixed(1)}\u00B0` : "";
      this.tlabel.textContent = `t = ${(t[i] + tr.t0).toFixed(1)} s (${i + 1}/${t.length}) \u00B7 ${e}${fin(d.x[i]) ? tt : ""}`;
    }
    state() {
      const d = this.cell._d, i = this.i, tr = this.tr;
      return { key: this.cell.key, axes: this.cell.axes, index: i, n: tr.tt.length, t: tr.tt[i] + tr.t0,
               est: [d.x[i], d.y[i], d.yaw[i]], truth: tr.tx ? [tr.tx[i], tr.ty[i], tr.tyaw[i]] : null,
               estPx: this.px.est, truthPx: this.px.truth, overviewPx: this.overPx,
               estOutlinePx: this.px.estOutline, truthOutlinePx: this.px.truthOutline };
    }
  }

  // ------------------------------------------------------------------ ultrasonic flight
  class FlightReplay extends Player {
    constructor(root, f) {
      super(root);
      this.f = f;
      const g = (o) => o ? { x: f32(o.x), y: f32(o.y), z: f32(o.z) } : null;
      this.tt = f32(f.t);
      this.tru = { front: g(f.truth.front), rear: g(f.truth.rear), yaw: f32(f.truth.yaw) };
      this.est = { front: g(f.est.front), rear: g(f.est.rear), cmd: g(f.est.cmd), yaw: f32(f.est.yaw) };
      this.rng = {};
      for (const k of ["true", "raw", "gated"]) {
        this.rng[k] = {}; for (const [nm, s] of Object.entries(f.ranges[k] || {})) this.rng[k][nm] = f32(s);
      }
      const ctl = el("div", { class: "controls" }, root);
      const rl = el("label", { text: "receiver (range plot)" }, ctl);
      this.rxSel = el("select", { class: "receiver" }, rl);
      for (const nm of f.ranges.names) el("option", { value: nm, text: nm + (f.receivers.used.includes(nm) ? " (used)" : "") }, this.rxSel);
      this.rxSel.value = f.receivers.used[0] || f.ranges.names[0];
      this.rxSel.addEventListener("change", () => this.draw());
      legend(root, [["true transmitters (front \u25CF green, rear \u25CF red) and path", "#111"],
                    ["Kalman estimate of both transmitters", "#d62728"], ["gated CMD fix (front, before the Kalman filter)", "#ff7f0e", "dot"],
                    ["receivers (filled = used for trilateration)", "#1f5fa8", "dot"],
                    ["range rays to the front transmitter: gated (blue), raw (orange dashed) where they differ", "#1f77b4"]]);
      const views = el("div", { class: "views" }, root);
      this.cvTop = el("canvas", { class: "overview" }, views);
      this.cvSide = el("canvas", { class: "closeup" }, views);
      root.appendChild(this.bar);
      const plots = el("div", { class: "plots" }, root);
      this.cvRng = this.addPlot(plots); this.cvErr = this.addPlot(plots); this.cvHead = this.addPlot(plots);
      this.setSpeeds([0.25, 1, 2, 5], 1);
      this.setTimes(this.tt);
      this.draw();
    }
    draw() {
      const f = this.f, i = this.i, t = this.tt, T = this.tru, E = this.est;
      const R = f.receivers, used = new Set(R.used);
      const views = [[this.cvTop, "x", "y", "top view (x east, y north)"], [this.cvSide, "x", "z", "side view (x east, z up)"]];
      for (const [cv, ax, ay, title] of views) {
        const { ctx, w, h } = canvasCtx(cv);
        const xs = [T.front[ax], T.rear[ax], R.xyz.map((p) => p[ax === "x" ? 0 : 1])];
        const ys = [T.front[ay], T.rear[ay], R.xyz.map((p) => p[ay === "y" ? 1 : 2])];
        const F = new Frame(ctx, plotBox(w, h), range(xs, 0.08), range(ys, 0.08), true);
        F.axes(ax + (ax === "x" ? " east" : "") + " (m)", ay + (ay === "y" ? " north" : " up") + " (m)", { title });
        F.clip();
        F.line(T.front[ax], T.front[ay], { color: "#111", width: 1, alpha: 0.35 });
        if (E.front) F.line(E.front[ax], E.front[ay], { color: "#d62728", width: 1, alpha: 0.5 }, 0, i + 1);
        const ri = ay === "y" ? 1 : 2;
        const tf = [T.front.x[i], T.front.y[i], T.front.z[i]];
        // range rays: from each receiver towards the true front transmitter, as long as the range
        R.names.forEach((nm, k) => {
          const p = R.xyz[k], dv = [tf[0] - p[0], tf[1] - p[1], tf[2] - p[2]], dn = Math.hypot(...dv);
          const ray = (r, style) => {
            if (!fin(r) || !(dn > 0)) return;
            const q = [p[0] + dv[0] / dn * r, p[1] + dv[1] / dn * r, p[2] + dv[2] / dn * r];
            F.line([p[0], q[0]], [p[ri], q[ri]], style);
          };
          const raw = this.rng.raw[nm] ? this.rng.raw[nm][i] : NaN, gt = this.rng.gated[nm] ? this.rng.gated[nm][i] : NaN;
          ray(gt, { color: "#1f77b4", width: used.has(nm) ? 1.6 : 0.8, alpha: used.has(nm) ? 0.9 : 0.45 });
          if (fin(raw) && !(Math.abs(raw - gt) < 1e-9)) ray(raw, { color: "#ff7f0e", width: 1.4, dash: [5, 3] });
        });
        R.names.forEach((nm, k) => {
          const p = R.xyz[k]; ctx.save(); ctx.fillStyle = "#1f5fa8"; ctx.strokeStyle = "#1f5fa8";
          const px = F.X(p[0]), py = F.Y(p[ri]);
          ctx.beginPath(); ctx.moveTo(px, py - 6); ctx.lineTo(px - 5, py + 4); ctx.lineTo(px + 5, py + 4); ctx.closePath();
          if (used.has(nm)) ctx.fill(); else { ctx.fillStyle = "#fff"; ctx.fill(); ctx.stroke(); }
          ctx.fillStyle = "#1f5fa8"; ctx.font = "11px system-ui"; ctx.fillText(nm, px + 6, py + 12); ctx.restore();
        });
        const pair = (P, color, dash, px) => {
          if (!P.front || !fin(P.front.x[i])) return null;
          const a = [P.front[ax][i], P.front[ay][i]], b = [P.rear[ax][i], P.rear[ay][i]];
          ctx.save(); ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.setLineDash(dash);
          ctx.beginPath(); ctx.moveTo(F.X(b[0]), F.Y(b[1])); ctx.lineTo(F.X(a[0]), F.Y(a[1])); ctx.stroke(); ctx.setLineDash([]);
          for (const [q, col] of [[a, px ? "#2ca02c" : color], [b, px ? "#d62728" : color]]) {
            ctx.fillStyle = col; ctx.beginPath(); ctx.arc(F.X(q[0]), F.Y(q[1]), 5, 0, 2 * Math.PI); ctx.fill();
          }
          ctx.restore();
          return [F.X(a[0]), F.Y(a[1])];
        };
        if (E.cmd) F.dots([E.cmd[ax][i]], [E.cmd[ay][i]], { color: "#ff7f0e", r: 3.5 });
        const tp = pair(T, "#111", [], true), ep = pair(E, "#d62728", [4, 3], false);
        if (ax === "x" && ay === "y") this.px = { truth: tp, est: ep };
        ctx.restore();
      }
      const nm = this.rxSel.value;
      timePlot(this.cvRng, t, [
        { y: this.rng.true[nm], color: "#111", width: 5, alpha: 0.2 },
        { y: this.rng.raw[nm], color: "#ff7f0e", dots: true, r: 1.5 },
        { y: this.rng.gated[nm], color: "#1f77b4", width: 2 }],
        { i, ylabel: "range (m)", title: `range ${nm} \u2192 front transmitter: raw (orange dots), gated (blue), true (grey band)` });
      if (E.front) {
        const ex = [], ey = [], ez = [];
        for (let k = 0; k < t.length; k++) {
          ex.push(E.front.x[k] - T.front.x[k]); ey.push(E.front.y[k] - T.front.y[k]); ez.push(E.front.z[k] - T.front.z[k]);
        }
        timePlot(this.cvErr, t, [{ y: ex, color: "#1f77b4" }, { y: ey, color: "#2ca02c" }, { y: ez, color: "#9467bd" }],
                 { i, ylabel: "error (m)", title: "front transmitter, Kalman estimate \u2212 truth: x (blue), y (green), z (purple)" });
      }
      if (E.yaw) {
        const eh = []; for (let k = 0; k < t.length; k++) eh.push(wrapPi(E.yaw[k] - T.yaw[k]) * DEG);
        timePlot(this.cvHead, t, [{ y: eh, color: "#d62728", wrap: 360 }], { i, ylabel: "error (deg)", title: "heading error, filtered \u2212 true (wrapped)" });
      }
      this.tlabel.textContent = `t = ${(t[i] + f.t0).toFixed(2)} s (${i + 1}/${t.length})`;
    }
    state() {
      const i = this.i;
      return { index: i, n: this.tt.length, t: this.tt[i] + this.f.t0, truthPx: this.px.truth, estPx: this.px.est,
               front: [this.tru.front.x[i], this.tru.front.y[i], this.tru.front.z[i]] };
    }
  }

  // ------------------------------------------------------------------ wiring
  function start() {
    (DATA.gps || []).forEach((src, k) => {
      const root = document.getElementById("replay-" + k);
      if (root) API.gps.push(new GpsReplay(root, src, k));
    });
    const fr = document.getElementById("flight-replay");
    if (fr && DATA.flight) API.flight = new FlightReplay(fr, DATA.flight);
    API.ready = true;
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start); else start();
})();
