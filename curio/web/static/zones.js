// Curio operator dashboard — zones (issue 11): keep-out zones (red) and speed-limit zones
// (amber, with their limit) drawn on the map, and their editor for operators with the `zones`
// permission: "Draw a zone", click the corners on the map, click the first corner (or Finish)
// to close it, choose the kind and the limit, Save; choose a zone (in the list or on the map)
// to delete it; export the Nav2 filter masks. A zone the rover refuses shows its sentence.
// Polygons in the map frame, metres; limits in m/s.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const Z = { map: null, revision: null, zones: [], draft: null, selected: null, off: "" };
  C.Z = Z;

  const { el, button, row } = C.uiKit;  // (unattended.js)
  const msg = (text, kind, s) => C.showMsg($("zMsg"), text, kind, s);

  // ----- data -----------------------------------------------------------------------------------------------
  async function load() {
    try {
      setData(await C.api("GET", "/api/zones"));
      Z.off = "";
    } catch (e) { Z.off = e.message; Z.zones = []; }
    renderList();
  }
  function setData(d) {
    Z.map = d.map; Z.revision = d.revision; Z.zones = d.zones || [];
    if (Z.selected !== null && !Z.zones.some((z) => z.id === Z.selected)) Z.selected = null;
    renderList(); C.view.dirty = true;
  }
  C.on("u:zones", (m) => { if (m.msg && m.msg.detail) setData(m.msg.detail); });

  // ----- the card ---------------------------------------------------------------------------------------------
  function buildCard() {
    const card = $("zonesCard");
    const sum = el("summary", null, null, "Zones ");
    sum.appendChild(el("span", "zSummary", "small"));
    const draw = button("zDraw", "✎ Draw a zone", "then click the zone's corners on the map; click the first corner to close it");
    const del = button("zDelete", "Delete", "delete the chosen zone", "danger");
    const form = el("div", "zForm", "zForm hidden");
    const grid = el("div", null, "grid2");
    const lName = el("label", null, null, "Name"), name = el("input", "zName");
    name.placeholder = "e.g. Staff door"; lName.appendChild(name);
    const lKind = el("label", null, null, "Kind"), kind = el("select", "zKind");
    for (const [v, t] of [["keepout", "keep out"], ["speed", "speed limit"]]) { const o = el("option", null, null, t); o.value = v; kind.appendChild(o); }
    lKind.appendChild(kind);
    const lSpeed = el("label", "zSpeedLabel", "hidden", "Limit, m/s"), speed = el("input", "zSpeed");
    speed.type = "number"; speed.step = "0.05"; speed.min = "0.05"; speed.value = "0.2"; speed.inputMode = "decimal";
    lSpeed.appendChild(speed);
    grid.append(lName, lKind, lSpeed);
    const finish = button("zFinish", "Finish shape"), undo = button("zUndo", "Undo corner"),
      save = button("zSave", "Save zone", null, "primary"), cancel = button("zCancel", "Cancel");
    form.append(grid, el("div", "zDraftText", "small"), row(finish, undo, save, cancel));
    const exp = button("zExport", "Export Nav2 masks", "write the keep-out and speed filter masks (map_server YAML + PGM) beside the zone file");
    card.append(sum, el("ul", "zList", "zList"), row(draw, del), form, row(exp), el("div", "zMsg", "msg"), el("div", "zFiles", "small mono"));

    kind.addEventListener("change", () => $("zSpeedLabel").classList.toggle("hidden", kind.value !== "speed"));
    draw.addEventListener("click", startDraft);
    del.addEventListener("click", deleteSelected);
    finish.addEventListener("click", finishDraft);
    undo.addEventListener("click", () => { if (Z.draft && Z.draft.points.length) { Z.draft.points.pop(); Z.draft.closed = false; renderDraft(); } });
    save.addEventListener("click", saveDraft);
    cancel.addEventListener("click", cancelDraft);
    exp.addEventListener("click", exportMasks);
    card.addEventListener("toggle", () => { if (card.open) load(); });
  }

  const zoneText = (z) => z.name + " — " + (z.kind === "keepout" ? "keep out" : "at most " + Number(z.speed_limit_mps).toFixed(2) + " m/s");
  function renderList() {
    const ul = $("zList");
    ul.textContent = "";
    if (Z.off) { ul.appendChild(el("li", null, "small", Z.off)); }
    else if (!Z.zones.length) ul.appendChild(el("li", null, "small", "No zones on this map yet."));
    for (const z of Z.zones) {
      const li = el("li", null, "zItem" + (z.id === Z.selected ? " selected" : ""));
      li.dataset.id = String(z.id);
      const sw = el("i", null, "sw " + (z.kind === "keepout" ? "keepout" : "speedz"));
      const b = el("button", null, "zPick", zoneText(z));
      b.type = "button"; b.title = "show this zone on the map";
      b.addEventListener("click", () => select(z.id === Z.selected ? null : z.id));
      li.append(sw, b);
      ul.appendChild(li);
    }
    const n = Z.zones.length;
    $("zSummary").textContent = Z.off ? "· off" : "· " + n + (n === 1 ? " zone" : " zones") + (Z.map ? " on " + Z.map : "");
    const edit = C.may("zones");
    $("zDraw").disabled = !edit || !!Z.draft || !!Z.off;
    $("zDelete").disabled = !edit || Z.selected === null;
    $("zExport").disabled = !C.may("data") || !!Z.off;
  }
  function select(id) {
    Z.selected = id;
    renderList(); C.view.dirty = true;
    const z = Z.zones.find((q) => q.id === id);
    if (z) msg("Chose “" + zoneText(z) + "”" + (C.may("zones") ? ": Delete removes it." : "."), "ok", 10);
  }

  // ----- drawing a new zone ---------------------------------------------------------------------------------------
  function startDraft() {
    if (!C.may("zones")) { msg(S.connected ? "Editing zones needs an operator token." : "Offline: nothing can be saved.", "error", 15); return; }
    Z.draft = { points: [], closed: false };
    Z.selected = null;
    $("zName").value = ""; $("zKind").value = "keepout"; $("zSpeedLabel").classList.add("hidden");
    C.setTool("zones");
    renderDraft();
  }
  function renderDraft() {
    const d = Z.draft;
    $("zForm").classList.toggle("hidden", !d);
    if (d) {
      const n = d.points.length;
      $("zDraftText").textContent = d.closed ? "Shape closed (" + n + " corners): name it, choose its kind, Save." :
        n === 0 ? "Click the map where the zone's first corner is." :
          n + " corner" + (n === 1 ? "" : "s") + (n >= 3 ? " — click the first corner (or Finish shape) to close it." : " — click the next corner.");
      $("zFinish").disabled = d.closed || n < 3;
      $("zUndo").disabled = n === 0;
      $("zSave").disabled = n < 3 || !C.may("zones");
    }
    renderList(); C.view.dirty = true;
  }
  function finishDraft() {
    if (!Z.draft || Z.draft.points.length < 3) { msg("A zone needs at least 3 corners.", "error", 10); return; }
    Z.draft.closed = true;
    C.setTool("look");
    renderDraft();
    $("zName").focus();
  }
  function cancelDraft() { Z.draft = null; if (C.tool === "zones") C.setTool("look"); renderDraft(); msg(""); }
  async function saveDraft() {
    const d = Z.draft;
    if (!d || d.points.length < 3) { msg("A zone needs at least 3 corners.", "error", 10); return; }
    const kind = $("zKind").value;
    const body = { name: $("zName").value.trim() || (kind === "keepout" ? "Keep out " : "Slow ") + (Z.zones.length + 1),
      kind, polygon: d.points.map(([x, y]) => [x, y]), revision: Z.revision };
    if (kind === "speed") body.speed_limit_mps = Number($("zSpeed").value);
    msg("Saving…", "wait");
    try {
      const z = await C.api("POST", "/api/zones", body);
      Z.draft = null;
      if (C.tool === "zones") C.setTool("look");
      await load();
      Z.selected = z.id;
      renderDraft();
      msg("Saved “" + zoneText(z) + "”: the planner, the controller and the safety stage honour it now.", "ok", 15);
    } catch (e) { msg(e.message, "error", 30); }  // the rover's own sentence (crossing edges, over home, …)
  }
  async function deleteSelected() {
    const z = Z.zones.find((q) => q.id === Z.selected);
    if (!z) { msg("Choose a zone first (in the list or on the map).", "error", 10); return; }
    if (!(await C.confirmBox("Delete the zone “" + z.name + "” for everyone?", "Delete", "Keep it"))) return;
    try {
      await C.api("DELETE", "/api/zones/" + z.id + "?revision=" + Z.revision);
      Z.selected = null;
      await load();
      msg("Deleted “" + z.name + "”.", "ok", 10);
    } catch (e) { msg(e.message, "error", 20); }
  }
  async function exportMasks() {
    msg("Writing the masks…", "wait");
    try {
      const out = await C.api("POST", "/api/zones/export");
      msg("Nav2 filter masks written on the rover (costmap_filter_info_server + map_server):", "ok", 30);
      $("zFiles").textContent = out.files.join("\n");
    } catch (e) { msg(e.message, "error", 20); }
  }

  // ----- the map tool: click corners; outside a drawing, a click chooses the zone under it -------------------------
  function inside(poly, x, y) {
    let c = false;
    for (let i = 0, j = poly.length - 1; i < poly.length; j = i++) {
      const [xi, yi] = poly[i], [xj, yj] = poly[j];
      if ((yi > y) !== (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi) c = !c;
    }
    return c;
  }
  C.mapTools.zones = {
    hint: "Click the zone's corners · click the first corner to close it · outside a drawing, click a zone to choose it.",
    hit(sx, sy) {
      const d = Z.draft;
      if (!d || d.closed || d.points.length < 3) return null;
      const [fx, fy] = C.toScreen(d.points[0][0], d.points[0][1]);
      return Math.hypot(fx - sx, fy - sy) <= 12 ? { kind: "close", index: 0 } : null;
    },
    onSelect() { $("zonesCard").open = true; C.view.dirty = true; },
    onAction(kind, x, y) {
      const d = Z.draft;
      if (d && !d.closed) {
        if (kind === "close") { finishDraft(); return; }
        d.points.push([x, y]);
        renderDraft();
        return;
      }
      const z = Z.zones.slice().reverse().find((q) => inside(q.polygon, x, y));
      select(z ? z.id : null);
    },
  };

  // ----- the layer ---------------------------------------------------------------------------------------------------
  const show = () => $("showZones").checked;
  function path(ctx, kit, pts, close) {
    ctx.beginPath();
    pts.forEach(([x, y], i) => { const [sx, sy] = kit.toScreen(x, y); if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy); });
    if (close) ctx.closePath();
  }
  function label(ctx, kit, pts, text, color) {
    let mx = 0, my = 0;
    for (const [x, y] of pts) { mx += x; my += y; }
    const [sx, sy] = kit.toScreen(mx / pts.length, my / pts.length);
    ctx.font = "bold 12px system-ui, sans-serif";
    const w = ctx.measureText(text).width;
    ctx.fillStyle = "rgba(255,255,255,.85)"; ctx.fillRect(sx - w / 2 - 4, sy - 9, w + 8, 18);
    ctx.fillStyle = color; ctx.fillText(text, sx - w / 2, sy + 4);
  }
  C.mapLayers.push((ctx, kit) => {
    if (show() || Z.draft) {
      for (const z of Z.zones) {
        const keep = z.kind === "keepout", sel = z.id === Z.selected;
        path(ctx, kit, z.polygon, true);
        ctx.fillStyle = keep ? "rgba(220,38,38,.22)" : "rgba(234,179,8,.25)"; ctx.fill();
        ctx.strokeStyle = keep ? "#b91c1c" : "#a16207"; ctx.lineWidth = sel ? 4 : 2;
        ctx.setLineDash(keep ? [] : [8, 4]); ctx.stroke(); ctx.setLineDash([]);
        label(ctx, kit, z.polygon, keep ? "keep out: " + z.name : "≤ " + Number(z.speed_limit_mps).toFixed(2) + " m/s", keep ? "#991b1b" : "#854d0e");
      }
    }
    const d = Z.draft;
    if (d && d.points.length) {
      path(ctx, kit, d.points, d.closed);
      if (d.closed) { ctx.fillStyle = "rgba(37,99,235,.15)"; ctx.fill(); }
      ctx.strokeStyle = "#1d4ed8"; ctx.lineWidth = 2.5; ctx.stroke();
      d.points.forEach(([x, y], i) => kit.drawMarker(x, y, i === 0 ? "#1d4ed8" : "#3b82f6", i === 0 ? "1" : "", i === 0 ? 8 : 5));
    }
  });

  // A layer switch and the legend's entries.
  const lab = el("label");
  const box = el("input", "showZones");
  box.type = "checkbox"; box.checked = true;
  try { const v = localStorage.getItem("curio.showZones"); if (v !== null) box.checked = v === "1"; } catch (e) { /* ignore */ }
  box.addEventListener("change", () => { try { localStorage.setItem("curio.showZones", box.checked ? "1" : "0"); } catch (e) { /* ignore */ } C.view.dirty = true; });
  lab.append(box, " zones");
  document.querySelector("#layers .layerList").appendChild(lab);
  for (const [cls, text] of [["keepout", "keep-out zone"], ["speedz", "speed zone"]]) {
    const span = el("span"); span.append(el("i", null, "sw " + cls), text); $("legend").appendChild(span);
  }

  buildCard();
  C.on("hello", () => renderList());  // who may edit
  C.on("state", () => load());
  setInterval(() => { if (!Z.draft) renderList(); }, 2000);
})();
