// Curio operator dashboard — the live link and the buttons. Everything shown comes from the
// rover; controls never guess state. The page says Offline the moment the link drops (or when
// nothing arrived for LINK_SILENT_S), greys what it last saw with its age, and reconnects by
// itself. The token travels as a WebSocket subprotocol, never in a URL.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const FRAME = { SCAN: 1, POSE: 2, PLAN: 3, LOCAL_PLAN: 4, TRUTH: 5 };
  const LINK_SILENT_S = 2.5;   // no message (pongs included) for this long: the link is dead
  const RECONNECT_MAX_MS = 2000;

  // ----- WebSocket --------------------------------------------------------------------------------
  let backoff = 250;
  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const protocols = ["curio.v1"];
    if (S.token) protocols.push("curio.token." + S.token);
    let ws;
    try { ws = new WebSocket(proto + "//" + location.host + "/ws", protocols); } catch (e) { scheduleReconnect(); return; }
    ws.binaryType = "arraybuffer";
    S.ws = ws;
    let opened = false;
    ws.onopen = () => { backoff = 250; opened = true; };
    ws.onmessage = (ev) => {
      if (S.ws !== ws) return;
      S.lastMsgAt = Date.now();
      S.rx.any = S.lastMsgAt;
      if (!S.connected) { S.connected = true; S.everConnected = true; S.offlineSince = null; C.renderChips(); C.renderStatus(); }
      if (typeof ev.data === "string") onJson(JSON.parse(ev.data));
      else onBinary(ev.data);
    };
    ws.onclose = (ev) => {
      if (S.ws !== ws) return;
      goOffline();
      if (ev.code === 4001) dropToken();  // the token was revoked or rotated
      if (!opened && S.token) checkToken().then(scheduleReconnect);  // refused: was it the token?
      else scheduleReconnect();
    };
    ws.onerror = () => { /* onclose follows */ };
  }
  function dropToken() {
    C.toast("Your token was revoked or replaced: this page is view-only now. Ask for a new link.", true);
    try { localStorage.removeItem("curio.token"); } catch (e) { /* ignore */ }
    S.token = null;
    S.who = { name: "viewer", role: "viewer", permissions: [] };
    C.renderChips();
  }
  async function checkToken() {
    try { await C.api("GET", "/api/auth"); } catch (e) { if (e.status === 403) dropToken(); }
  }
  function scheduleReconnect() {
    setTimeout(connect, backoff);
    backoff = Math.min(RECONNECT_MAX_MS, backoff * 2);
  }
  function goOffline() {
    const ws = S.ws;
    S.ws = null;
    if (S.connected) S.offlineSince = Date.now();
    S.connected = false;
    C.stopTeleop();
    if (ws) { ws.onclose = null; ws.onmessage = null; try { ws.close(); } catch (e) { /* already closed */ } }
    C.renderChips(); C.renderStatus(); C.renderLease();
    C.view.dirty = true;
  }

  function onJson(m) {
    for (const fn of C.listeners[m.t] || []) fn(m);  // other modules (tours, ...) hear it too
    switch (m.t) {
      case "hello":
        S.clientId = m.client; S.who = m.who || S.who; S.requireToken = !!m.require_token;
        C.renderChips(); break;
      case "state": onState(m); break;
      case "status": S.status = m.status; if (m.help) S.help = m.help; C.renderStatus(); break;
      case "progress": S.progress = m.progress; C.renderProgress(); C.renderStatus(); break;
      case "event": if (m.help) S.help = m.help; C.addEvent(m.event, false); C.renderHelp(); break;
      case "estop": onEstop(m); break;
      case "lease": C.onLease(m.lease); break;
      case "goal": S.goal = m.goal; C.renderProgress(); C.view.dirty = true; break;
      case "blocker": S.blocker = m.blocker; C.view.dirty = true; break;
      case "paths": S.paths = m.paths; C.renderPaths(m); break;
      case "tree": S.tree = m.tree; if ($("treeCard").open) C.renderTree(); break;
      case "health": S.health = m; S.rx.health = Date.now(); C.renderHealth(); break;
      case "grid": C.onGrid(m.grid); break;
      case "obstacles": S.obstacles = m; S.rx.obstacles = Date.now(); C.view.dirty = true; break;
      case "localization": S.loc = m.localization; S.rx.loc = Date.now(); C.renderChips(); break;
      case "battery": S.battery = m.battery; S.rx.battery = Date.now(); C.renderChips(); break;
      case "cmd_vel":
        S.rx.cmdVel = Date.now();
        $("cmdVel").textContent = m.linear_mps.toFixed(2) + " m/s\n" + m.angular_radps.toFixed(2) + " rad/s";
        $("cmdVel").title = "what the wheels are told now (after the safety stage)";
        break;
      case "error":
        if (m.code === "lease_held") C.onLeaseRefused(m.holder);
        else if (m.id && C.pending.has(m.id)) C.answer(m.id, false, m.message);
        else C.toast(m.message, true);
        break;
      case "ack":
        if (m.action === "estop") $("estopFail").classList.add("hidden");
        break;
      default: break;
    }
  }

  function onState(m) {
    S.status = m.status; S.progress = m.progress; S.estop = m.estop; S.estopLog = m.estop_log;
    S.help = m.help || { active: false }; S.paths = m.paths || []; S.tree = m.tree; S.health = m.health;
    S.robot = m.robot; S.goal = m.goal; S.blocker = m.blocker; S.bounds = m.map_bounds;
    S.loc = m.localization; S.battery = m.battery;
    const t = Date.now();
    if (m.localization) S.rx.loc = t;
    if (m.battery) S.rx.battery = t;
    S.rx.health = t;
    for (const g of Object.values(m.grids || {})) if (g) C.onGrid(g);
    $("events").textContent = "";
    for (const ev of m.events || []) C.addEvent(ev, true);
    C.onLease(m.lease);
    C.renderStatus(); C.renderProgress(); C.renderPaths(); C.renderTree(); C.renderHealth(); C.renderChips();
    C.view.dirty = true;
  }

  function onEstop(m) {
    const was = !!(S.estop && S.estop.engaged);
    S.estop = m.estop; S.estopLog = m.log || S.estopLog;
    const on = !!(S.estop && S.estop.engaged);
    if (on) C.answerAction("estop", true, "E-stop engaged by " + C.nameOf(S.estop.source) + ": the rover will not move.");
    if (!on && was) {
      C.answerAction("release_estop", true, "E-stop released by " + C.nameOf(S.estop.source) + ".");
      C.toast("E-stop released by " + C.nameOf(S.estop.source) + ".");
    }
    C.renderStatus();
  }

  function onBinary(buf) {
    const dv = new DataView(buf);
    const type = dv.getUint8(0);
    const stamp = dv.getFloat64(8, true);
    const off = 16;
    if (type === FRAME.SCAN) {
      const lx = dv.getFloat32(off, true), ly = dv.getFloat32(off + 4, true), lyaw = dv.getFloat32(off + 8, true);
      const amin = dv.getFloat32(off + 12, true), ainc = dv.getFloat32(off + 16, true), n = dv.getUint32(off + 20, true);
      const pts = new Float32Array(n * 2);
      let k = 0;
      for (let i = 0; i < n; i++) {
        const mm = dv.getUint16(off + 24 + 2 * i, true);
        if (mm === 0) continue;
        const a = lyaw + amin + i * ainc, r = mm / 1000;
        pts[k++] = lx + r * Math.cos(a); pts[k++] = ly + r * Math.sin(a);
      }
      S.scan = { pts, n: k / 2, stamp };
      S.rx.scan = Date.now();
    } else if (type === FRAME.POSE || type === FRAME.TRUTH) {
      const p = { x: dv.getFloat32(off, true), y: dv.getFloat32(off + 4, true), yaw: dv.getFloat32(off + 8, true),
        std: [dv.getFloat32(off + 12, true), dv.getFloat32(off + 16, true), dv.getFloat32(off + 20, true)], stamp };
      if (type === FRAME.POSE) { S.rx.pose = Date.now(); C.onPose(p); } else S.truth = p;
    } else if (type === FRAME.PLAN || type === FRAME.LOCAL_PLAN) {
      const n = dv.getUint32(off, true);
      const xy = new Float32Array(buf, off + 4, n * 2).slice();
      if (type === FRAME.PLAN) S.plan = xy; else S.localPlan = xy;
    }
    C.view.dirty = true;
  }

  // ----- buttons ------------------------------------------------------------------------------------
  $("goHome").addEventListener("click", () => C.command("go_home"));
  $("pause").addEventListener("click", () => C.command($("pause").dataset.action || "pause"));
  $("helpDone").addEventListener("click", () => C.command("help_done"));
  $("startTour").addEventListener("click", () => C.command("start_tour"));
  $("cancelTrip").addEventListener("click", () => C.command($("cancelTrip").dataset.action || "cancel"));
  $("pathForm").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const text = $("pathInput").value.trim();
    const msg = $("pathMsg");
    if (text === "") { C.showMsg(msg, "Type a path number first (e.g. 1), then press Enter.", "error", 15); return; }
    if (!/^\d+$/.test(text)) { C.showMsg(msg, "“" + text + "” is not a path number. Type a whole number like 1.", "error", 15); return; }
    const ids = S.paths.map((p) => p.id).sort((a, b) => a - b);
    if (ids.length && !ids.includes(Number(text))) {
      const contiguous = ids.length > 2 && ids.every((v, i) => v === ids[0] + i);
      C.showMsg(msg, "There is no path " + Number(text) + "; paths are " + (contiguous ? ids[0] + "–" + ids[ids.length - 1] : ids.join(", ")), "error", 15);
      return;
    }
    C.command("select_path", { path_id: Number(text) }, msg);
  });

  // ----- once a second: ages, stale data, a ping that proves the link is alive ----------------------
  setInterval(() => {
    if (S.connected && Date.now() - S.lastMsgAt > LINK_SILENT_S * 1000) { goOffline(); scheduleReconnect(); }
    if (S.ws && S.ws.readyState === WebSocket.OPEN) S.ws.send(JSON.stringify({ op: "ping" }));
    C.renderHelp(); C.renderChips();
    if (!S.connected) { C.renderStatus(); C.renderHealth(); }
    const stale = !S.connected ? "Offline: the map shows what the rover sent " + C.fmtAge(C.ageS("any")) :
      (S.pose && C.isStale("pose") ? "No position from the rover for " + Math.round(C.ageS("pose")) + " s" : "");
    $("staleNote").textContent = stale;
    $("staleNote").classList.toggle("hidden", !stale || !S.everConnected);
    C.view.dirty = true;
  }, 1000);

  // ----- start ----------------------------------------------------------------------------------------
  async function start() {
    S.token = C.loadToken();
    if (S.token) {
      try {
        const a = await C.api("GET", "/api/auth");
        S.who = a.who;
      } catch (e) {
        if (e.status === 403) {
          C.toast("The saved token was not accepted (wrong, revoked or replaced): this page is view-only. Open a link with a valid token.", true);
          try { localStorage.removeItem("curio.token"); } catch (err) { /* ignore */ }
          S.token = null;
        }
      }
    }
    C.renderChips(); C.renderStatus(); C.renderLease();
    connect();
  }
  window.addEventListener("resize", C.resize);
  start();
})();
