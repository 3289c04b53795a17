// Curio operator dashboard — unattended operation (issue 11): the battery (state of charge,
// time left, level, charging) in the header chip; the dock (its state, Dock / Undock, the dock
// and its staging pose on the map); lost and found (a bar while the rover is lost or unsure,
// Relocalise, the spread sent with "Set position"); help (a red bar with the reason and how long
// the rover has waited, a chime at each request and repeat, what blocks it on the map, a test
// notification). Reads /api/unattended/ws (power, dock, help, zones, blockage); other modules
// hear its messages as C.on("u:<type>"). Map frame: metres, radians; rover times in seconds.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const U = { power: null, dock: null, dockInfo: null, help: null, zones: null, blockage: null,
    rx: {}, chimeKey: "", chimesAsked: 0, chimesPlayed: 0 };
  C.U = U;

  // ----- the rover's messages (the hub's socket: "u:power", "u:dock", "u:help", "u:zones", "u:blockage") --
  for (const t of ["power", "dock", "help", "zones", "blockage"]) {
    C.on("u:" + t, (m) => {
      U[t] = m.msg; U.rx[t] = Date.now();
      if (t === "help") onHelp(m.msg);
      if (t === "dock") loadDock();
      render();
      C.view.dirty = true;
    });
  }
  C.on("hello", () => loadDock());  // (re)connected: home and staging may have moved
  // The position line and the lost bar follow the hub's own messages (after app.js stored them).
  let soon = null;
  for (const t of ["localization", "status", "state", "event"]) {
    C.on(t, () => { if (!soon) soon = setTimeout(() => { soon = null; render(); }, 100); });
  }
  async function loadDock() {
    try { U.dockInfo = await C.api("GET", "/api/dock"); } catch (e) { U.dockInfo = null; }
    render(); C.view.dirty = true;
  }

  // ----- words --------------------------------------------------------------------------------------------
  function fmtDur(s) {
    if (s === null || s === undefined || !isFinite(s)) return "";
    if (s < 60) return Math.max(0, Math.round(s)) + " s";
    if (s < 600) return Math.floor(s / 60) + " min" + (Math.round(s % 60) ? " " + Math.round(s % 60) + " s" : "");
    if (s < 3600) return Math.round(s / 60) + " min";
    const h = Math.floor(s / 3600), m = Math.round((s - 3600 * h) / 60);
    return h + " h" + (m ? " " + m + " min" : "");
  }
  const pct = (soc) => Math.round(100 * soc) + " %";
  const DOCK_WORDS = { idle: "not docked", staging: "driving to the dock", approaching: "docking (final approach)",
    backing_off: "backing off to try again", docked: "on the dock", undocking: "leaving the dock", failed: "docking failed" };
  const REASON_WORDS = { blocked: "its way is blocked", lost: "it does not know where it is",
    battery_critical: "its battery is almost empty", dock_failed: "it could not dock" };

  // ----- the battery chip (replaces the raw voltage when /power is known) ----------------------------------
  function renderPowerChip() {
    const p = U.power, el = $("batteryChip");
    if (!p) return;
    const stale = !S.connected || Date.now() - (U.rx.power || 0) > 15000;
    const icon = p.charging ? "⚡" : "";  // (no emoji: a kiosk browser may lack the font)
    let long = "Battery " + pct(p.soc);
    if (p.charging) long += " · charging" + (p.time_to_full_s ? ", full in " + fmtDur(p.time_to_full_s) : "");
    else if (p.time_left_s) long += " · " + fmtDur(p.time_left_s) + " left";
    if (p.level !== "ok") long += " · " + p.level.toUpperCase();
    el.textContent = "";
    for (const [text, c] of [[(icon ? icon + " " : "") + long, "long"], [(icon || "Bat ") + pct(p.soc).replace(" ", "") + (p.level !== "ok" ? "!" : ""), "short"]]) {
      const span = document.createElement("span");
      span.className = c; span.textContent = text;
      el.appendChild(span);
    }
    const cls = stale ? "stale" : (p.level === "critical" ? "bad critical" : (p.level === "low" ? "bad" : (p.charging ? "ok charging" : "ok")));
    el.className = "chip " + cls;
    el.dataset.level = p.level;
    el.title = "battery: " + p.voltage_v.toFixed(2) + " V (filtered), " + pct(p.soc) + " charged" +
      (p.time_left_s ? ", about " + fmtDur(p.time_left_s) + " left at this drain" : "") +
      (p.time_to_low_s ? ", low in " + fmtDur(p.time_to_low_s) : "") + (p.charging ? ", on the charger" : "") +
      (stale ? " — last heard " + C.fmtAge((Date.now() - (U.rx.power || 0)) / 1000) : "");
  }
  const baseChips = C.renderChips;
  C.renderChips = () => { baseChips(); renderPowerChip(); };

  // ----- help: the red bar, the chime, how long it has waited -------------------------------------------------
  function roverNow() {  // the rover's clock now, s (its stamps, as they arrive)
    return Math.max(S.pose ? S.pose.stamp : -Infinity, U.power ? U.power.stamp : -Infinity, U.help ? U.help.stamp : -Infinity);
  }
  function onHelp(h) {  // a new request or a repeat (the desk sets `sound` for both) chimes once
    if (!h || !h.active) return;
    const key = h.since_s + ":" + h.repeats;
    if (key === U.chimeKey) return;
    U.chimeKey = key;
    chime();
  }
  function chime() {  // three soft rising tones (drive.js's player: Web Audio, after a gesture, unless muted)
    U.chimesAsked += 1;
    if (C.playTones([[523, 0], [784, 0.25], [1047, 0.5]], "sine", 0.25, 0.35)) U.chimesPlayed += 1;
  }
  const lostNow = () => (S.loc && S.loc.state === "lost") || (S.status && /^lost\b/i.test(S.status.text || ""));
  const unsureNow = () => S.loc && S.loc.state === "uncertain";
  function renderBar() {
    const bar = $("uBar");
    const h = U.help && U.help.active ? U.help : null;
    const hubHelp = S.help && S.help.active ? S.help : null;
    let text = "", cls = "";
    if (h || hubHelp) {
      const why = h && !h.message && REASON_WORDS[h.reason] ? " — " + REASON_WORDS[h.reason] : "";
      const waited = h && h.since_s !== null && h.since_s !== undefined ? roverNow() - h.since_s : null;
      const said = (h && h.message) || (hubHelp && hubHelp.message) || "the rover needs a person";
      text = (/^help/i.test(said) ? "" : "HELP: ") + said + why +
        (waited !== null && isFinite(waited) ? " · waiting " + fmtDur(Math.max(0, waited)) : "") +
        (h && h.repeats ? " · asked " + (h.repeats + 1) + " times" : "");
      cls = "help";  // (data-kind; the class is u-help: .help is the HELP ME button's)
    } else if (lostNow()) {
      text = "Lost: the rover is looking around to find where it is. Relocalise, or set its position on the map.";
      cls = "lost";
    } else if (unsureNow()) {
      text = "Position uncertain (± " + S.loc.std_xy_m.toFixed(2) + " m): the rover drives carefully; set its position if it is wrong.";
      cls = "unsure";
    }
    bar.textContent = text;
    bar.className = "uBar" + (cls ? " u-" + cls : "") + (text ? "" : " hidden");
    bar.dataset.kind = cls;
  }

  // ----- the card: battery, dock, position, notifications ---------------------------------------------------------
  function renderCard() {
    const p = U.power;
    $("uBattery").textContent = p ? "Battery " + pct(p.soc) + " (" + p.voltage_v.toFixed(2) + " V)" +
      (p.charging ? ", charging" + (p.time_to_full_s ? " — full in about " + fmtDur(p.time_to_full_s) : "") :
        (p.time_left_s ? ", about " + fmtDur(p.time_left_s) + " left" : "")) + " · level " + p.level :
      "Battery: no reading yet.";
    $("uBattery").className = "uLine lvl-" + (p ? p.level : "none");
    const info = U.dockInfo, d = U.dock;
    let dockText;
    if (!info) dockText = "Dock: unknown (the rover has not said).";
    else if (!info.enabled) dockText = "No dock (dock.enabled = false): Go Home drives home.";
    else {
      const st = d ? d.state : (info.state ? info.state.state : "idle");
      dockText = "Dock: " + (DOCK_WORDS[st] || st) + (d && d.attempt > 1 && st !== "docked" ? " (attempt " + d.attempt + ")" : "") +
        (d && d.charging ? ", charging" : "") + (d && d.error_m !== null && d.error_m !== undefined ?
        " · last docking " + (100 * d.error_m).toFixed(1) + " cm, " + Number(d.error_deg).toFixed(1) + "° off" : "") +
        (d && d.detail && !["docked", "idle"].includes(d.state) ? " — " + d.detail : "");
    }
    $("uDock").textContent = dockText;
    $("uDock").dataset.state = d ? d.state : "";
    const docked = !!(d && d.state === "docked");
    const enabled = !!(info && info.enabled);
    const busy = !!(d && !["idle", "failed", "docked"].includes(d.state));  // docking or undocking now
    $("uDockBtn").disabled = !C.may("command") || !enabled || docked || busy;
    $("uUndockBtn").disabled = !C.may("command") || !enabled || !docked;
    const loc = S.loc;
    $("uLoc").textContent = loc ? "Position: " + ({ ok: "sure", uncertain: "uncertain", lost: "LOST", off: "odometry only" }[loc.state] || loc.state) +
      (loc.std_xy_m ? " (± " + loc.std_xy_m.toFixed(2) + " m, ± " + Math.round(loc.std_yaw_rad * 180 / Math.PI) + "°)" : "") :
      "Position: no report yet.";
    $("uLoc").className = "uLine loc-" + (loc ? loc.state : "none");
    $("uRelocalise").disabled = !C.may("initial_pose");
    $("uSetPose").disabled = !C.may("initial_pose");
    $("uNotify").disabled = !C.may("command");
  }

  async function post(path, okText, body) {
    const el = $("uMsg");
    C.showMsg(el, "Sent — waiting for the rover…", "wait");
    try {
      const out = await C.api("POST", path, body);
      C.showMsg(el, okText(out), "ok", 15);
      return out;
    } catch (e) { C.showMsg(el, e.message, "error", 20); return null; }
  }

  // Small builders for the cards (zones.js uses them too): an element, a button, a row.
  const el = (tag, id, cls, text) => {
    const e = document.createElement(tag);
    if (id) e.id = id; if (cls) e.className = cls; if (text) e.textContent = text;
    return e;
  };
  const button = (id, text, title, cls) => {
    const b = el("button", id, cls, text);
    b.type = "button";
    if (title) b.title = title;
    return b;
  };
  const row = (...kids) => { const r = el("div", null, "row"); r.append(...kids); return r; };
  C.uiKit = { el, button, row };

  function buildCard() {
    const card = $("careCard");
    const sum = el("summary", null, null, "Battery, dock and position ");
    sum.appendChild(el("span", "uSummary", "small"));
    const dock = button("uDockBtn", "⚡ Dock now", "drive to the dock and dock (Go Home, with a dock)");
    const undock = button("uUndockBtn", "Undock", "back out of the dock");
    const reloc = button("uRelocalise", "⟳ Relocalise", "forget the position and search the whole map (the rover turns in place to look)");
    const setp = button("uSetPose", "Set position…", "then press where the rover is on the map and drag the way it faces");
    const notify = button("uNotify", "Send a test notification", "send a test message to every configured channel (webhook, ntfy)");
    const spread = el("select", "uSpread");
    spread.title = "how sure you are of the position you set";
    spread.setAttribute("aria-label", "spread of the position you set");
    for (const [v, t] of [["0.1", "± 0.1 m (sure)"], ["0.25", "± 0.25 m"], ["0.5", "± 0.5 m"], ["1", "± 1 m (rough)"]]) {
      const o = el("option", null, null, t); o.value = v; spread.appendChild(o);
    }
    spread.value = "0.25";
    card.append(sum, el("div", "uBattery", "uLine"), el("div", "uDock", "uLine"), row(dock, undock),
      el("div", "uLoc", "uLine"), row(reloc, setp, spread), row(notify), el("div", "uMsg", "msg"));
    dock.addEventListener("click", () => post("/api/dock", () => "Going to the dock…"));
    undock.addEventListener("click", () => post("/api/undock", () => "Leaving the dock…"));
    reloc.addEventListener("click", () => post("/api/relocalise", (o) => (o && o.message) || "Searching the whole map."));
    setp.addEventListener("click", () => { C.setTool("pose"); if (S.connected) C.showMsg($("uMsg"), "Press where the rover is on the map and drag the way it faces.", "ok", 15); });
    notify.addEventListener("click", () => post("/api/notify/test", (o) => "Test notification: " +
      (o.channels && o.channels.length ? "sent to " + o.channels.join(", ") + " (" + o.note + ")" : o.note)));
  }
  // "Set position" sends this spread (panels.js setPose); the map draws it while you drag.
  C.poseSpread = () => {
    const v = Number(($("uSpread") || {}).value || 0.25);
    return { std_xy_m: v, std_yaw_rad: Math.min(Math.PI, Math.max(0.05, v)) };
  };

  function render() {
    renderPowerChip(); renderBar(); renderCard();
    const p = U.power, d = U.dock;
    $("uSummary").textContent = (p ? "· " + pct(p.soc) + (p.charging ? " ⚡" : "") : "") + (d && d.state === "docked" ? " · docked" : "") +
      (lostNow() ? " · LOST" : "");
  }

  // ----- the map: the dock, its staging pose, what blocks the rover, the spread of a pose being set ----------------
  C.mapLayers.push((ctx, kit) => {
    const info = U.dockInfo;
    if (info && info.enabled && info.home) {
      const [hx, hy, hyaw] = info.home;
      const front = S.robot && S.robot.footprint ? Math.max(...S.robot.footprint.map((q) => q[0])) : 0.33;
      const c = Math.cos(hyaw), s = Math.sin(hyaw);
      const pt = (u, v) => kit.toScreen(hx + c * u - s * v, hy + s * u + c * v);
      ctx.beginPath();
      for (const [u, v] of [[front + 0.02, -0.4], [front + 0.02, -0.15], [front + 0.14, 0], [front + 0.02, 0.15],
        [front + 0.02, 0.4], [front + 0.12, 0.4], [front + 0.12, -0.4]]) {
        const [sx, sy] = pt(u, v);
        if (u === front + 0.02 && v === -0.4) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
      }
      ctx.closePath();
      ctx.fillStyle = "rgba(124,58,237,.55)"; ctx.fill();
      ctx.strokeStyle = "#5b21b6"; ctx.lineWidth = 2; ctx.stroke();
      if (C.view.scale > 45) {  // zoomed out, the label would sit on the rover's
        const [lx, ly] = pt(front + 0.07, -0.62);  // past the plate's end: clear of the rover's arrow
        ctx.font = "bold 12px system-ui, sans-serif";
        ctx.fillStyle = "rgba(255,255,255,.85)"; ctx.fillRect(lx - 16, ly - 9, 32, 16);
        ctx.fillStyle = "#5b21b6"; ctx.fillText("dock", lx - 13, ly + 4);
      }
      if (info.staging && C.view.scale > 25) {
        kit.drawHeading(info.staging[0], info.staging[1], info.staging[2], "rgba(124,58,237,.7)", 18);
        kit.drawMarker(info.staging[0], info.staging[1], "rgba(124,58,237,.7)", "S", 7);
      }
    }
    const h = U.help && U.help.active ? U.help : null;
    if (h && U.blockage && U.blockage.circles && U.blockage.circles.length) {
      ctx.strokeStyle = "#7f1d1d"; ctx.lineWidth = 2;
      for (const [x, y] of U.blockage.circles) {
        const [sx, sy] = kit.toScreen(x, y);
        ctx.beginPath(); ctx.moveTo(sx - 5, sy - 5); ctx.lineTo(sx + 5, sy + 5); ctx.moveTo(sx + 5, sy - 5); ctx.lineTo(sx - 5, sy + 5); ctx.stroke();
      }
    }
    if (h && h.blocked_at) {
      const [sx, sy] = kit.toScreen(h.blocked_at[0], h.blocked_at[1]);
      ctx.strokeStyle = "#b91c1c"; ctx.lineWidth = 3;
      ctx.beginPath(); ctx.arc(sx, sy, 16, 0, 2 * Math.PI); ctx.stroke();
      ctx.font = "bold 12px system-ui, sans-serif";
      const t = "blocked here", w = ctx.measureText(t).width;
      const lx = Math.max(4, Math.min(kit.width - w - 8, sx - w / 2));  // under the ring, on the canvas
      ctx.fillStyle = "#7f1d1d"; ctx.fillRect(lx - 4, sy + 19, w + 8, 18);
      ctx.fillStyle = "#fff"; ctx.fillText(t, lx, sy + 32);
    }
    const drag = kit.drag;
    if (drag && drag.kind === "arrow" && C.tool === "pose") {  // the spread you are about to send
      const [sx, sy] = kit.toScreen(drag.wx0, drag.wy0);
      const r = C.poseSpread().std_xy_m * C.view.scale;
      ctx.beginPath(); ctx.arc(sx, sy, Math.max(4, r), 0, 2 * Math.PI);
      ctx.fillStyle = "rgba(124,58,237,.12)"; ctx.fill();
      ctx.setLineDash([5, 4]); ctx.strokeStyle = "#7c3aed"; ctx.lineWidth = 1.5; ctx.stroke(); ctx.setLineDash([]);
    }
  });

  // Events as sentences (the rover's own message when it has one).
  const said = (cls, fallback) => (d) => [cls, d.message || fallback(d)];
  Object.assign(C.EVENT_TEXT, {
    "battery.low": said("bad", () => "Battery low"),
    "battery.critical": said("bad", (d) => "Battery critical" + (d.voltage_v ? " (" + Number(d.voltage_v).toFixed(2) + " V)" : "")),
    "power.charging": (d) => (d.charging ? ["ok", "On the charger"] : ["", "Off the charger"]),
    "dock.started": said("", () => "Going to the dock"),
    "dock.staging_reached": said("", () => "In front of the dock: final approach"),
    "dock.attempt": said("", (d) => "Docking, attempt " + d.attempt),
    "dock.retry": said("warn", (d) => "Missed the dock" + (d.reason ? " (" + d.reason + ")" : "") + ": backing off to try again"),
    "dock.docked": said("ok", (d) => "Docked" + (d.error_m !== undefined ? " (" + (100 * d.error_m).toFixed(1) + " cm off)" : "")),
    "dock.failed": said("bad", () => "Docking failed"),
    "dock.undocked": said("", () => "Left the dock"),
    "dock.left": said("", () => "Off the dock"),
    "localization.lost": said("bad", () => "Lost: looking around"),
    "localization.jump": said("warn", (d) => "The position estimate jumped " + (d.distance_m ? Number(d.distance_m).toFixed(1) + " m" : "")),
    "localization.search": said("warn", () => "Searching the whole map"),
    "localization.found": said("ok", () => "Found: I know where I am again"),
    "zones.changed": (d) => ["who", "Zone " + d.zone_id + " " + d.change + (d.actor ? " by " + d.actor : "")],
    "notify.sent": (d) => ["ok", "Notification sent" + (d.channel ? " (" + d.channel + ")" : "")],
    "notify.failed": (d) => ["bad", "Notification failed" + (d.channel ? " (" + d.channel + ")" : "") + (d.error ? ": " + d.error : "")],
    "people.excuse_me": said("", () => "“Excuse me”: waiting for people to make way"),
  });

  // The legend: what this module draws.
  for (const [cls, text] of [["dock", "dock"], ["blockx", "seen blocking (help)"]]) {
    const span = document.createElement("span");
    const i = document.createElement("i"); i.className = "sw " + cls;
    span.append(i, text);
    $("legend").appendChild(span);
  }

  buildCard();
  render();
  setInterval(render, 1000);  // the wait time counts on; stale battery readings grey out
})();
