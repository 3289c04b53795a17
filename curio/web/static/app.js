// Curio operator dashboard. Hand-written, no libraries, no build step.
// Everything shown comes from the rover (WebSocket frames and /api); controls never guess state.
"use strict";

(() => {
  const $ = (id) => document.getElementById(id);
  const FRAME = { SCAN: 1, POSE: 2, PLAN: 3, LOCAL_PLAN: 4, TRUTH: 5 };
  const STATE_WORDS = {
    moving: ["Moving", "The rover is driving to its next stop."],
    arrived: ["Arrived", "The rover reached its stop. Type a path number or press Go Home."],
    paused: ["Paused", "The rover is holding still. Press Resume to continue."],
    going_home: ["Going home", "The rover is driving back to its home position."],
    needs_help: ["Needs help", "The way is blocked. Please clear it, then press “I cleared the way”."],
    idle: ["Idle", "Waiting for a command: type a path number and press Enter, or press Go Home."],
    estop: ["E-STOP", "Emergency stop engaged. Release it when it is safe."],
    tour: ["Giving a tour", "The rover is guiding visitors along the tour."],
  };

  // ----- state (all from the rover) -------------------------------------------------------------
  const S = {
    token: null, control: false, requireToken: true, connected: false, ws: null,
    status: null, progress: null, help: { active: false }, estop: null, paths: [],
    grids: {}, images: {}, pose: null, truth: null, scan: null, plan: [], localPlan: [],
    obstacles: null, tree: null, health: null, robot: null, lastMsgAt: 0,
    editPathId: null, thanksUntil: 0, teleopSeq: 0, lastCmdRequest: null, answered: new Set(),
  };
  const view = { cx: 0, cy: 0, scale: 60, fitted: false, zoomedOnRover: false, dirty: true };
  let tool = "look";

  // ----- token ------------------------------------------------------------------------------------
  function loadToken() {
    const url = new URL(location.href);
    const fromUrl = url.searchParams.get("token");
    if (fromUrl) {
      try { localStorage.setItem("curio.token", fromUrl); } catch (e) { /* private mode */ }
      url.searchParams.delete("token");
      history.replaceState(null, "", url.pathname + url.search + url.hash);
      return fromUrl;
    }
    try { return localStorage.getItem("curio.token"); } catch (e) { return null; }
  }

  function authHeaders() {
    const h = { "Content-Type": "application/json" };
    if (S.token) h["Authorization"] = "Bearer " + S.token;
    return h;
  }

  async function api(method, path, body) {
    let resp;
    try {
      resp = await fetch(path, { method, headers: authHeaders(),
        body: body === undefined ? undefined : JSON.stringify(body) });
    } catch (e) {
      throw new Error("the rover did not answer (is it on, and is this device on its network?)");
    }
    let data = null;
    try { data = await resp.json(); } catch (e) { data = null; }
    if (!resp.ok) {
      const msg = (data && data.error) || (resp.status + " " + resp.statusText);
      const err = new Error(msg);
      err.status = resp.status;
      throw err;
    }
    return data;
  }

  // ----- messages -------------------------------------------------------------------------------
  function showMsg(el, text, kind) {
    el.textContent = text || "";
    el.className = "msg" + (kind ? " " + kind : "");
  }
  let toastTimer = null;
  function toast(text, isError) {
    const t = $("toast");
    t.textContent = text;
    t.className = "toast" + (isError ? " error" : "");
    clearTimeout(toastTimer);
    toastTimer = setTimeout(() => t.classList.add("hidden"), isError ? 6000 : 3000);
  }

  function newRequestId() {
    return "web-" + Date.now().toString(36) + "-" + Math.floor(Math.random() * 1e9).toString(36);
  }

  async function command(action, extra, msgEl) {
    const el = msgEl || $("cmdMsg");
    if (!S.control) { showMsg(el, "Viewing only: open the link with the token from the rover's start-up log to control it.", "error"); return false; }
    if (!S.connected && action !== "estop") { showMsg(el, "Not connected to the rover; nothing was sent.", "error"); return false; }
    const body = Object.assign({ action, request_id: newRequestId() }, extra || {});
    S.lastCmdRequest = body.request_id;
    try {
      await api("POST", "/api/command", body);
      // The rover's answer (an event) can arrive before the POST returns; keep it.
      if (!S.answered.has(body.request_id)) showMsg(el, "Sent — waiting for the rover…", "ok");
      return true;
    } catch (e) {
      showMsg(el, e.message, "error");
      return false;
    }
  }

  // ----- rendering of state ------------------------------------------------------------------
  function renderStatus() {
    const st = S.status;
    const state = st ? st.state : "idle";
    const estopOn = S.estop && S.estop.engaged;
    const shown = !S.connected ? "offline" : (estopOn ? "estop" : state);
    const words = STATE_WORDS[shown] || [shown, ""];
    const badge = $("stateBadge");
    badge.textContent = shown === "offline" ? "Offline" : words[0];
    badge.className = "badge " + shown;
    $("statusText").textContent = !S.connected ? "No connection to the rover — reconnecting…" :
      (st && st.text ? st.text : "Waiting for the rover…");
    let hint = !S.connected ? "The page keeps trying; nothing is sent while offline." : words[1];
    if (S.connected && !S.control) hint += " (Viewing only: use the link with the token to control.)";
    $("stateHint").textContent = hint;
    // Pause/Resume shows what pressing it will do, from the rover's real state.
    const pause = $("pause");
    const paused = state === "paused";
    pause.textContent = paused ? "▶ Resume" : "❚❚ Pause";
    pause.dataset.action = paused ? "resume" : "pause";
    pause.classList.toggle("paused", paused);
    const home = $("goHome");
    const homeOn = state === "going_home" || (S.progress && S.progress.path_id === 0 && state !== "idle");
    home.classList.toggle("on", !!homeOn);
    home.textContent = state === "going_home" ? "⌂ Going home…" : "⌂ Go Home";
    const isTour = S.robot && S.robot.tree === "tour";
    $("startTour").classList.toggle("hidden", !isTour);
    const tripOn = ["moving", "going_home", "tour", "paused", "needs_help"].includes(state);
    $("cancelTrip").classList.toggle("hidden", !tripOn);
    $("cancelTrip").dataset.action = state === "tour" ? "stop_tour" : "cancel";
    const canControl = S.control && S.connected;
    for (const id of ["goHome", "pause", "startTour", "cancelTrip", "pathEnter", "helpDone", "newPath", "renamePath", "deletePath", "releaseEstop"]) {
      $(id).disabled = !canControl;
    }
    if (state === "tour") $("startTour").disabled = true;
    $("estop").disabled = !S.control;  // tried even while the live link is down
    $("estop").classList.toggle("engaged", !!estopOn);
    $("estopBanner").classList.toggle("hidden", !estopOn);
    $("estopReason").textContent = estopOn && S.estop.reason ? "(" + S.estop.reason + ")" : "";
    renderHelp();
  }

  function renderHelp() {
    const el = $("help");
    const active = S.help && S.help.active;
    if (active) {
      el.textContent = "HELP ME!";
      el.className = "help active";
      el.title = S.help.message || "the way is blocked";
    } else if (Date.now() < S.thanksUntil) {
      el.textContent = "Thanks!";
      el.className = "help thanks";
    } else {
      el.textContent = "All clear";
      el.className = "help clear";
    }
    $("helpActions").classList.toggle("hidden", !active);
  }

  function renderProgress() {
    const p = S.progress;
    const box = $("progress");
    box.textContent = "";
    if (!p || !p.states || p.states.length === 0) {
      $("progressTitle").textContent = "No path running";
      return;
    }
    const reached = p.states.filter((s) => s === "reached").length;
    const what = p.path_id < 0 ? (p.path_name || "Tour") : "Path " + p.path_id + (p.path_name ? " “" + p.path_name + "”" : "");
    $("progressTitle").textContent = what +
      ": " + reached + " of " + p.states.length + " stops reached";
    p.states.forEach((s, i) => {
      const d = document.createElement("div");
      d.className = "sq " + s;
      d.textContent = String(i + 1);
      d.title = "stop " + (i + 1) + ": " + s;
      d.dataset.state = s;
      box.appendChild(d);
    });
  }

  function renderPaths() {
    const list = $("pathList");
    list.textContent = "";
    for (const p of S.paths) {
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = p.id + ": " + (p.name || "path " + p.id);
      b.title = p.waypoints.length + " waypoint(s)";
      b.onclick = () => { $("pathInput").value = String(p.id); $("pathInput").focus(); };
      list.appendChild(b);
    }
    const sel = $("editPath");
    const keep = S.editPathId;
    sel.textContent = "";
    const none = document.createElement("option");
    none.value = ""; none.textContent = "— choose a path to edit —";
    sel.appendChild(none);
    for (const p of S.paths) {
      const o = document.createElement("option");
      o.value = String(p.id);
      o.textContent = p.id + ": " + (p.name || "path " + p.id) + " (" + p.waypoints.length + ")";
      sel.appendChild(o);
    }
    if (keep !== null && S.paths.some((p) => p.id === keep)) sel.value = String(keep);
    else { S.editPathId = null; sel.value = ""; }
    renderWaypoints();
    view.dirty = true;
  }

  function describeIds(ids) {
    const contiguous = ids.length > 2 && ids.every((v, i) => v === ids[0] + i);
    return contiguous ? ids[0] + "–" + ids[ids.length - 1] : ids.join(", ");
  }

  function editPath() { return S.paths.find((p) => p.id === S.editPathId) || null; }

  function renderWaypoints() {
    const ol = $("waypoints");
    ol.textContent = "";
    const p = editPath();
    $("pathName").value = p ? p.name : "";
    if (!p) return;
    p.waypoints.forEach((w, i) => {
      const li = document.createElement("li");
      li.textContent = "(" + w.x_m.toFixed(2) + ", " + w.y_m.toFixed(2) + ")" +
        (w.yaw_rad === null ? "" : " " + Math.round(w.yaw_rad * 180 / Math.PI) + "°");
      const rm = document.createElement("button");
      rm.textContent = "×"; rm.title = "remove this waypoint";
      rm.disabled = !S.control;
      rm.onclick = async () => {
        try { await api("DELETE", "/api/paths/" + p.id + "/waypoints/" + i); showMsg($("pathEditMsg"), "Waypoint removed.", "ok"); }
        catch (e) { showMsg($("pathEditMsg"), e.message, "error"); }
      };
      li.appendChild(rm);
      ol.appendChild(li);
    });
  }

  const STATUS_MARK = { SUCCESS: "✔", RUNNING: "▶", FAILURE: "✘", INVALID: "·" };
  function renderTree() {
    const t = S.tree;
    const el = $("tree");
    el.textContent = "";
    if (!t || !t.nodes || t.nodes.length === 0) { el.textContent = "No tree yet."; return; }
    const byId = new Map(t.nodes.map((n) => [String(n.id), n]));
    const roots = t.nodes.filter((n) => n.parent === null || n.parent === undefined || !byId.has(String(n.parent)));
    const walk = (n, depth) => {
      const d = document.createElement("div");
      const st = String(n.status || "INVALID").toUpperCase();
      d.className = "node st-" + st;
      d.textContent = "  ".repeat(depth) + (STATUS_MARK[st] || "?") + " " + n.name + (n.type ? "  [" + n.type + "]" : "");
      d.title = st;
      el.appendChild(d);
      const kids = n.children || t.nodes.filter((c) => String(c.parent) === String(n.id)).map((c) => c.id);
      for (const k of kids) { const c = byId.get(String(k)); if (c) walk(c, depth + 1); }
    };
    roots.forEach((r) => walk(r, 0));
    const bb = $("blackboard");
    bb.textContent = "";
    for (const [k, v] of Object.entries(t.blackboard || {}).sort()) {
      const tr = bb.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = typeof v === "string" ? v : JSON.stringify(v);
    }
  }

  function fmt(v) {
    if (v === null || v === undefined) return "—";
    if (typeof v === "number") return Number.isInteger(v) ? String(v) : v.toFixed(3);
    return typeof v === "string" ? v : JSON.stringify(v);
  }

  function renderHealth() {
    const h = S.health;
    const table = $("health");
    table.textContent = "";
    if (!h) return;
    const row = (k, v, cls) => {
      const tr = table.insertRow();
      tr.insertCell().textContent = k;
      const c = tr.insertCell(); c.textContent = v; if (cls) c.className = cls;
    };
    const sys = h.system || {};
    const loc = h.localization;
    $("healthSummary").textContent =
      "CPU " + (sys.cpu_fraction !== undefined ? Math.round(sys.cpu_fraction * 100) + " %" : "—") +
      " · temp " + (sys.temperature_c ? sys.temperature_c.toFixed(1) + " °C" : "n/a") +
      " · localisation " + (loc ? loc.state : "—") +
      " · bus drops " + (h.bus ? h.bus.dropped_total : "—");
    for (const [name, c] of Object.entries(h.components || {})) {
      const counters = Object.entries(c.counters || {}).map(([k, v]) => k + "=" + fmt(v)).join(" ");
      row(name, c.state + (c.message ? " — " + c.message : "") + (counters ? "  [" + counters + "]" : ""), "state-" + c.state);
    }
    if (loc) row("localisation", loc.state + " · ±" + fmt(loc.std_xy_m) + " m · ±" + fmt(loc.std_yaw_rad) + " rad · " + loc.particles + " particles", "state-" + loc.state);
    if (h.battery) row("battery", h.battery.voltage_v.toFixed(2) + " V" + (h.battery.low ? " LOW" : ""), h.battery.low ? "state-error" : "state-ok");
    row("CPU", (sys.cpu_fraction !== undefined ? Math.round(sys.cpu_fraction * 100) + " % of " + sys.cpu_count + " cores" : "—") +
      (sys.process_cpu_fraction !== undefined ? " · Curio " + Math.round(sys.process_cpu_fraction * 100) + " % of one core" : ""));
    row("load average", sys.load_avg ? sys.load_avg.join(" ") : "—");
    row("temperature", sys.temperature_c ? sys.temperature_c.toFixed(1) + " °C" : "no sensor");
    row("event-loop lag", sys.loop_lag_ms !== undefined ? sys.loop_lag_ms + " ms" : "—");
    if (h.bus) {
      row("bus drops", String(h.bus.dropped_total));
      for (const [name, t] of Object.entries(h.bus.topics || {})) {
        if (t.dropped) row("  " + name, t.dropped + " dropped of " + t.published);
      }
    }
    if (h.web) row("dashboards", h.web.clients + " connected");
  }

  const LOC_WORDS = { ok: ["Position OK", "ok"], uncertain: ["Position uncertain", "warn"],
    lost: ["Position lost — use “Set rover's position”", "bad"], off: ["Position from odometry", "warn"] };
  function renderLoc(loc) {
    const el = $("locChip");
    if (!loc) { el.classList.add("hidden"); return; }
    const [text, cls] = LOC_WORDS[loc.state] || [loc.state, "warn"];
    el.textContent = text;
    el.className = "chip " + cls;
  }
  function renderBattery(b) {
    const el = $("batteryChip");
    if (!b) { el.classList.add("hidden"); return; }
    el.textContent = "Battery " + b.voltage_v.toFixed(1) + " V" + (b.low ? " LOW" : "");
    el.className = "chip " + (b.low ? "bad" : "ok");
  }

  function addEvent(ev, history) {
    const ol = $("events");
    const li = document.createElement("li");
    const detail = ev.detail && Object.keys(ev.detail).length ? " " + JSON.stringify(ev.detail) : "";
    li.textContent = "t=" + Number(ev.stamp).toFixed(1) + " s  " + ev.kind + detail;
    ol.insertBefore(li, ol.firstChild);
    while (ol.children.length > 100) ol.removeChild(ol.lastChild);
    if (history) return;
    const msg = ev.detail && ev.detail.message;
    if ((ev.kind === "bt.command_rejected" || ev.kind === "bt.command_accepted") && ev.detail && ev.detail.request_id) {
      S.answered.add(ev.detail.request_id);
      if (S.answered.size > 200) S.answered.delete(S.answered.values().next().value);
    }
    if (ev.kind === "bt.command_rejected") {
      showMsg($("cmdMsg"), msg || "The rover refused the command.", "error");
      if (ev.detail && ev.detail.action === "select_path") showMsg($("pathMsg"), msg || "The rover refused the path.", "error");
    } else if (ev.kind === "bt.command_accepted") {
      showMsg($("cmdMsg"), msg || "The rover accepted the command.", "ok");
    } else if (ev.kind === "help.resolved") {
      S.thanksUntil = Date.now() + 15000;
      setTimeout(renderHelp, 15100);
    } else if (ev.kind === "tour.stop" && msg) {
      toast(msg);
    } else if (ev.kind === "battery.low") {
      toast("Battery low" + (msg ? ": " + msg : ""), true);
    } else if (ev.kind === "path.finished") {
      toast("Path finished.");
    }
  }

  // ----- WebSocket ------------------------------------------------------------------------------
  let backoff = 500;
  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const q = S.token && S.control ? "?token=" + encodeURIComponent(S.token) : "";
    const ws = new WebSocket(proto + "//" + location.host + "/ws" + q);
    ws.binaryType = "arraybuffer";
    S.ws = ws;
    ws.onopen = () => { backoff = 500; };
    ws.onmessage = (ev) => {
      S.lastMsgAt = Date.now();
      if (!S.connected) { S.connected = true; setConn(); renderStatus(); }
      if (typeof ev.data === "string") onJson(JSON.parse(ev.data));
      else onBinary(ev.data);
    };
    ws.onclose = () => {
      if (S.ws !== ws) return;
      S.ws = null;
      S.connected = false;
      stopTeleop();
      setConn();
      renderStatus();
      setTimeout(connect, backoff);
      backoff = Math.min(5000, backoff * 2);
    };
    ws.onerror = () => { /* onclose follows */ };
  }

  function setConn() {
    const c = $("conn");
    c.textContent = S.connected ? "Connected" : "Reconnecting…";
    c.className = "conn " + (S.connected ? "ok" : "bad");
    const m = $("mode");
    m.textContent = S.control ? "You can control" : "View only";
    m.className = "mode" + (S.control ? " control" : "");
  }

  function onJson(m) {
    switch (m.t) {
      case "hello":
        S.control = !!m.control; S.requireToken = !!m.require_token; setConn(); break;
      case "state":
        S.status = m.status; S.progress = m.progress; S.estop = m.estop; S.help = m.help || { active: false };
        S.paths = m.paths || []; S.tree = m.tree; S.health = m.health; S.robot = m.robot;
        for (const [name, g] of Object.entries(m.grids || {})) if (g) onGrid(g);
        $("events").textContent = "";
        for (const ev of m.events || []) addEvent(ev, true);
        renderStatus(); renderProgress(); renderPaths(); renderTree(); renderHealth();
        renderLoc(m.localization); renderBattery(m.battery);
        break;
      case "status": S.status = m.status; if (m.help) S.help = m.help; renderStatus(); break;
      case "progress": S.progress = m.progress; renderProgress(); renderStatus(); break;
      case "event": if (m.help) S.help = m.help; addEvent(m.event, false); renderHelp(); break;
      case "estop": S.estop = m.estop; renderStatus(); break;
      case "paths": S.paths = m.paths; renderPaths(); break;
      case "tree": S.tree = m.tree; if ($("treeCard").open) renderTree(); break;
      case "health": S.health = m; if ($("healthCard").open) renderHealth(); break;
      case "grid": onGrid(m.grid); break;
      case "obstacles": S.obstacles = m; view.dirty = true; break;
      case "localization": renderLoc(m.localization); break;
      case "battery": renderBattery(m.battery); break;
      case "cmd_vel":
        $("cmdVel").textContent = "wheels: " + m.linear_mps.toFixed(2) + " m/s, " + m.angular_radps.toFixed(2) + " rad/s" + (m.source ? " (" + m.source + ")" : "");
        break;
      case "error": toast(m.message, true); break;
      default: break;
    }
  }

  function onGrid(g) {
    const old = S.grids[g.name];
    S.grids[g.name] = g;
    if (old && old.version === g.version && S.images[g.name]) return;
    if (g.name !== "map" && !$("showCostmap").checked) return;
    loadGridImage(g);
  }

  // One image request per grid at a time, at most one a second; the newest version wins.
  const gridLoad = {};
  function loadGridImage(g) {
    const st = gridLoad[g.name] || (gridLoad[g.name] = { busy: false, last: 0, want: null, timer: null });
    st.want = g;
    if (st.busy || st.timer) return;
    const wait = Math.max(0, st.last + 1000 - Date.now());
    if (wait > 0) { st.timer = setTimeout(() => { st.timer = null; if (st.want) loadGridImage(st.want); }, wait); return; }
    if (S.images[g.name] && S.images[g.name].meta.version === g.version) { st.want = null; return; }
    st.busy = true; st.want = null; st.last = Date.now();
    const img = new Image();
    const done = () => { st.busy = false; if (st.want) loadGridImage(st.want); };
    img.onload = () => {
      S.images[g.name] = { img, meta: g };
      if (g.name === "map" && !view.fitted) closeView();
      view.dirty = true;
      done();
    };
    img.onerror = done;
    img.src = g.url;
  }

  function onBinary(buf) {
    const dv = new DataView(buf);
    const type = dv.getUint8(0);
    const stamp = dv.getFloat64(8, true);
    let off = 16;
    if (type === FRAME.SCAN) {
      const lx = dv.getFloat32(off, true), ly = dv.getFloat32(off + 4, true), lyaw = dv.getFloat32(off + 8, true);
      const amin = dv.getFloat32(off + 12, true), ainc = dv.getFloat32(off + 16, true), n = dv.getUint32(off + 20, true);
      off += 24;
      const pts = new Float32Array(n * 2);
      let k = 0;
      for (let i = 0; i < n; i++) {
        const mm = dv.getUint16(off + 2 * i, true);
        if (mm === 0) continue;
        const a = lyaw + amin + i * ainc, r = mm / 1000;
        pts[k++] = lx + r * Math.cos(a); pts[k++] = ly + r * Math.sin(a);
      }
      S.scan = { pts, n: k / 2, stamp };
    } else if (type === FRAME.POSE || type === FRAME.TRUTH) {
      const p = { x: dv.getFloat32(off, true), y: dv.getFloat32(off + 4, true), yaw: dv.getFloat32(off + 8, true),
        std: [dv.getFloat32(off + 12, true), dv.getFloat32(off + 16, true), dv.getFloat32(off + 20, true)], stamp };
      if (type === FRAME.POSE) {
        S.pose = p;
        if (!view.zoomedOnRover && S.images.map) closeView();  // first pose after the map
        if ($("follow").checked && tool === "look" && !dragging) followRover();
      } else S.truth = p;
    } else if (type === FRAME.PLAN || type === FRAME.LOCAL_PLAN) {
      const n = dv.getUint32(off, true);
      const xy = new Float32Array(buf, off + 4, n * 2).slice();
      if (type === FRAME.PLAN) S.plan = xy; else S.localPlan = xy;
    }
    view.dirty = true;
  }

  // ----- map drawing ----------------------------------------------------------------------------
  const canvas = $("map");
  const ctx = canvas.getContext("2d");
  let W = 0, H = 0, dpr = 1;

  function resize() {
    const r = canvas.getBoundingClientRect();
    dpr = window.devicePixelRatio || 1;
    W = r.width; H = r.height;
    canvas.width = Math.max(1, Math.round(W * dpr));
    canvas.height = Math.max(1, Math.round(H * dpr));
    view.dirty = true;
  }
  const toScreen = (x, y) => [W / 2 + (x - view.cx) * view.scale, H / 2 - (y - view.cy) * view.scale];
  const toWorld = (sx, sy) => [view.cx + (sx - W / 2) / view.scale, view.cy - (sy - H / 2) / view.scale];

  function fitView() {
    const m = S.images.map;
    if (!m || W === 0) return;
    const g = m.meta;
    const wm = g.width * g.resolution_m, hm = g.height * g.resolution_m;
    view.cx = g.origin[0] + wm / 2; view.cy = g.origin[1] + hm / 2;
    view.scale = Math.max(5, Math.min(W / wm, H / hm) * 0.95);
    view.fitted = true; view.dirty = true;
  }

  function closeView() {
    fitView();
    if (!S.pose || W === 0) return;
    view.zoomedOnRover = true;
    const minScale = W / 16;  // at least 16 m across, so the rover is easy to see
    if (view.scale < minScale) { view.scale = minScale; view.cx = S.pose.x; view.cy = S.pose.y; }
  }

  function followRover() {
    if (!S.pose || W === 0) return;
    const [sx, sy] = toScreen(S.pose.x, S.pose.y);
    const margin = Math.min(W, H) * 0.2;
    if (sx < margin || sx > W - margin || sy < margin || sy > H - margin) {
      view.cx = S.pose.x; view.cy = S.pose.y;
    }
  }

  function drawGrid(name, alpha) {
    const m = S.images[name];
    if (!m) return;
    const g = m.meta;
    ctx.save();
    ctx.globalAlpha = alpha;
    ctx.imageSmoothingEnabled = false;
    const [ox, oy] = toScreen(g.origin[0], g.origin[1]);
    ctx.translate(ox, oy);
    ctx.rotate(-g.origin[2]);
    const w = g.width * g.resolution_m * view.scale, h = g.height * g.resolution_m * view.scale;
    ctx.drawImage(m.img, 0, -h, w, h);
    ctx.restore();
  }

  function polyline(xy, color, width, dash) {
    if (!xy || xy.length < 4) return;
    ctx.beginPath();
    for (let i = 0; i < xy.length; i += 2) {
      const [sx, sy] = toScreen(xy[i], xy[i + 1]);
      if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
    }
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.setLineDash(dash || []);
    ctx.stroke(); ctx.setLineDash([]);
  }

  function drawRobot(p, fill, stroke, label) {
    if (label) {
      const [hx0, hy0] = toScreen(p.x, p.y);
      ctx.beginPath(); ctx.arc(hx0, hy0, 22, 0, 2 * Math.PI);
      ctx.fillStyle = "rgba(37,99,235,.15)"; ctx.fill();
      ctx.strokeStyle = "rgba(37,99,235,.6)"; ctx.lineWidth = 1.5; ctx.stroke();
    }
    const fp = (S.robot && S.robot.footprint) || [[0.33, 0.31], [0.33, -0.31], [-0.33, -0.31], [-0.33, 0.31]];
    const c = Math.cos(p.yaw), s = Math.sin(p.yaw);
    ctx.beginPath();
    fp.forEach(([x, y], i) => {
      const [sx, sy] = toScreen(p.x + c * x - s * y, p.y + s * x + c * y);
      if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
    });
    ctx.closePath();
    ctx.fillStyle = fill; ctx.fill();
    ctx.strokeStyle = stroke; ctx.lineWidth = 2; ctx.stroke();
    const [ax, ay] = toScreen(p.x, p.y);
    const len = Math.max(0.5, 24 / view.scale);
    const [bx, by] = toScreen(p.x + c * len, p.y + s * len);
    ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(bx, by);
    ctx.strokeStyle = stroke; ctx.lineWidth = 3; ctx.stroke();
    const hx = Math.atan2(ay - by, bx - ax);
    ctx.beginPath();
    ctx.moveTo(bx, by);
    ctx.lineTo(bx - 10 * Math.cos(hx - 0.5), by + 10 * Math.sin(hx - 0.5));
    ctx.lineTo(bx - 10 * Math.cos(hx + 0.5), by + 10 * Math.sin(hx + 0.5));
    ctx.closePath(); ctx.fillStyle = stroke; ctx.fill();
    if (label) {
      ctx.font = "bold 13px system-ui, sans-serif"; ctx.fillStyle = "#111827";
      ctx.fillText(label, ax + 14, ay - 14);
    }
  }

  function drawMarker(x, y, color, text, r) {
    const [sx, sy] = toScreen(x, y);
    ctx.beginPath(); ctx.arc(sx, sy, r || 9, 0, 2 * Math.PI);
    ctx.fillStyle = color; ctx.fill(); ctx.strokeStyle = "#fff"; ctx.lineWidth = 2; ctx.stroke();
    if (text) {
      ctx.fillStyle = "#fff"; ctx.font = "bold 11px system-ui, sans-serif";
      ctx.textAlign = "center"; ctx.textBaseline = "middle"; ctx.fillText(text, sx, sy + 0.5);
      ctx.textAlign = "start"; ctx.textBaseline = "alphabetic";
    }
  }

  function draw() {
    if (!view.dirty) return;
    view.dirty = false;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#cdcdcd"; ctx.fillRect(0, 0, W, H);
    drawGrid("map", 1);
    if ($("showCostmap").checked) { drawGrid("costmap", 0.55); drawGrid("local_costmap", 0.55); }
    // 1 m scale bar
    const bar = view.scale;
    ctx.fillStyle = "#111827"; ctx.fillRect(12, H - 40, Math.min(bar, W / 2), 3);
    ctx.font = "12px system-ui, sans-serif"; ctx.fillText("1 m", 12, H - 46);
    if ($("showPaths").checked) {
      for (const p of S.paths) {
        const sel = p.id === S.editPathId;
        const xy = [];
        for (const w of p.waypoints) xy.push(w.x_m, w.y_m);
        polyline(xy, sel ? "#f59e0b" : "rgba(245,158,11,.55)", sel ? 3 : 2, [6, 5]);
        p.waypoints.forEach((w, i) => drawMarker(w.x_m, w.y_m, sel ? "#d97706" : "rgba(217,119,6,.7)",
          p.id === 0 ? "H" : String(i + 1), sel ? 10 : 8));
      }
    }
    if (S.robot && S.robot.home) drawMarker(S.robot.home[0], S.robot.home[1], "#7c3aed", "⌂", 11);
    if (S.robot && S.robot.tree === "tour") {
      (S.robot.tour_stops || []).forEach((t, i) => {
        drawMarker(t.x_m, t.y_m, "#0f766e", String(i + 1), 10);
        const [sx, sy] = toScreen(t.x_m, t.y_m);
        ctx.font = "bold 12px system-ui, sans-serif"; ctx.fillStyle = "#0f766e";
        ctx.fillText(t.name, sx + 13, sy + 4);
      });
    }
    polyline(S.plan, "#16a34a", 3);
    polyline(S.localPlan, "#06b6d4", 2);
    if (S.obstacles) {
      ctx.strokeStyle = "rgba(234,88,12,.6)"; ctx.lineWidth = 1.5;
      for (const [[x1, y1], [x2, y2]] of S.obstacles.segments || []) {
        const [a, b] = toScreen(x1, y1), [c, d] = toScreen(x2, y2);
        ctx.beginPath(); ctx.moveTo(a, b); ctx.lineTo(c, d); ctx.stroke();
      }
      for (const [x, y, r] of S.obstacles.circles || []) {
        const [a, b] = toScreen(x, y);
        ctx.beginPath(); ctx.arc(a, b, Math.max(2, r * view.scale), 0, 2 * Math.PI); ctx.stroke();
      }
    }
    if (S.scan && $("showScan").checked) {
      ctx.fillStyle = "#ef4444";
      const sz = 3;
      for (let i = 0; i < S.scan.n; i++) {
        const [sx, sy] = toScreen(S.scan.pts[2 * i], S.scan.pts[2 * i + 1]);
        ctx.fillRect(sx - sz / 2, sy - sz / 2, sz, sz);
      }
    }
    if (S.truth) drawRobot(S.truth, "rgba(0,0,0,0)", "rgba(17,24,39,.35)");
    if (S.pose) {
      const home = S.robot && S.robot.home;
      const atHome = home && Math.hypot(S.pose.x - home[0], S.pose.y - home[1]) < 0.3;
      drawRobot(S.pose, "rgba(29,78,216,.35)", "#1d4ed8", atHome ? "Curio (at home)" : "Curio");
    }
    if (drag && drag.kind === "arrow") {
      const [ax, ay] = toScreen(drag.wx, drag.wy);
      ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(drag.sx, drag.sy);
      ctx.strokeStyle = tool === "pose" ? "#7c3aed" : "#16a34a"; ctx.lineWidth = 4; ctx.stroke();
      drawMarker(drag.wx, drag.wy, ctx.strokeStyle, "", 7);
    }
  }

  function frame() { draw(); requestAnimationFrame(frame); }

  // ----- map interaction: pan, zoom, tools --------------------------------------------------------
  const pointers = new Map();
  let drag = null, dragging = false, pinch = null;
  const HINTS = {
    look: "Drag to look around. Wheel or pinch to zoom.",
    goal: "Click where the rover should go (drag to choose the direction it faces).",
    waypoint: "Click to add a waypoint to the path chosen in the Paths panel.",
    pose: "Press where the rover really is and drag in the direction it faces.",
  };

  function setTool(t) {
    tool = t;
    for (const b of document.querySelectorAll(".tool")) b.classList.toggle("active", b.dataset.tool === t);
    $("toolHint").textContent = HINTS[t];
    canvas.style.cursor = t === "look" ? "grab" : "crosshair";
    if (t === "waypoint" && !editPath()) {
      $("pathsCard").open = true;
      showMsg($("pathEditMsg"), "Choose a path to edit (or make a new one) first.", "error");
    }
  }

  function zoomAt(sx, sy, factor) {
    const [wx, wy] = toWorld(sx, sy);
    view.scale = Math.max(2, Math.min(800, view.scale * factor));
    view.cx = wx - (sx - W / 2) / view.scale;
    view.cy = wy + (sy - H / 2) / view.scale;
    view.dirty = true;
  }

  function localXY(ev) { const r = canvas.getBoundingClientRect(); return [ev.clientX - r.left, ev.clientY - r.top]; }

  canvas.addEventListener("pointerdown", (ev) => {
    try { canvas.setPointerCapture(ev.pointerId); } catch (e) { /* synthetic or lost pointer */ }
    const [sx, sy] = localXY(ev);
    pointers.set(ev.pointerId, [sx, sy]);
    if (pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      pinch = { d: Math.hypot(a[0] - b[0], a[1] - b[1]) };
      drag = null;
      return;
    }
    const [wx, wy] = toWorld(sx, sy);
    const pan = tool === "look" || ev.button === 1 || ev.button === 2;
    drag = { kind: pan ? "pan" : "arrow", sx0: sx, sy0: sy, sx, sy, wx, wy, cx: view.cx, cy: view.cy };
    dragging = true;
  });
  canvas.addEventListener("pointermove", (ev) => {
    const [sx, sy] = localXY(ev);
    const [wx, wy] = toWorld(sx, sy);
    $("cursor").textContent = "x " + wx.toFixed(2) + " m, y " + wy.toFixed(2) + " m";
    if (!pointers.has(ev.pointerId)) return;
    pointers.set(ev.pointerId, [sx, sy]);
    if (pinch && pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      const d = Math.hypot(a[0] - b[0], a[1] - b[1]);
      if (pinch.d > 0) zoomAt((a[0] + b[0]) / 2, (a[1] + b[1]) / 2, d / pinch.d);
      pinch.d = d;
      return;
    }
    if (!drag) return;
    drag.sx = sx; drag.sy = sy;
    if (drag.kind === "pan") {
      view.cx = drag.cx - (sx - drag.sx0) / view.scale;
      view.cy = drag.cy + (sy - drag.sy0) / view.scale;
    }
    view.dirty = true;
  });
  const endPointer = (ev) => {
    pointers.delete(ev.pointerId);
    if (pointers.size < 2) pinch = null;
    if (!drag) { dragging = false; return; }
    const d = drag; drag = null; dragging = false; view.dirty = true;
    if (d.kind !== "arrow" || ev.type === "pointercancel") return;
    const moved = Math.hypot(d.sx - d.sx0, d.sy - d.sy0) > 12;
    const yaw = moved ? Math.atan2(-(d.sy - d.sy0), d.sx - d.sx0) : null;
    onMapAction(d.wx, d.wy, yaw);
  };
  canvas.addEventListener("pointerup", endPointer);
  canvas.addEventListener("pointercancel", endPointer);
  canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const [sx, sy] = localXY(ev);
    zoomAt(sx, sy, Math.exp(-ev.deltaY * 0.0015));
  }, { passive: false });

  async function onMapAction(x, y, yaw) {
    const r2 = (v) => Math.round(v * 1000) / 1000;
    if (tool === "goal") {
      const goal = { x_m: r2(x), y_m: r2(y) };
      if (yaw !== null) goal.yaw_rad = r2(yaw);
      if (await command("goto", { goal })) toast("Goal sent: (" + goal.x_m.toFixed(2) + ", " + goal.y_m.toFixed(2) + ")");
    } else if (tool === "waypoint") {
      const p = editPath();
      if (!p) { $("pathsCard").open = true; showMsg($("pathEditMsg"), "Choose a path to edit (or make a new one) first.", "error"); return; }
      const body = { x_m: r2(x), y_m: r2(y) };
      if (yaw !== null) body.yaw_rad = r2(yaw);
      try {
        await api("POST", "/api/paths/" + p.id + "/waypoints", body);
        showMsg($("pathEditMsg"), "Added waypoint " + (p.waypoints.length + 1) + " to “" + p.name + "”.", "ok");
      } catch (e) { showMsg($("pathEditMsg"), e.message, "error"); $("pathsCard").open = true; }
    } else if (tool === "pose") {
      if (!S.control) { toast("Viewing only: control needs the token.", true); return; }
      try {
        await api("POST", "/api/initial_pose", { x_m: r2(x), y_m: r2(y), yaw_rad: r2(yaw === null ? 0 : yaw) });
        toast("Position set: (" + x.toFixed(2) + ", " + y.toFixed(2) + ")");
      } catch (e) { toast(e.message, true); }
    }
  }

  // ----- controls ---------------------------------------------------------------------------------
  $("goHome").addEventListener("click", () => command("go_home"));
  $("pause").addEventListener("click", () => command($("pause").dataset.action || "pause"));
  $("helpDone").addEventListener("click", () => command("help_done"));
  $("startTour").addEventListener("click", () => command("start_tour"));
  $("cancelTrip").addEventListener("click", () => command($("cancelTrip").dataset.action || "cancel"));
  $("estop").addEventListener("click", () => { stopTeleop(); command("estop"); });
  $("releaseEstop").addEventListener("click", () => command("release_estop"));
  $("pathForm").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const text = $("pathInput").value.trim();
    const msg = $("pathMsg");
    if (text === "") { showMsg(msg, "Type a path number first (e.g. 1), then press Enter.", "error"); return; }
    if (!/^\d+$/.test(text)) {
      showMsg(msg, "“" + text + "” is not a path number. Type a whole number like 1.", "error");
      return;
    }
    const ids = S.paths.map((p) => p.id).sort((a, b) => a - b);
    if (ids.length && !ids.includes(Number(text))) {
      showMsg(msg, "There is no path " + Number(text) + "; paths are " + describeIds(ids), "error");
      return;
    }
    if (await command("select_path", { path_id: Number(text) }, msg)) {
      const p = S.paths.find((q) => q.id === Number(text));
      showMsg(msg, "Path " + text + (p && p.name ? " “" + p.name + "”" : "") + " sent — watch the status line.", "ok");
    }
  });
  for (const b of document.querySelectorAll(".tool")) b.addEventListener("click", () => setTool(b.dataset.tool));
  $("zoomIn").addEventListener("click", () => zoomAt(W / 2, H / 2, 1.3));
  $("zoomOut").addEventListener("click", () => zoomAt(W / 2, H / 2, 1 / 1.3));
  $("fit").addEventListener("click", () => { $("follow").checked = false; fitView(); });
  for (const id of ["showScan", "showPaths", "follow", "showCostmap"]) {
    const el = $(id);
    try { const v = localStorage.getItem("curio." + id); if (v !== null) el.checked = v === "1"; } catch (e) { /* ignore */ }
    el.addEventListener("change", () => {
      try { localStorage.setItem("curio." + id, el.checked ? "1" : "0"); } catch (e) { /* ignore */ }
      if (id === "showCostmap" && el.checked) for (const n of ["costmap", "local_costmap"]) if (S.grids[n]) loadGridImage(S.grids[n]);
      view.dirty = true;
    });
  }
  $("treeCard").addEventListener("toggle", renderTree);
  $("healthCard").addEventListener("toggle", renderHealth);

  // path editor
  $("editPath").addEventListener("change", () => {
    const v = $("editPath").value;
    S.editPathId = v === "" ? null : Number(v);
    showMsg($("pathEditMsg"), "");
    renderWaypoints(); view.dirty = true;
  });
  $("newPath").addEventListener("click", async () => {
    const name = $("pathName").value.trim() && !editPath() ? $("pathName").value.trim() : "New path " + (S.paths.length);
    try {
      const p = await api("POST", "/api/paths", { name });
      S.editPathId = p.id;
      if (!S.paths.some((q) => q.id === p.id)) S.paths.push(p);
      renderPaths();
      setTool("waypoint");
      showMsg($("pathEditMsg"), "Made “" + p.name + "” (path " + p.id + "). Click the map to add its waypoints.", "ok");
    } catch (e) { showMsg($("pathEditMsg"), e.message, "error"); }
  });
  $("renamePath").addEventListener("click", async () => {
    const p = editPath();
    if (!p) { showMsg($("pathEditMsg"), "Choose a path to rename first.", "error"); return; }
    try { await api("PATCH", "/api/paths/" + p.id, { name: $("pathName").value.trim() }); showMsg($("pathEditMsg"), "Renamed.", "ok"); }
    catch (e) { showMsg($("pathEditMsg"), e.message, "error"); }
  });
  $("deletePath").addEventListener("click", async () => {
    const p = editPath();
    if (!p) { showMsg($("pathEditMsg"), "Choose a path to delete first.", "error"); return; }
    if (!confirm("Delete path " + p.id + " “" + p.name + "”?")) return;
    try { await api("DELETE", "/api/paths/" + p.id); showMsg($("pathEditMsg"), "Deleted.", "ok"); }
    catch (e) { showMsg($("pathEditMsg"), e.message, "error"); }
  });

  // ----- teleop: joystick and keyboard, deadman ---------------------------------------------------
  const stick = { x: 0, y: 0, held: false, pointer: null };
  const keys = new Set();
  let teleopTimer = null;

  function limits() {
    const r = S.robot || {};
    return [r.max_speed_mps || 0.3, r.max_angular_radps || 1.0];
  }

  function teleopVector() {
    if (stick.held) return [stick.y, -stick.x];
    let f = 0, t = 0;
    if (keys.has("up")) f += 1;
    if (keys.has("down")) f -= 1;
    if (keys.has("left")) t += 1;
    if (keys.has("right")) t -= 1;
    return [f * 0.6, t * 0.7];
  }

  function sendTeleop(lin, ang) {
    if (!S.ws || S.ws.readyState !== WebSocket.OPEN || !S.control) return;
    S.teleopSeq += 1;
    S.ws.send(JSON.stringify({ op: "teleop", seq: S.teleopSeq, linear_mps: lin, angular_radps: ang }));
  }

  function teleopTick() {
    const [f, t] = teleopVector();
    const [vmax, wmax] = limits();
    sendTeleop(Math.round(f * vmax * 1000) / 1000, Math.round(t * wmax * 1000) / 1000);
  }

  function startTeleop() {
    if (!S.control) { toast("Viewing only: driving needs the token.", true); return false; }
    if (teleopTimer === null) { teleopTick(); teleopTimer = setInterval(teleopTick, 100); }
    return true;
  }

  function stopTeleop() {
    const wasActive = teleopTimer !== null;
    if (teleopTimer !== null) { clearInterval(teleopTimer); teleopTimer = null; }
    stick.held = false; stick.x = 0; stick.y = 0; keys.clear();
    placeKnob();
    if (wasActive) sendTeleop(0, 0);
  }

  const joy = $("joystick"), knob = $("knob");
  function placeKnob() {
    const R = joy.clientWidth / 2 - 28;
    knob.style.left = (joy.clientWidth / 2 - 28 + stick.x * R) + "px";
    knob.style.top = (joy.clientHeight / 2 - 28 - stick.y * R) + "px";
    joy.classList.toggle("held", stick.held);
  }
  function stickFrom(ev) {
    const r = joy.getBoundingClientRect();
    const R = r.width / 2 - 28;
    let dx = (ev.clientX - r.left - r.width / 2) / R, dy = -(ev.clientY - r.top - r.height / 2) / R;
    const m = Math.hypot(dx, dy);
    if (m > 1) { dx /= m; dy /= m; }
    stick.x = Math.abs(dx) < 0.08 ? 0 : dx; stick.y = Math.abs(dy) < 0.08 ? 0 : dy;
    placeKnob();
  }
  joy.addEventListener("pointerdown", (ev) => {
    ev.preventDefault();
    if (!startTeleop()) return;
    joy.setPointerCapture(ev.pointerId);
    stick.held = true; stick.pointer = ev.pointerId;
    stickFrom(ev);
  });
  joy.addEventListener("pointermove", (ev) => { if (stick.held && ev.pointerId === stick.pointer) stickFrom(ev); });
  for (const t of ["pointerup", "pointercancel", "lostpointercapture"]) {
    joy.addEventListener(t, (ev) => { if (ev.pointerId === stick.pointer) stopTeleop(); });
  }
  const KEYMAP = { ArrowUp: "up", KeyW: "up", ArrowDown: "down", KeyS: "down", ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right" };
  window.addEventListener("keydown", (ev) => {
    const tag = (ev.target && ev.target.tagName) || "";
    if (ev.code === "Escape") { stopTeleop(); if (S.control) command("estop"); return; }
    if (tag === "INPUT" || tag === "SELECT" || tag === "TEXTAREA") return;
    const k = KEYMAP[ev.code];
    if (!k) return;
    ev.preventDefault();
    if (ev.repeat) return;
    if (!startTeleop()) return;
    keys.add(k);
  });
  window.addEventListener("keyup", (ev) => {
    const k = KEYMAP[ev.code];
    if (!k) return;
    keys.delete(k);
    if (keys.size === 0 && !stick.held) stopTeleop();
  });
  window.addEventListener("blur", stopTeleop);
  document.addEventListener("visibilitychange", () => {
    if (document.hidden) stopTeleop();
    // A hidden tab asks for 1 update a second (status and events still arrive at once).
    if (S.ws && S.ws.readyState === WebSocket.OPEN) S.ws.send(JSON.stringify({ op: "rate", hz: document.hidden ? 1 : 60 }));
  });

  // ----- start ------------------------------------------------------------------------------------
  async function start() {
    S.token = loadToken();
    if (S.token) {
      try {
        const a = await api("GET", "/api/auth");
        S.control = !!a.control;
        if (!a.control) {
          toast("The saved control token was not accepted; this page is view-only. Open the link from the rover's start-up log.", true);
          try { localStorage.removeItem("curio.token"); } catch (e) { /* ignore */ }
          S.token = null;
        }
      } catch (e) { S.control = true; }
    } else {
      try { const a = await api("GET", "/api/auth"); S.control = !!a.control; } catch (e) { S.control = false; }
    }
    setConn();
    renderStatus();
    connect();
  }
  window.addEventListener("resize", resize);
  resize();
  setTool("look");
  setInterval(() => {
    if (S.connected && Date.now() - S.lastMsgAt > 5000 && S.ws) { S.ws.close(); }
    renderHelp();
  }, 1000);
  requestAnimationFrame(frame);
  window.curio = { S, view, setTool, toWorld, toScreen };
  start();
})();
