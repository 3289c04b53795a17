// Curio — a small bar chart on a canvas (no library, no CDN): days along x, one bar per day
// (stacked series or a single one), a y axis with round ticks, day labels thinned to fit, a
// legend, a value label for a single series, and "no data" days drawn as a faint dash. Sharp on
// high-density screens; redrawn when the canvas changes size.
"use strict";

(() => {
  const C = window.curio = window.curio || {};

  function niceMax(v) {
    if (!(v > 0)) return 1;
    const p = Math.pow(10, Math.floor(Math.log10(v)));
    for (const m of [1, 2, 2.5, 5, 10]) if (m * p >= v) return m * p;
    return 10 * p;
  }

  // spec: {labels: [..], series: [{name, color, values: [number|null]}], unit: "s", stacked: true,
  //        integer: true (counts: whole-number ticks)}
  function barChart(canvas, spec) {
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth, h = canvas.clientHeight;
    canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    ctx.font = "12px system-ui, sans-serif";
    const n = spec.labels.length;
    const totals = spec.labels.map((_, i) => spec.series.reduce((a, s) => a + (s.values[i] || 0), 0));
    let top = niceMax(Math.max(0, ...(spec.stacked ? totals : spec.series.flatMap((s) => s.values.map((v) => v || 0)))));
    if (spec.integer) top = Math.max(4, Math.ceil(top / 4) * 4);  // counts: whole ticks
    const tick = (k) => { const v = top * k / 4; return (Number.isInteger(v) ? String(v) : v.toFixed(1)) + (k === 4 && spec.unit ? " " + spec.unit : ""); };
    const tickW = Math.max(...[0, 1, 2, 3, 4].map((k) => ctx.measureText(tick(k)).width));
    const left = 8 + tickW + 6, right = 8, legendH = 22, bottom = 24;
    const plotW = Math.max(10, w - left - right), plotH = Math.max(10, h - legendH - bottom - 6);
    const y0 = legendH + plotH;
    // axis and grid
    ctx.strokeStyle = "#e5e7eb"; ctx.fillStyle = "#6b7280"; ctx.lineWidth = 1;
    ctx.textAlign = "right"; ctx.textBaseline = "middle";
    for (let k = 0; k <= 4; k++) {
      const y = Math.round(y0 - plotH * k / 4) + 0.5;
      ctx.beginPath(); ctx.moveTo(left, y); ctx.lineTo(left + plotW, y); ctx.stroke();
      ctx.fillText(tick(k), left - 4, y);
    }
    // bars
    const slot = plotW / Math.max(1, n), barW = Math.max(2, Math.min(40, slot * 0.7));
    const dayW = Math.max(...spec.labels.map((l) => ctx.measureText(l).width), 1) + 8;
    const every = Math.max(1, Math.ceil(n / Math.max(1, Math.floor(plotW / dayW))));
    let lastLabelX = -Infinity;
    ctx.textAlign = "center"; ctx.textBaseline = "top";
    for (let i = 0; i < n; i++) {
      const cx = left + slot * (i + 0.5);
      let base = y0;
      let any = false;
      for (const s of spec.series) {
        const v = s.values[i];
        if (v === null || v === undefined) continue;
        any = true;
        const bh = plotH * v / top;
        ctx.fillStyle = s.color;
        ctx.fillRect(cx - barW / 2, base - bh, barW, bh);
        if (!spec.stacked && spec.series.length === 1 && v > 0) {
          ctx.fillStyle = "#111827"; ctx.textBaseline = "bottom";
          ctx.fillText(Math.round(v) + (spec.unit || ""), cx, base - bh - 1);
          ctx.textBaseline = "top";
        }
        if (spec.stacked) base -= bh;
      }
      if (!any) { ctx.fillStyle = "#cbd5e1"; ctx.fillRect(cx - barW / 4, y0 - 2, barW / 2, 2); }
      if ((i % every === 0 || i === n - 1) && cx - lastLabelX >= dayW) {  // never overlapping
        ctx.fillStyle = "#6b7280";
        ctx.fillText(spec.labels[i], cx, y0 + 5);
        lastLabelX = cx;
      }
    }
    ctx.strokeStyle = "#9ca3af";
    ctx.beginPath(); ctx.moveTo(left, y0 + 0.5); ctx.lineTo(left + plotW, y0 + 0.5); ctx.stroke();
    // legend
    ctx.textAlign = "left"; ctx.textBaseline = "middle";
    let lx = left;
    for (const s of spec.series) {
      ctx.fillStyle = s.color; ctx.fillRect(lx, 6, 12, 12);
      ctx.fillStyle = "#374151"; ctx.fillText(s.name, lx + 16, 12);
      lx += 16 + ctx.measureText(s.name).width + 14;
    }
  }

  C.barChart = barChart;
})();
