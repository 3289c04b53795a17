// Curio operator dashboard — people (issue 14): the people the rover tracks from its lidar
// (orange discs, a velocity arrow showing where each walks in the next second, the track's id)
// and, in simulation, the true visitors (grey rings) — one map layer, switched in Layers.
// Frames: "people" {tracks: [{id, x, y, vx, vy, std, moving}]} and "people_truth" {people:
// [{id, x, y, vx, vy, r}]} on the hub's socket; map frame, metres and m/s.
"use strict";

(() => {
  const C = window.curio;
  const { $ } = C;
  const P = { tracks: [], truth: [], rxTracks: 0, rxTruth: 0, frames: 0, drawn: [] };
  C.P = P;
  const FRESH_MS = 3000;  // older frames are not drawn (the rover stopped tracking)

  C.on("people", (m) => { P.tracks = m.tracks || []; P.rxTracks = Date.now(); P.frames += 1; C.view.dirty = true; });
  C.on("people_truth", (m) => { P.truth = m.people || []; P.rxTruth = Date.now(); C.view.dirty = true; });

  const show = () => $("showPeople").checked;
  C.mapLayers.push((ctx, kit) => {
    P.drawn = [];  // where the last drawing put each track (CSS px on the canvas)
    if (!show()) return;
    const now = Date.now(), scale = C.view.scale;
    if (now - P.rxTruth < FRESH_MS) {
      ctx.setLineDash([4, 3]); ctx.lineWidth = 1.5; ctx.strokeStyle = "rgba(55,65,81,.8)";
      for (const p of P.truth) {
        const [sx, sy] = kit.toScreen(p.x, p.y);
        ctx.beginPath(); ctx.arc(sx, sy, Math.max(3, (p.r || 0.25) * scale), 0, 2 * Math.PI);
        ctx.fillStyle = "rgba(107,114,128,.18)"; ctx.fill(); ctx.stroke();
      }
      ctx.setLineDash([]);
    }
    if (now - P.rxTracks >= FRESH_MS) return;
    for (const t of P.tracks) {
      const [sx, sy] = kit.toScreen(t.x, t.y);
      P.drawn.push([sx, sy]);
      ctx.beginPath(); ctx.arc(sx, sy, Math.max(4, 0.2 * scale), 0, 2 * Math.PI);
      ctx.fillStyle = t.moving ? "rgba(234,88,12,.75)" : "rgba(234,88,12,.45)"; ctx.fill();
      ctx.strokeStyle = "#9a3412"; ctx.lineWidth = 1.5; ctx.stroke();
      const speed = Math.hypot(t.vx, t.vy);
      if (speed > 0.1) kit.drawHeading(t.x, t.y, Math.atan2(t.vy, t.vx), "#c2410c", speed * scale);  // where it is in 1 s
      if (scale > 25) {
        ctx.font = "bold 10px system-ui, sans-serif"; ctx.fillStyle = "#7c2d12";
        ctx.fillText("P" + t.id, sx + 6, sy - 6);
      }
    }
  });

  // A layer switch and the legend's entries.
  const lab = document.createElement("label");
  const box = document.createElement("input");
  box.type = "checkbox"; box.id = "showPeople"; box.checked = true;
  try { const v = localStorage.getItem("curio.showPeople"); if (v !== null) box.checked = v === "1"; } catch (e) { /* ignore */ }
  box.addEventListener("change", () => { try { localStorage.setItem("curio.showPeople", box.checked ? "1" : "0"); } catch (e) { /* ignore */ } C.view.dirty = true; });
  lab.append(box, " people");
  document.querySelector("#layers .layerList").appendChild(lab);
  for (const [cls, text] of [["person", "person (tracked)"], ["visitor", "visitor (sim truth)"]]) {
    const span = document.createElement("span"), i = document.createElement("i");
    i.className = "sw " + cls; span.append(i, text); $("legend").appendChild(span);
  }
})();
