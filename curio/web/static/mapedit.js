// Curio — a map's cells on a canvas: the grid as the rover sends it (/api/maps/{name}/cells,
// /api/maps/live: one byte per cell, rows from the bottom, 0..100 occupancy, 255 unknown), a
// view that pans and zooms (wheel, drag with Pan, two fingers), and the cell editor: a brush
// that paints free / occupied / unknown cells, undo and redo of whole strokes, and the changes
// as runs [row, col, length, value] for the save. Used by maps.js.
"use strict";

(() => {
  const C = window.curio;
  const UNKNOWN = 255;

  function decode(b64) {
    const s = atob(b64);
    const a = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) a[i] = s.charCodeAt(i);
    return a;
  }

  function shade(v, out, j) {  // one cell's colour into an RGBA buffer
    if (v === UNKNOWN) { out[j] = 203; out[j + 1] = 213; out[j + 2] = 225; }
    else {  // as the rover reads it: free up to 19 (free_thresh), occupied from 65, grey between
      const g = v <= 19 ? 255 - v : v >= 65 ? 40 - Math.round((v - 65) * 0.6) : 200 - Math.round((v - 20) * 1.6);
      out[j] = g; out[j + 1] = g; out[j + 2] = g;
    }
    out[j + 3] = 255;
  }

  // The grid as an offscreen canvas (one pixel per cell, the top row of the image = the top of the map).
  class GridImage {
    constructor(grid) {
      this.w = grid.width; this.h = grid.height; this.res = grid.resolution_m; this.origin = grid.origin;
      this.cells = decode(grid.cells);
      this.canvas = document.createElement("canvas");
      this.canvas.width = this.w; this.canvas.height = this.h;
      this.ctx = this.canvas.getContext("2d");
      this.img = this.ctx.createImageData(this.w, this.h);
      this.redraw(0, 0, this.w - 1, this.h - 1);
    }
    index(col, row) { return row * this.w + col; }  // row 0 = bottom
    redraw(c0, r0, c1, r1) {  // cells (c0..c1, r0..r1) into the image
      const d = this.img.data;
      for (let r = r0; r <= r1; r++) {
        const y = this.h - 1 - r;
        for (let c = c0; c <= c1; c++) shade(this.cells[r * this.w + c], d, (y * this.w + c) * 4);
      }
      this.ctx.putImageData(this.img, 0, 0, c0, this.h - 1 - r1, c1 - c0 + 1, r1 - r0 + 1);
    }
    toMap(col, row) {  // a cell's centre in the map frame, metres (the grid's yaw applied)
      const lx = (col + 0.5) * this.res, ly = (row + 0.5) * this.res;
      const [ox, oy, yaw] = this.origin, c = Math.cos(yaw), s = Math.sin(yaw);
      return [ox + c * lx - s * ly, oy + s * lx + c * ly];
    }
    fromMap(x, y) {  // map metres → (col, row) as fractions
      const [ox, oy, yaw] = this.origin, c = Math.cos(yaw), s = Math.sin(yaw);
      const dx = x - ox, dy = y - oy;
      return [(c * dx + s * dy) / this.res, (-s * dx + c * dy) / this.res];
    }
  }

  // A canvas showing a GridImage: scale in CSS pixels per cell, centre in image pixels.
  class GridView {
    constructor(canvas) {
      this.canvas = canvas; this.ctx = canvas.getContext("2d");
      this.grid = null; this.scale = 1; this.cx = 0; this.cy = 0; this.marker = null;
      this.pointers = new Map(); this.pinch = null;
      canvas.addEventListener("wheel", (e) => {
        if (!this.grid) return;
        e.preventDefault();
        this.zoomAt(e.offsetX, e.offsetY, e.deltaY < 0 ? 1.25 : 0.8);
      }, { passive: false });
      new ResizeObserver(() => this.draw()).observe(canvas);
    }
    show(grid, keepView) {
      const first = !this.grid || this.grid.w !== grid.w || this.grid.h !== grid.h;
      this.grid = grid;
      if (first || !keepView) this.fit();
      this.draw();
    }
    fit() {
      const g = this.grid, W = this.canvas.clientWidth || 300, H = this.canvas.clientHeight || 200;
      this.scale = Math.min(W / g.w, H / g.h) * 0.96;
      this.cx = g.w / 2; this.cy = g.h / 2;
      this.draw();
    }
    zoomAt(px, py, factor) {
      const [ix, iy] = this.toImage(px, py);
      this.scale = Math.max(0.2, Math.min(60, this.scale * factor));
      const W = this.canvas.clientWidth, H = this.canvas.clientHeight;
      this.cx = ix - (px - W / 2) / this.scale; this.cy = iy - (py - H / 2) / this.scale;
      this.draw();
    }
    toImage(px, py) {  // CSS pixels on the canvas → image pixels (fractions)
      const W = this.canvas.clientWidth, H = this.canvas.clientHeight;
      return [(px - W / 2) / this.scale + this.cx, (py - H / 2) / this.scale + this.cy];
    }
    toCell(px, py) {  // → [col, row] (row 0 at the bottom), integers
      const [ix, iy] = this.toImage(px, py);
      return [Math.floor(ix), this.grid.h - 1 - Math.floor(iy)];
    }
    draw() {
      const cv = this.canvas, dpr = window.devicePixelRatio || 1;
      const W = cv.clientWidth, H = cv.clientHeight;
      if (cv.width !== Math.round(W * dpr) || cv.height !== Math.round(H * dpr)) {
        cv.width = Math.round(W * dpr); cv.height = Math.round(H * dpr);
      }
      const ctx = this.ctx;
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.fillStyle = "#e5e7eb"; ctx.fillRect(0, 0, cv.width, cv.height);
      if (!this.grid) return;
      const s = this.scale * dpr;
      ctx.setTransform(s, 0, 0, s, dpr * (W / 2 - this.cx * this.scale), dpr * (H / 2 - this.cy * this.scale));
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(this.grid.canvas, 0, 0);
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      if (this.marker) {  // the rover: a blue dot with its heading
        const [col, row] = this.grid.fromMap(this.marker[0], this.marker[1]);
        const x = dpr * (W / 2 + (col - this.cx) * this.scale), y = dpr * (H / 2 + (this.grid.h - row - this.cy) * this.scale);
        const r = 6 * dpr, yaw = this.marker[2] - this.grid.origin[2];
        ctx.fillStyle = "#2563eb"; ctx.strokeStyle = "#fff"; ctx.lineWidth = 2 * dpr;
        ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
        ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x + 2.2 * r * Math.cos(yaw), y - 2.2 * r * Math.sin(yaw)); ctx.stroke();
      }
    }
    // Two fingers (or Pan): move and zoom. Returns true when the pointer is used for that.
    panStart(e, always) {
      this.pointers.set(e.pointerId, [e.offsetX, e.offsetY]);
      if (this.pointers.size === 2) {
        const [a, b] = [...this.pointers.values()];
        this.pinch = { d: Math.hypot(a[0] - b[0], a[1] - b[1]), mx: (a[0] + b[0]) / 2, my: (a[1] + b[1]) / 2 };
        return true;
      }
      return always;
    }
    panMove(e) {
      const last = this.pointers.get(e.pointerId);
      if (!last) return;
      this.pointers.set(e.pointerId, [e.offsetX, e.offsetY]);
      if (this.pointers.size === 2 && this.pinch) {
        const [a, b] = [...this.pointers.values()];
        const d = Math.hypot(a[0] - b[0], a[1] - b[1]), mx = (a[0] + b[0]) / 2, my = (a[1] + b[1]) / 2;
        this.cx -= (mx - this.pinch.mx) / this.scale; this.cy -= (my - this.pinch.my) / this.scale;
        if (this.pinch.d > 0) this.zoomAt(mx, my, d / this.pinch.d);
        this.pinch = { d, mx, my };
      } else {
        this.cx -= (e.offsetX - last[0]) / this.scale; this.cy -= (e.offsetY - last[1]) / this.scale;
      }
      this.draw();
    }
    panEnd(e) { this.pointers.delete(e.pointerId); if (this.pointers.size < 2) this.pinch = null; }
  }

  // The editor: strokes of a brush on a GridImage, with undo and redo.
  class CellEditor {
    constructor(canvas, onChange) {
      this.view = new GridView(canvas);
      this.onChange = onChange || (() => {});
      this.tool = "0"; this.brush = 1; this.undoStack = []; this.redoStack = []; this.stroke = null;
      this.orig = null; this.meta = null; this.panning = false; this.last = null;
      canvas.addEventListener("pointerdown", (e) => this.down(e));
      canvas.addEventListener("pointermove", (e) => this.move(e));
      for (const t of ["pointerup", "pointercancel", "pointerleave"]) canvas.addEventListener(t, (e) => this.up(e));
    }
    load(meta) {  // meta: the JSON of /api/maps/{name}/cells
      this.meta = meta;
      this.grid = new GridImage(meta);
      this.orig = this.grid.cells.slice();
      this.undoStack = []; this.redoStack = []; this.stroke = null;
      this.view.show(this.grid, false);
      this.onChange();
    }
    get value() { return this.tool === "-1" ? UNKNOWN : Number(this.tool); }
    down(e) {
      if (!this.grid) return;
      e.preventDefault();
      this.view.canvas.setPointerCapture(e.pointerId);
      if (this.view.panStart(e, this.tool === "pan" || e.button !== 0)) {
        this.panning = true;
        if (this.stroke) this.endStroke();  // a second finger: the first one's stroke ends
        return;
      }
      this.stroke = new Map();  // cell index → [before, after]
      this.last = this.view.toCell(e.offsetX, e.offsetY);
      this.dab(this.last[0], this.last[1]);
    }
    move(e) {
      if (this.grid) {
        const [col, row] = this.view.toCell(e.offsetX, e.offsetY);
        const inside = col >= 0 && row >= 0 && col < this.grid.w && row < this.grid.h;
        const [x, y] = this.grid.toMap(col, row);
        C.$("edCursor").textContent = inside ? "x " + x.toFixed(2) + " m, y " + y.toFixed(2) + " m (cell " + col + ", " + row + ")" : "outside the map";
      }
      if (this.panning) { this.view.panMove(e); return; }
      if (!this.stroke) return;
      const to = this.view.toCell(e.offsetX, e.offsetY);
      const [c0, r0] = this.last, n = Math.max(Math.abs(to[0] - c0), Math.abs(to[1] - r0), 1);
      for (let i = 1; i <= n; i++) this.dab(Math.round(c0 + (to[0] - c0) * i / n), Math.round(r0 + (to[1] - r0) * i / n));
      this.last = to;
    }
    up(e) {
      this.view.panEnd(e);
      if (this.panning) { if (this.view.pointers.size === 0) this.panning = false; return; }
      if (this.stroke) this.endStroke();
    }
    endStroke() {
      if (this.stroke.size) { this.undoStack.push(this.stroke); this.redoStack = []; }
      this.stroke = null;
      this.onChange();
    }
    dab(col, row) {  // paint a disc of radius `brush` cells
      const g = this.grid, b = this.brush, v = this.value;
      const c0 = Math.max(0, col - b), c1 = Math.min(g.w - 1, col + b), r0 = Math.max(0, row - b), r1 = Math.min(g.h - 1, row + b);
      if (c0 > c1 || r0 > r1) return;
      for (let r = r0; r <= r1; r++) {
        for (let c = c0; c <= c1; c++) {
          if ((c - col) ** 2 + (r - row) ** 2 > b * b + b) continue;
          const i = g.index(c, r), old = g.cells[i];
          if (old === v) continue;
          const was = this.stroke.get(i);
          this.stroke.set(i, [was ? was[0] : old, v]);
          g.cells[i] = v;
        }
      }
      g.redraw(c0, r0, c1, r1);
      this.view.draw();
    }
    apply(stroke, which) {  // which 0: before (undo), 1: after (redo)
      const g = this.grid;
      let c0 = g.w, r0 = g.h, c1 = -1, r1 = -1;
      for (const [i, pair] of stroke) {
        g.cells[i] = pair[which];
        const c = i % g.w, r = (i - c) / g.w;
        c0 = Math.min(c0, c); c1 = Math.max(c1, c); r0 = Math.min(r0, r); r1 = Math.max(r1, r);
      }
      if (c1 >= 0) g.redraw(c0, r0, c1, r1);
      this.view.draw();
      this.onChange();
    }
    markSaved() {  // the server kept the changes: nothing is unsaved any more
      if (!this.grid) return;
      this.orig = this.grid.cells.slice();
      this.undoStack = []; this.redoStack = [];
      this.onChange();
    }
    undo() { const s = this.undoStack.pop(); if (s) { this.redoStack.push(s); this.apply(s, 0); } }
    redo() { const s = this.redoStack.pop(); if (s) { this.undoStack.push(s); this.apply(s, 1); } }
    changedCount() {
      if (!this.grid) return 0;
      let n = 0;
      const a = this.grid.cells, o = this.orig;
      for (let i = 0; i < a.length; i++) if (a[i] !== o[i]) n++;
      return n;
    }
    runs() {  // what differs from the loaded revision, as [row, col, length, value] runs
      const g = this.grid, a = g.cells, o = this.orig, out = [];
      for (let r = 0; r < g.h; r++) {
        let c = 0;
        while (c < g.w) {
          const i = r * g.w + c;
          if (a[i] === o[i]) { c++; continue; }
          const v = a[i];
          let n = 1;
          while (c + n < g.w && a[i + n] === v && a[i + n] !== o[i + n]) n++;
          out.push([r, c, n, v === UNKNOWN ? -1 : v]);
          c += n;
        }
      }
      return out;
    }
  }

  Object.assign(C, { GridImage, GridView, CellEditor });
})();
