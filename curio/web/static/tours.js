// Curio operator dashboard — tours on the map: create, rename, offer at the kiosk, duplicate,
// delete; add a stop by clicking the map (drag to set the way it faces), drag a stop to move
// it, reorder, edit its dwell time and message; the route (home → stops → home) and its
// estimated duration are drawn before anything is saved. Every change is the rover's answer:
// the page shows the tour the rover returns, and a change made meanwhile by someone else is
// refused ("reload it and edit again") instead of overwriting theirs (revisions).
// Uses the map's tool machinery (C.mapTools, C.mapLayers) and the rover's events (C.on).
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const T = { list: [], selId: null, enabled: true, home: [0, 0], est: { speed_mps: 0.2, detour_factor: 1.4 },
    pending: null, editIndex: null, loaded: false, lastPreview: "" };

  const card = $("toursCard");
  const body = document.createElement("div");
  body.innerHTML = `
    <div class="row"><select id="tourSel" aria-label="tour to edit"></select><button id="tourNew" type="button">New tour</button></div>
    <div id="tourBody" class="hidden">
      <div class="row"><input id="tourName" placeholder="tour name" aria-label="tour name" maxlength="60"><button id="tourRename" type="button">Rename</button></div>
      <div class="row tourActions">
        <label class="check"><input type="checkbox" id="tourKiosk"> offered at the kiosk</label>
        <button id="tourStart" type="button" title="start this tour now">▶ Start</button>
      </div>
      <div class="row tourActions"><button id="tourDup" type="button">Duplicate</button><button id="tourDel" class="danger" type="button">Delete</button><button id="tourStop" type="button" class="hidden">■ Stop the tour</button></div>
      <div id="tourEstimate" class="estimate" aria-live="polite"></div>
      <ul id="tourProblems" class="problems"></ul>
      <div class="small">Choose <b>Stops</b> above the map: click to add a stop (drag to set the way the rover faces), drag a stop to move it, click one to edit it.</div>
      <ol id="tourStops" class="stops"></ol>
      <div id="stopEdit" class="stopEdit hidden">
        <div id="stopEditTitle" class="stopEditTitle"></div>
        <div class="grid2">
          <label>Name <input id="stopName" maxlength="60"></label>
          <label>Stay (s) <input id="stopDwell" type="number" min="0" max="3600" step="1" inputmode="numeric"></label>
          <label>Facing (°) <input id="stopYaw" type="number" min="-180" max="360" step="5" placeholder="any" inputmode="numeric"></label>
          <label>Language <input id="stopLang" placeholder="e.g. en, fr" maxlength="20"></label>
        </div>
        <label class="block">Message for visitors <textarea id="stopText" rows="3" maxlength="1000" placeholder="what the rover says and the kiosk shows here"></textarea></label>
        <div class="row"><button id="stopSave" type="button" class="primary">Add stop</button><button id="stopCancel" type="button">Cancel</button></div>
        <div id="stopEditMsg" class="msg" aria-live="polite"></div>
      </div>
    </div>
    <div id="tourMsg" class="msg" aria-live="polite"></div>`;
  card.appendChild(body);

  const legend = document.createElement("span");  // the stops in the map's legend
  legend.innerHTML = '<i class="sw stop"></i>tour stops';
  $("legend").appendChild(legend);

  // The "Stops" tool beside the other map tools.
  const toolBtn = document.createElement("button");
  toolBtn.className = "tool"; toolBtn.type = "button"; toolBtn.dataset.tool = "stops";
  toolBtn.textContent = "Stops";
  toolBtn.title = "tours: click to add a stop (drag for the way it faces), drag a stop to move it";
  $("toolbar").insertBefore(toolBtn, $("layers"));
  toolBtn.addEventListener("click", () => C.setTool("stops"));

  const selected = () => T.list.find((t) => t.id === T.selId) || null;
  const msg = (text, kind, after) => C.showMsg($("tourMsg"), text, kind, after === undefined ? 12 : after);
  const deg = (rad) => Math.round(rad * 180 / Math.PI);

  // ----- estimates: the server's formula, so a preview matches what is saved ------------------------
  function routeOf(stops) {
    const pts = [T.home];
    for (const s of stops) {
      const path = s.route_path_id === null || s.route_path_id === undefined ? null : S.paths.find((p) => p.id === s.route_path_id);
      if (path) for (const w of path.waypoints) pts.push([w.x_m, w.y_m]);
      pts.push([s.x_m, s.y_m]);
    }
    pts.push(T.home);
    return pts;
  }
  function estimateOf(stops) {
    const pts = routeOf(stops);
    let d = 0;
    for (let i = 1; i < pts.length; i++) d += Math.hypot(pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1]);
    const distance = d * T.est.detour_factor;
    const driving = distance / T.est.speed_mps;
    const dwell = stops.reduce((a, s) => a + (Number(s.dwell_s) || 0), 0);
    return { distance_m: distance, driving_s: driving, dwell_s: dwell, total_s: driving + dwell };
  }
  function fmtDur(s) {
    if (s < 90) return Math.round(s) + " s";
    if (s < 5400) return Math.round(s / 60) + " min";
    return (s / 3600).toFixed(1) + " h";
  }
  const estimateText = (e, n) => n + " stop" + (n === 1 ? "" : "s") + " · " + Math.round(e.distance_m) + " m · about " +
    fmtDur(e.total_s) + " (" + fmtDur(e.driving_s) + " driving, " + fmtDur(e.dwell_s) + " at stops), home to home";

  // ----- loading and rendering -----------------------------------------------------------------------
  async function load() {
    try {
      const data = await C.api("GET", "/api/tours");
      T.list = data.tours; T.enabled = data.enabled; T.home = data.home; T.est = data.estimate; T.loaded = true;
      if (T.selId === null || !selected()) {
        const running = T.list.find((t) => t.running);
        T.selId = running ? running.id : (T.list[0] ? T.list[0].id : null);
      }
      render();
      for (const fn of C.listeners.tours || []) fn({ t: "tours", tours: T.list });
    } catch (e) {
      msg(e.status === 503 ? "Tours are not available on this rover." : "Could not read the tours: " + e.message, "error", 0);
    }
  }

  function put(tour) {  // a tour as the rover returned it after an edit
    const i = T.list.findIndex((t) => t.id === tour.id);
    if (i >= 0) T.list[i] = tour; else T.list.push(tour);
    render();
  }

  function render() {
    const sel = $("tourSel");
    sel.textContent = "";
    const none = document.createElement("option");
    none.value = ""; none.textContent = T.list.length ? "— choose a tour —" : "— no tours yet —";
    sel.appendChild(none);
    for (const t of T.list) {
      const o = document.createElement("option");
      o.value = String(t.id);
      o.textContent = (t.running ? "▶ " : "") + t.name + " (" + t.stops.length + " stop" + (t.stops.length === 1 ? "" : "s") + ")";
      sel.appendChild(o);
    }
    sel.value = T.selId === null ? "" : String(T.selId);
    const t = selected();
    $("tourBody").classList.toggle("hidden", !t);
    const edit = C.may("tours");
    for (const id of ["tourNew", "tourRename", "tourDup", "tourDel", "tourKiosk"]) $(id).disabled = !edit;
    $("toursSummary").textContent = runningText() || (T.list.length ? "· " + T.list.length + " tour" + (T.list.length === 1 ? "" : "s") : "");
    if (t) renderTour(t, edit);
    C.view.dirty = true;
  }

  function runningText() {
    const r = S.tour;
    if (!r || r.tour_id === null || r.tour_id === undefined) return "";
    const at = r.stop_index !== null && r.stop_index !== undefined ? ": stop " + (r.stop_index + 1) + " of " + r.stops_total + (r.stop_name ? " (" + r.stop_name + ")" : "") : "";
    return "· ▶ " + r.name + at;
  }

  function renderTour(t, edit) {
    if (document.activeElement !== $("tourName")) $("tourName").value = t.name;
    $("tourKiosk").checked = !!t.kiosk;
    const running = S.tour && S.tour.tour_id === t.id;
    $("tourStart").disabled = !C.may("tour") || !!running || !t.stops.length;
    $("tourStop").classList.toggle("hidden", !running);
    $("tourStop").disabled = !C.may("tour");
    renderEstimate();
    const probs = $("tourProblems");
    probs.textContent = "";
    for (const p of t.problems || []) {
      const li = document.createElement("li");
      li.textContent = p;
      probs.appendChild(li);
    }
    if (!T.enabled) {
      const li = document.createElement("li");
      li.textContent = "This rover runs another behaviour tree: tours can be edited here but start only with bt.tree = \"tour\".";
      probs.appendChild(li);
    }
    const ol = $("tourStops");
    ol.textContent = "";
    t.stops.forEach((s, i) => {
      const li = document.createElement("li");
      li.dataset.index = String(i);
      if (i === T.editIndex) li.className = "editing";
      if (running && S.tour.stop_index === i) li.classList.add("current");
      const span = document.createElement("span");
      span.className = "stopText";
      span.textContent = s.name + " · " + Math.round(s.dwell_s) + " s" + (s.yaw_rad === null ? "" : " · facing " + deg(s.yaw_rad) + "°") +
        (s.message && s.message.text ? " · “" + s.message.text.slice(0, 40) + (s.message.text.length > 40 ? "…" : "") + "”" : "");
      span.title = "(" + s.x_m.toFixed(2) + ", " + s.y_m.toFixed(2) + ") m";
      li.appendChild(span);
      const btn = (label, title, disabled, fn) => {
        const b = document.createElement("button");
        b.type = "button"; b.textContent = label; b.title = title;
        b.disabled = disabled || !edit;
        b.addEventListener("click", fn);
        li.appendChild(b);
      };
      btn("↑", "visit earlier", i === 0, () => move(i, i - 1));
      btn("↓", "visit later", i === t.stops.length - 1, () => move(i, i + 1));
      btn("✎", "edit name, stay, message", false, () => openEditor(i));
      btn("×", "remove this stop", false, () => removeStop(i));
      ol.appendChild(li);
    });
  }

  function renderEstimate() {
    const t = selected();
    if (!t) return;
    const el = $("tourEstimate");
    if (T.pending && !T.pending.problem) {
      const stops = withPending(t.stops);
      const e = estimateOf(stops);
      el.textContent = "With the new stop: " + estimateText(e, stops.length) + " (now " + fmtDur(t.estimate.total_s) + ")";
      el.className = "estimate preview";
    } else {
      el.textContent = t.stops.length ? estimateText(t.estimate, t.stops.length) : "No stops yet.";
      el.className = "estimate";
    }
  }

  // The stops with the new one (a preview, before it is added); none where the rover cannot stand.
  const withPending = (stops) => (T.pending && !T.pending.problem ?
    stops.concat([{ x_m: T.pending.x, y_m: T.pending.y, dwell_s: Number($("stopDwell").value) || 0 }]) : stops);

  // ----- edits: each is saved at once and answered with the tour as the rover has it -------------------
  async function edit(method, suffix, body, okText, t) {
    const tour = t || selected();
    if (!tour) { msg("Choose a tour (or make a new one) first.", "error"); return null; }
    if (!C.may("tours")) { msg(S.connected ? "Editing tours needs an operator token." : "Offline: nothing was sent.", "error"); return null; }
    try {
      const out = await C.api(method, "/api/tours/" + tour.id + suffix, body);
      if (out && out.stops) put(out);
      if (okText) msg(okText, "ok", 8);
      return out || {};
    } catch (e) {
      msg(e.message, "error", 25);
      card.open = true;
      load();  // show the tour as it is now
      return null;
    }
  }
  const rev = () => (selected() ? selected().revision : undefined);

  function move(from, to) {
    edit("POST", "/order", { from, to, revision: rev() }, "Stop " + (from + 1) + " is now number " + (to + 1) + ".");
  }
  async function removeStop(i) {
    const t = selected();
    if (!(await C.confirmBox("Remove stop " + (i + 1) + " “" + t.stops[i].name + "” from “" + t.name + "”?", "Remove", "Keep it"))) return;
    if (T.editIndex === i) closeEditor();
    edit("DELETE", "/stops/" + i + "?revision=" + t.revision, undefined, "Removed stop " + (i + 1) + ".");
  }

  // ----- the stop editor: a new stop (from a click on the map) or an existing one ----------------------
  function openEditor(i) {
    const t = selected();
    const s = t.stops[i];
    T.pending = null; T.editIndex = i;
    $("stopEditTitle").textContent = "Stop " + (i + 1) + " at (" + s.x_m.toFixed(2) + ", " + s.y_m.toFixed(2) + ") m";
    $("stopName").value = s.name;
    $("stopDwell").value = String(Math.round(s.dwell_s));
    $("stopYaw").value = s.yaw_rad === null ? "" : String(deg(s.yaw_rad));
    $("stopText").value = s.message ? s.message.text : "";
    $("stopLang").value = s.message ? s.message.language : "";
    $("stopSave").textContent = "Save stop";
    $("stopSave").disabled = !C.may("tours");
    C.showMsg($("stopEditMsg"), "");
    $("stopEdit").classList.remove("hidden");
    card.open = true;
    render();
  }
  function closeEditor() {
    T.pending = null; T.editIndex = null;
    $("stopEdit").classList.add("hidden");
    render();
  }

  async function newStop(x, y, yaw) {
    const t = selected();
    T.editIndex = null;
    T.pending = { x, y, yaw, problem: null, checking: true };
    $("stopEditTitle").textContent = "New stop " + (t.stops.length + 1) + " at (" + x.toFixed(2) + ", " + y.toFixed(2) + ") m" +
      (yaw === null ? "" : ", facing " + deg(yaw) + "°");
    $("stopName").value = "Stop " + (t.stops.length + 1);
    $("stopDwell").value = "10";
    $("stopYaw").value = yaw === null ? "" : String(deg(yaw));
    $("stopText").value = ""; $("stopLang").value = "";
    $("stopSave").textContent = "Add stop";
    $("stopSave").disabled = true;
    $("stopEdit").classList.remove("hidden");
    C.showMsg($("stopEditMsg"), "Checking the map…", "wait");
    card.open = true;
    render();
    try {
      const check = await C.api("POST", "/api/place-check", { x_m: x, y_m: y });
      if (!T.pending || T.pending.x !== x || T.pending.y !== y) return;
      T.pending.checking = false;
      T.pending.problem = check.ok ? null : check.problem;
      $("stopSave").disabled = !check.ok;
      C.showMsg($("stopEditMsg"), check.ok ? "Name it, then press Add stop (the route and duration are a preview until then)." :
        "The rover cannot stand there: it " + check.problem + ". Click somewhere else.", check.ok ? "" : "error");
      render();
    } catch (e) { C.showMsg($("stopEditMsg"), e.message, "error", 20); }
  }

  function editorFields() {
    const yawText = $("stopYaw").value.trim();
    const fields = { name: $("stopName").value.trim(), dwell_s: Number($("stopDwell").value),
      yaw_rad: yawText === "" ? null : Math.round(Number(yawText) * Math.PI / 180 * 1e4) / 1e4 };
    return [fields, $("stopText").value, $("stopLang").value.trim()];
  }

  async function saveStop() {
    const [fields, text, language] = editorFields();
    const el = $("stopEditMsg");
    if (!fields.name) { C.showMsg(el, "Give the stop a name.", "error", 10); return; }
    if (!isFinite(fields.dwell_s) || fields.dwell_s < 0 || fields.dwell_s > 3600) { C.showMsg(el, "The stay must be 0 to 3600 seconds.", "error", 10); return; }
    if (fields.yaw_rad !== null && !isFinite(fields.yaw_rad)) { C.showMsg(el, "Facing must be a number of degrees (or empty for any).", "error", 10); return; }
    let out;
    if (T.pending) {
      const p = T.pending;
      const stop = Object.assign({ x_m: p.x, y_m: p.y, message: { text, language, voice: "" } }, fields);
      out = await edit("POST", "/stops", { stop, revision: rev() }, "Added “" + fields.name + "”.");
    } else if (T.editIndex !== null) {
      const i = T.editIndex;
      out = await edit("PATCH", "/stops/" + i, Object.assign({ message: text, language, revision: rev() }, fields), "Saved stop " + (i + 1) + ".");
    }
    if (out) closeEditor();
    else if (out === null) C.showMsg(el, $("tourMsg").textContent, "error", 25);
  }

  // ----- the map tool and layer ------------------------------------------------------------------------
  function hitStop(sx, sy) {
    const t = selected();
    if (!t || !C.may("tours")) return null;
    for (let i = t.stops.length - 1; i >= 0; i--) {
      const [x, y] = C.toScreen(t.stops[i].x_m, t.stops[i].y_m);
      if (Math.hypot(x - sx, y - sy) <= 15) return { kind: "stop", index: i };
    }
    return null;
  }

  C.mapTools.stops = {
    hint: "Click to add a stop (drag to set the way the rover faces) · drag a stop to move it · click a stop to edit it.",
    hit: hitStop,
    onSelect() {
      card.open = true;
      if (!selected()) msg("Choose a tour (or make a new one) first.", "error", 15);
      else if (!C.may("tours")) msg("Viewing only: editing tours needs an operator token.", "error", 15);
      C.view.dirty = true;
    },
    onAction(kind, x, y, yaw, index) {
      const t = selected();
      if (!t) { msg("Choose a tour (or make a new one) first.", "error", 15); card.open = true; return; }
      if (!C.may("tours")) { msg("Viewing only: editing tours needs an operator token.", "error", 15); return; }
      if (kind === "select") openEditor(index);
      else if (kind === "stop") {
        edit("PATCH", "/stops/" + index, { x_m: x, y_m: y, revision: t.revision }, "Moved stop " + (index + 1) + " “" + t.stops[index].name + "”.");
      } else newStop(x, y, yaw);
    },
  };

  function shownTour() {
    if (card.open || C.tool === "stops") return [selected(), true];
    const r = S.tour && S.tour.tour_id !== null && S.tour.tour_id !== undefined ? T.list.find((t) => t.id === S.tour.tour_id) : null;
    if (r) return [r, true];
    return [S.robot && S.robot.tree === "tour" ? T.list[0] || null : null, false];
  }

  C.mapLayers.push((ctx, kit) => {
    const [t, withRoute] = shownTour();
    if (!t) return;
    const drag = kit.drag && kit.drag.kind === "stop" && t.id === T.selId ? kit.drag : null;
    let stops = t.stops.map((s, i) => (drag && drag.index === i ? Object.assign({}, s, { x_m: drag.wx, y_m: drag.wy }) : s));
    if (t.id === T.selId) stops = withPending(stops);
    if (withRoute) {
      const flat = [];
      for (const [x, y] of routeOf(stops)) flat.push(x, y);
      kit.polyline(flat, T.pending || drag ? "rgba(13,148,136,.95)" : "rgba(15,118,110,.7)", 3, [10, 6]);
    }
    const current = S.tour && S.tour.tour_id === t.id ? S.tour.stop_index : null;
    if (T.pending && T.pending.problem && t.id === T.selId) stops = stops.concat([{ x_m: T.pending.x, y_m: T.pending.y }]);
    stops.forEach((s, i) => {
      const isPending = T.pending && t.id === T.selId && i === stops.length - 1;
      const color = isPending ? (T.pending.problem ? "#dc2626" : (T.pending.checking ? "#d97706" : "#14b8a6")) :
        (i === current ? "#2563eb" : "#0f766e");
      const yaw = isPending ? T.pending.yaw : s.yaw_rad;
      if (yaw !== null && yaw !== undefined) kit.drawHeading(s.x_m, s.y_m, yaw, color, 26);
      kit.drawMarker(s.x_m, s.y_m, color, isPending ? "+" : String(i + 1), i === T.editIndex ? 13 : 11);
      const [sx, sy] = kit.toScreen(s.x_m, s.y_m);
      const label = isPending ? (T.pending.problem ? "cannot stand here" : "new stop") : s.name;
      ctx.font = "bold 12px system-ui, sans-serif";
      const w = ctx.measureText(label).width;
      const lx = sx + 16 + w > kit.width ? sx - 16 - w : sx + 14;
      ctx.fillStyle = "rgba(255,255,255,.85)"; ctx.fillRect(lx - 3, sy - 8, w + 6, 16);
      ctx.fillStyle = color; ctx.fillText(label, lx, sy + 4);
    });
    if (drag) {  // the duration while dragging, before the drop is sent
      const e = estimateOf(stops);
      const text = "about " + fmtDur(e.total_s) + " home to home";
      ctx.font = "bold 13px system-ui, sans-serif";
      const w = ctx.measureText(text).width;
      ctx.fillStyle = "#0f766e"; ctx.fillRect(drag.sx + 14, drag.sy + 10, w + 10, 20);
      ctx.fillStyle = "#fff"; ctx.fillText(text, drag.sx + 19, drag.sy + 25);
      if (text !== T.lastPreview) { T.lastPreview = text; $("tourEstimate").textContent = "Moving stop " + (drag.index + 1) + ": " + estimateText(e, stops.length); }
    } else if (T.lastPreview) { T.lastPreview = ""; renderEstimate(); }
  });

  // ----- buttons ---------------------------------------------------------------------------------------
  $("tourSel").addEventListener("change", () => {
    const v = $("tourSel").value;
    T.selId = v === "" ? null : Number(v);
    T.pending = null; T.editIndex = null;
    $("stopEdit").classList.add("hidden");
    C.showMsg($("tourMsg"), "");
    render();
  });
  $("tourNew").addEventListener("click", async () => {
    const typed = $("tourName").value.trim();
    const name = typed && !selected() ? typed : "New tour " + (T.list.length + 1);
    try {
      const t = await C.api("POST", "/api/tours", { name, kiosk: false });
      T.selId = t.id; T.pending = null; T.editIndex = null;
      put(t);
      C.setTool("stops");
      msg("Made “" + t.name + "”. Click the map to add its stops; tick “offered at the kiosk” when it is ready for visitors.", "ok", 20);
    } catch (e) { msg(e.message, "error", 20); }
  });
  $("tourRename").addEventListener("click", () => edit("PATCH", "", { name: $("tourName").value.trim(), revision: rev() }, "Renamed."));
  $("tourName").addEventListener("keydown", (ev) => { if (ev.key === "Enter") $("tourRename").click(); });
  $("tourKiosk").addEventListener("change", () => {
    const on = $("tourKiosk").checked;
    edit("PATCH", "", { kiosk: on, revision: rev() }, on ? "Visitors can start it at the kiosk." : "No longer offered at the kiosk.");
  });
  $("tourDup").addEventListener("click", async () => {
    const out = await edit("POST", "/duplicate", {}, null);
    if (out && out.id) { T.selId = out.id; render(); msg("Made “" + out.name + "” (not offered at the kiosk yet).", "ok", 15); }
  });
  $("tourDel").addEventListener("click", async () => {
    const t = selected();
    if (!t || !(await C.confirmBox("Delete the tour “" + t.name + "” for everyone?", "Delete", "Keep it"))) return;
    try {
      await C.api("DELETE", "/api/tours/" + t.id);
    } catch (e) {
      if (e.status !== 400 || !/not deleted/.test(e.message)) { msg(e.message, "error", 20); return; }
      if (!(await C.confirmBox(e.message.replace(/; or delete it with force to do both\.?$/, "") + ". Do both and delete it?", "Stop and delete", "Keep it"))) return;
      try { await C.api("DELETE", "/api/tours/" + t.id + "?force=1"); } catch (e2) { msg(e2.message, "error", 20); return; }
    }
    T.list = T.list.filter((x) => x.id !== t.id);
    T.selId = T.list[0] ? T.list[0].id : null;
    closeEditor();
    msg("Deleted “" + t.name + "”.", "ok", 10);
  });
  $("tourStart").addEventListener("click", async () => {
    const t = selected();
    if (!t) return;
    const rid = C.newRequestId();
    C.showMsg($("tourMsg"), "Sent — waiting for the rover…", "wait");
    C.expectAnswer(rid, $("tourMsg"), "start_tour");
    try { await C.api("POST", "/api/tours/" + t.id + "/start", { request_id: rid }); } catch (e) {
      C.pending.delete(rid);
      msg(e.message, "error", 20);
    }
  });
  $("tourStop").addEventListener("click", async () => {
    try { await C.api("POST", "/api/tours/stop"); msg("Stopping the tour…", "wait", 8); } catch (e) { msg(e.message, "error", 15); }
  });
  $("stopSave").addEventListener("click", saveStop);
  $("stopCancel").addEventListener("click", closeEditor);
  $("stopDwell").addEventListener("input", () => { if (T.pending) { renderEstimate(); C.view.dirty = true; } });
  card.addEventListener("toggle", () => { C.view.dirty = true; });

  // ----- what the rover says ---------------------------------------------------------------------------
  let reloadTimer = null;
  const reloadSoon = () => { clearTimeout(reloadTimer); reloadTimer = setTimeout(load, 150); };
  C.on("state", (m) => { S.tour = m.tour || null; load(); });
  C.on("tour", (m) => {
    const was = S.tour && S.tour.tour_id;
    S.tour = m.tour;
    if ((m.tour && m.tour.tour_id) !== was) reloadSoon(); else render();
  });
  C.on("event", (m) => {
    const ev = m.event;
    if (ev.kind === "tours.changed") {
      const d = ev.detail || {};
      if (d.actor && d.actor !== S.who.name) {
        C.toast(d.actor + " changed the tours (" + String(d.change).replace(/_/g, " ") + ", tour " + d.tour_id + ").");
        if (d.tour_id === T.selId && (T.pending || T.editIndex !== null)) msg(d.actor + " changed this tour; you see the new version.", "warn", 15);
      }
      reloadSoon();
    }
  });

  // Events about tours, as sentences in the events list.
  const name = (d) => (d.tour ? "“" + d.tour + "”" : "the tour");
  Object.assign(C.EVENT_TEXT, {
    "tour.started": (d) => ["ok", "Tour " + name(d) + " started" + (d.source ? " by " + C.nameOf(d.source) : "")],
    "tour.finished": (d) => ["ok", "Tour " + name(d) + " finished" + (d.stops_reached !== undefined ? ": " + d.stops_reached + " of " + d.stops + " stops" : "")],
    "tour.interrupted": (d) => ["bad", d.message || "Tour " + name(d) + " was interrupted: Curio stopped during it"],
    "tour.stopped": (d) => ["warn", "Tour " + name(d) + " stopped" + (d.reason ? ": " + d.reason : "")],
    "tour.scheduled_start": (d) => ["ok", "Scheduled tour " + name(d) + " (" + String(d.due || "").slice(11, 16) + ") started" + (d.late_s > 1 ? ", " + Math.round(d.late_s) + " s late" : "")],
    "tour.delayed": (d) => ["warn", d.message || "A scheduled tour waits: " + (d.reason || "")],
    "tour.skipped": (d) => ["bad", d.message || "A scheduled tour was skipped: " + (d.reason || "")],
    "tours.changed": (d) => ["who", (d.actor || "Someone") + " changed the tours (" + String(d.change).replace(/_/g, " ") + ", tour " + d.tour_id + ")"],
    "schedules.changed": (d) => ["who", (d.actor || "Someone") + " changed the schedule (" + d.change + ")"],
  });
  Object.assign(C, { tours: T, loadTours: load });
})();
