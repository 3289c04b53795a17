// Curio operator dashboard — the panels: the status line, buttons that show the rover's real
// state, progress squares, the path editor, events in wall-clock time as sentences, the health
// of every part with its age, the behaviour tree, the e-stop's who and when.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;

  const STATE_WORDS = {
    moving: ["Moving", "The rover is driving to its next stop."],
    arrived: ["Arrived", "The rover reached its stop. Type a path number or press Go Home."],
    paused: ["Paused", "The rover is holding still. Press Resume to continue."],
    going_home: ["Going home", "The rover is driving back to its home position."],
    needs_help: ["Needs help", "The way is blocked (drawn in red on the map). Please clear it, then press “I cleared the way”."],
    idle: ["Idle", "Waiting for a command: type a path number and press Enter, or press Go Home."],
    estop: ["E-STOP", "Emergency stop engaged. Release it when it is safe."],
    tour: ["Giving a tour", "The rover is guiding visitors along the tour."],
    manual: ["Driving by hand", "Someone is driving with the joystick; the rover's own trip waits."],
    offline: ["Offline", "No connection to the rover: what you see is old. The page reconnects by itself; nothing is sent while offline."],
  };

  // ----- status line and buttons ------------------------------------------------------------------
  function shownState() {
    if (!S.connected) return "offline";
    if (S.estop && S.estop.engaged) return "estop";
    if (S.lease && S.lease.holder && S.lease.driving) return "manual";
    return S.status ? S.status.state : "idle";
  }

  function renderStatus() {
    const st = S.status;
    const state = st ? st.state : "idle";
    const shown = shownState();
    const words = STATE_WORDS[shown] || [shown, ""];
    const badge = $("stateBadge");
    badge.textContent = words[0];
    badge.className = "badge s-" + shown;
    let text = st && st.text ? st.text : "Waiting for the rover…";
    if (shown === "offline") {
      text = S.everConnected ? "Offline — last news from the rover " + C.fmtAge(C.ageS("any")) : "Connecting to the rover…";
    } else if (shown === "manual") {
      text = (S.lease.holder === S.who.name ? "You are" : S.lease.holder + " is") + " driving by hand";
    }
    let hint = words[1];
    if (text.trim().toLowerCase() === words[0].toLowerCase()) { text = words[1]; hint = ""; }  // no "Idle Idle"
    $("statusText").textContent = text;
    if (S.connected && !S.who.permissions.length) hint += " (Viewing only: use a link with a token to control.)";
    $("stateHint").textContent = hint;
    $("sticky").classList.toggle("offline", !S.connected);
    renderButtons(state);
    renderEstop();
    renderHelp();
  }

  function renderButtons(state) {
    const pause = $("pause");
    const paused = state === "paused";
    pause.textContent = paused ? "▶ Resume" : "❚❚ Pause";
    pause.dataset.action = paused ? "resume" : "pause";
    pause.classList.toggle("paused", paused);
    const home = $("goHome");
    home.classList.toggle("on", state === "going_home");  // only while really going home
    home.textContent = state === "going_home" ? "⌂ Going home…" : "⌂ Go Home";
    const isTour = S.robot && S.robot.tree === "tour";
    $("startTour").classList.toggle("hidden", !isTour);
    const tripOn = ["moving", "going_home", "tour", "paused", "needs_help"].includes(state);
    $("cancelTrip").classList.toggle("hidden", !tripOn);
    $("cancelTrip").dataset.action = state === "tour" ? "stop_tour" : "cancel";
    for (const id of ["goHome", "pause", "cancelTrip", "pathEnter", "helpDone"]) $(id).disabled = !C.may("command");
    for (const id of ["newPath", "renamePath", "deletePath"]) $(id).disabled = !C.may("paths");
    $("startTour").disabled = !C.may("tour") || state === "tour";
    if (state === "tour" && C.may("tour")) $("cancelTrip").disabled = false;
    $("releaseEstop").disabled = !C.may("estop");
    $("estop").disabled = !C.mayOffline("estop");  // tried even while the live link is down
    $("speed").disabled = !C.mayOffline("drive");
    $("joystick").classList.toggle("disabled", !C.may("drive"));
  }

  function renderEstop() {
    const on = !!(S.estop && S.estop.engaged);
    const log = S.estopLog || {};
    $("estop").classList.toggle("engaged", on);
    $("estop").title = on ? "The e-stop is engaged (press again to repeat it; release it in the red bar)" :
      "Emergency stop (key: Esc, outside text boxes)";
    $("estopBanner").classList.toggle("hidden", !on);
    if (on) {
      const who = C.nameOf(log.set_by || S.estop.source), when = log.set_at ? C.clockTime(log.set_at) : "";
      const el = $("estopWho");
      el.textContent = "";
      const long = document.createElement("span");
      long.className = "long";
      long.textContent = "EMERGENCY STOP by " + who + (when ? " at " + when : "") + " — the rover will not move.";
      const short = document.createElement("span");
      short.className = "short";
      short.textContent = "E-STOP by " + who + (when ? " · " + when : "");
      el.append(long, short);
    }
    const el = $("estopLog");
    if (log.set_by) {
      el.textContent = "Last e-stop: set by " + C.nameOf(log.set_by) + " at " + C.clockTime(log.set_at) +
        (log.released_by ? "; released by " + C.nameOf(log.released_by) + " at " + C.clockTime(log.released_at) : "; not released yet") + ".";
    } else el.textContent = "";
  }

  function renderHelp() {
    const el = $("help");
    const active = S.help && S.help.active;
    if (active) {
      el.textContent = "HELP ME!";
      el.className = "help active";
      el.title = (S.help.message || "the way is blocked") + (C.may("command") ? " — tap when you cleared the way" : "");
    } else if (Date.now() < S.thanksUntil) {
      el.textContent = "Thanks!";
      el.className = "help thanks";
    } else {
      el.textContent = "All clear";
      el.className = "help clear";
    }
    $("helpActions").classList.toggle("hidden", !active);
    el.disabled = !(active && C.may("command"));
  }
  // HELP ME in the sticky bar is also the "I cleared the way" button (on a phone the card with
  // that button may be scrolled away).
  $("help").addEventListener("click", async () => {
    if (!(S.help && S.help.active) || !C.may("command")) return;
    if (await C.confirmBox("Is the way clear? The rover will continue.", "Yes, continue", "Not yet")) {
      C.command("help_done");
    }
  });

  function renderProgress() {
    const p = S.progress;
    const box = $("progress");
    box.textContent = "";
    const none = !p || !p.states || p.states.length === 0;
    $("progressBox").classList.toggle("empty", none);
    if (none) {
      $("progressTitle").textContent = S.goal ? "Driving to a single goal (no path)" : "No path running";
      return;
    }
    const reached = p.states.filter((s) => s === "reached").length;
    const what = p.path_id < 0 ? (p.path_name || "Tour") : "Path " + p.path_id + (p.path_name ? " “" + p.path_name + "”" : "");
    $("progressTitle").textContent = what + ": " + reached + " of " + p.states.length + " stops reached";
    p.states.forEach((s, i) => {
      const d = document.createElement("div");
      d.className = "sq " + s;
      d.textContent = String(i + 1);
      d.title = "stop " + (i + 1) + ": " + s;
      d.dataset.state = s;
      box.appendChild(d);
    });
  }

  const LOC_WORDS = { ok: ["Position OK", "Pos OK", "ok"], uncertain: ["Position uncertain", "Pos ?", "warn"],
    lost: ["Position lost — use “Set position”", "LOST", "bad"], off: ["Position from odometry", "Odom", "warn"] };
  function setChip(el, long, short, cls, title) {  // a long text, and a short one for phones
    el.textContent = "";
    for (const [text, c] of [[long, "long"], [short, "short"]]) {
      const span = document.createElement("span");
      span.className = c; span.textContent = text;
      el.appendChild(span);
    }
    el.className = "chip " + cls;
    el.title = title;
  }
  function renderChips() {
    const loc = $("locChip"), bat = $("batteryChip");
    if (S.loc) {
      const [text, short, cls] = LOC_WORDS[S.loc.state] || [S.loc.state, S.loc.state, "warn"];
      const stale = C.isStale("loc");
      const age = stale ? " · " + C.fmtAge(C.ageS("loc")) : "";
      setChip(loc, text + age, short, stale ? "stale" : cls,
        "how sure the rover is of where it is" + (stale ? " — last heard " + C.fmtAge(C.ageS("loc")) : ""));
    } else loc.className = "chip hidden";
    if (S.battery) {
      const stale = C.isStale("battery");
      const v = S.battery.voltage_v.toFixed(1) + " V" + (S.battery.low ? " LOW" : "");
      setChip(bat, "Battery " + v + (stale ? " · " + C.fmtAge(C.ageS("battery")) : ""), v,
        stale ? "stale" : (S.battery.low ? "bad" : "ok"),
        "servo battery voltage" + (stale ? " — last heard " + C.fmtAge(C.ageS("battery")) : ""));
    } else bat.className = "chip hidden";
    const who = $("who");
    const viewer = S.who.role === "viewer";
    setChip(who, viewer ? "View only" : S.who.name + " · " + S.who.role, viewer ? "View" : S.who.name, "",
      viewer ? "no token: you can watch, not control" : S.who.name + " (" + S.who.role + ") may: " + S.who.permissions.join(", "));
    who.className = "who " + S.who.role;
    const conn = $("conn");
    conn.textContent = S.connected ? "Live" : (S.everConnected ? "Offline" : "Connecting…");
    conn.className = "conn " + (S.connected ? "ok" : "bad");
  }

  // ----- paths and the path editor ------------------------------------------------------------------
  const editPath = () => S.paths.find((p) => p.id === S.editPathId) || null;

  function renderPaths(change) {
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
    else {
      if (keep !== null) {  // the path being edited is gone: say who did it, never silently
        const by = change && change.by && change.by !== S.who.name ? change.by : null;
        C.showMsg($("pathEditMsg"), "Path " + keep + ", which you were editing, was deleted" +
          (by ? " by " + by : "") + ".", by ? "error" : "ok", 30);
        if (by) C.toast(by + " deleted path " + keep + ", which you were editing.", true);
      }
      S.editPathId = null; sel.value = "";
    }
    if (change && change.by && change.by !== S.who.name && change.path_id === S.editPathId && change.change !== "deleted") {
      C.showMsg($("pathEditMsg"), change.by + " changed this path; you see the new version.", "ok", 15);
    }
    renderWaypoints();
    C.view.dirty = true;
  }

  function renderWaypoints() {
    const ol = $("waypoints");
    ol.textContent = "";
    const p = editPath();
    if (document.activeElement !== $("pathName")) $("pathName").value = p ? p.name : "";
    if (!p) return;
    const n = p.waypoints.length;
    p.waypoints.forEach((w, i) => {
      const li = document.createElement("li");
      const span = document.createElement("span");
      span.textContent = "(" + w.x_m.toFixed(2) + ", " + w.y_m.toFixed(2) + ")" +
        (w.yaw_rad === null ? "" : " facing " + Math.round(w.yaw_rad * 180 / Math.PI) + "°");
      li.appendChild(span);
      const btn = (label, title, disabled, fn) => {
        const b = document.createElement("button");
        b.type = "button"; b.textContent = label; b.title = title;
        b.disabled = disabled || !C.may("paths");
        b.onclick = fn;
        li.appendChild(b);
      };
      btn("↑", "move earlier", i === 0, () => reorder(i, i - 1));
      btn("↓", "move later", i === n - 1, () => reorder(i, i + 1));
      btn("×", "remove this waypoint", false, () => pathEdit("DELETE", "/waypoints/" + i + "?rev=" + p.rev, undefined, "Waypoint " + (i + 1) + " removed."));
      ol.appendChild(li);
    });
  }

  async function pathEdit(method, suffix, body, okText) {
    const p = editPath();
    const el = $("pathEditMsg");
    if (!p) { $("pathsCard").open = true; C.showMsg(el, "Choose a path to edit (or make a new one) first.", "error", 15); return null; }
    if (!C.may("paths")) { C.showMsg(el, S.connected ? "Editing paths needs an operator token." : "Offline: nothing was sent.", "error", 15); return null; }
    try {
      const out = await C.api(method, "/api/paths/" + p.id + suffix, body);
      C.showMsg(el, okText, "ok", 8);
      return out;
    } catch (e) {
      C.showMsg(el, e.message, "error", 20);
      $("pathsCard").open = true;
      return null;
    }
  }
  function reorder(from, to) {
    const p = editPath();
    const wps = p.waypoints.map((w) => ({ x_m: w.x_m, y_m: w.y_m, yaw_rad: w.yaw_rad }));
    const [moved] = wps.splice(from, 1);
    wps.splice(to, 0, moved);
    pathEdit("PUT", "/waypoints", { waypoints: wps, rev: p.rev }, "Waypoint " + (from + 1) + " is now number " + (to + 1) + ".");
  }
  function addWaypoint(x, y, yaw, index) {
    const p = editPath();
    const body = { x_m: x, y_m: y, rev: p ? p.rev : undefined };
    if (yaw !== null) body.yaw_rad = yaw;
    if (index !== null && index !== undefined) body.index = index;
    const where = index !== null && index !== undefined ? "Inserted waypoint " + (index + 1) : "Added waypoint " + (p ? p.waypoints.length + 1 : "");
    return pathEdit("POST", "/waypoints", body, where + (p ? " in “" + p.name + "”." : "."));
  }
  function moveWaypoint(index, x, y) {
    const p = editPath();
    return pathEdit("PATCH", "/waypoints/" + index, { x_m: x, y_m: y, rev: p ? p.rev : undefined }, "Moved waypoint " + (index + 1) + ".");
  }

  $("editPath").addEventListener("change", () => {
    const v = $("editPath").value;
    S.editPathId = v === "" ? null : Number(v);
    C.showMsg($("pathEditMsg"), "");
    renderWaypoints(); C.view.dirty = true;
  });
  $("newPath").addEventListener("click", async () => {
    const typed = $("pathName").value.trim();
    const name = typed && !editPath() ? typed : "New path " + S.paths.length;
    try {
      const p = await C.api("POST", "/api/paths", { name });
      S.editPathId = p.id;
      if (!S.paths.some((q) => q.id === p.id)) S.paths.push(p);
      renderPaths();
      C.setTool("waypoint");
      C.showMsg($("pathEditMsg"), "Made “" + p.name + "” (path " + p.id + "). Click the map to add its waypoints.", "ok", 15);
    } catch (e) { C.showMsg($("pathEditMsg"), e.message, "error", 20); }
  });
  $("renamePath").addEventListener("click", () => {
    const p = editPath();
    pathEdit("PATCH", "", { name: $("pathName").value.trim(), rev: p ? p.rev : undefined }, "Renamed.");
  });
  $("deletePath").addEventListener("click", async () => {
    const p = editPath();
    if (!p) { C.showMsg($("pathEditMsg"), "Choose a path to delete first.", "error", 15); return; }
    if (!(await C.confirmBox("Delete path " + p.id + " “" + p.name + "” for everyone?", "Delete", "Keep it"))) return;
    const id = p.id;
    if (await pathEdit("DELETE", "", undefined, "Deleted path " + id + ".")) { S.editPathId = null; renderPaths(); }
  });

  // ----- setting the pose: the answer is the rover's own pose afterwards --------------------------------
  let poseCheck = null;
  const near = (p, q, m, rad) => Math.hypot(p.x - q.x, p.y - q.y) < m &&
    Math.abs(Math.atan2(Math.sin(p.yaw - q.yaw), Math.cos(p.yaw - q.yaw))) < rad;
  const poseText = (p) => "(" + p.x.toFixed(2) + ", " + p.y.toFixed(2) + "), facing " + Math.round(p.yaw * 180 / Math.PI) + "°";
  async function setPose(x, y, yaw) {
    const el = $("cmdMsg");
    if (!C.may("initial_pose")) { C.toast(S.connected ? "Setting the position needs an operator token." : "Offline: nothing was sent.", true); return; }
    C.showMsg(el, "Position sent — waiting for the rover to take it…", "wait");
    try {
      // With its spread (unattended.js's choice) when the rover has /api/pose.
      await C.api("POST", C.poseSpread ? "/api/pose" : "/api/initial_pose", Object.assign({ x_m: x, y_m: y, yaw_rad: yaw }, C.poseSpread ? C.poseSpread() : {}));
    } catch (e) { C.showMsg(el, e.message, "error", 20); return; }
    C.flashPose(x, y, yaw);
    clearTimeout(poseCheck && poseCheck.timer);
    const before = S.pose ? Object.assign({}, S.pose) : null;
    poseCheck = { x, y, yaw, timer: setTimeout(() => {
      poseCheck = null;
      const p = S.pose;
      if (p && before && !near(p, before, 0.2, 0.3)) {
        C.showMsg(el, "The rover took the position and its laser corrected it: it now thinks it is at " + poseText(p) +
          ", " + Math.hypot(p.x - x, p.y - y).toFixed(2) + " m from where you set it.", "warn", 30);
      } else {
        C.showMsg(el, "The rover did not take the new position" + (p ? " (it still thinks it is at " + poseText(p) + ")" : "") +
          ". Is localisation running? See Health.", "error", 30);
      }
    }, 5000) };
  }
  C.onPoseForCheck = (p) => {
    if (!poseCheck || !near(p, poseCheck, 0.3, 0.3)) return;
    clearTimeout(poseCheck.timer);
    poseCheck = null;
    C.showMsg($("cmdMsg"), "The rover took the new position: it is at " + poseText(p) + ".", "ok", 12);
  };

  // ----- events as sentences in wall-clock time ---------------------------------------------------------
  const xy = (v) => (Array.isArray(v) ? "(" + Number(v[0]).toFixed(2) + ", " + Number(v[1]).toFixed(2) + ")" : "");
  const lastGoal = (d) => (Array.isArray(d.goal) && d.goal.length ? xy(d.goal[d.goal.length - 1]) : "");
  const pathName = (id) => (Number(id) < 0 ? "the tour" : "path " + id);
  const tagText = (tag) => {  // "web:alice goto" → "sent by alice"; "path 3 wp 0" → "path 3, stop 1"
    const t = String(tag || "");
    const goto = /^(web|kiosk):(\S+) goto$/.exec(t);
    if (goto) return "sent by " + (goto[2] === S.who.name ? "you" : goto[2]);
    const wp = /^path (-?\d+) wp (\d+)$/.exec(t);
    return wp ? pathName(wp[1]) + ", stop " + (Number(wp[2]) + 1) : t;
  };
  const stopName = (d) => (d.name ? "“" + d.name + "”" : (d.index !== null && d.index !== undefined ? "stop " + (Number(d.index) + 1) : "the stop")) +
    (d.x_m !== undefined ? " " + xy([d.x_m, d.y_m]) : "");
  const EVENT_TEXT = {
    "bt.command_accepted": (d) => ["ok", "✓ " + (d.message || d.action + " accepted")],
    "bt.command_rejected": (d) => ["bad", "✗ Refused: " + (d.message || d.action)],
    "bt.estop_released": (d) => ["", d.message || "The tree carries on after the e-stop"],
    "safety.estop": (d) => (d.engaged ? ["bad", "E-stop engaged by " + C.nameOf(d.source)] : ["ok", "E-stop released by " + C.nameOf(d.source)]),
    "safety.stop_zone": (d) => ["warn", "Stopped for an obstacle " + (d.clearance_m !== undefined ? d.clearance_m.toFixed(2) + " m away" : "ahead")],
    "safety.stop_zone_cleared": () => ["", "The way ahead is clear again"],
    "safety.watchdog": () => ["warn", "Velocity commands stopped arriving: slowing to a halt"],
    "safety.no_scan": (d) => (d.blind ? ["bad", "No lidar scan: the rover holds still"] : ["ok", "Lidar scans are back"]),
    "nav.goal_accepted": (d) => ["", "Driving to " + lastGoal(d) + (d.tag ? " (" + tagText(d.tag) + ")" : "")],
    "nav.goal_succeeded": (d) => ["ok", "Reached " + lastGoal(d) + (d.time_s ? " in " + Math.round(d.time_s) + " s" : "")],
    "nav.goal_aborted": (d) => ["bad", "Gave up driving to " + lastGoal(d) + ": " + (d.message || d.note || "")],
    "nav.goal_preempted": (d) => ["", "Goal " + lastGoal(d) + " replaced by a newer one"],
    "nav.goal_canceled": (d) => ["", "Goal " + lastGoal(d) + " cancelled"],
    "nav.goal_rejected": (d) => ["bad", "Goal refused: " + (d.message || d.code || "")],
    "nav.waypoint_reached": (d) => ["ok", "Reached waypoint " + (Number(d.index) + 1)],
    "nav.path_blocked": () => ["warn", "The planned route is blocked; looking for another"],
    "nav.recovery": (d) => [d.ok ? "" : "warn", "Trying to get free: " + String(d.step || "").replace(/_/g, " ") + (d.ok ? "" : " (did not help)")],
    "nav.blocked": (d) => ["warn", "Blocked: " + (d.reason || "an obstacle ahead")],
    "nav.unblocked": () => ["ok", "Not blocked any more"],
    "nav.holding": (d) => ["warn", "Holding still: " + (d.reason || "")],
    "nav.keep_out": (d) => ["", "Keeping out of " + xy([d.x, d.y])],
    "path.started": (d) => ["", "Started " + pathName(d.path_id) + (d.name ? " “" + d.name + "”" : "") + (d.index ? " at stop " + (d.index + 1) : "")],
    "path.interrupted": (d) => ["warn", "Interrupted " + pathName(d.path_id) + " at stop " + (Number(d.index) + 1)],
    "path.finished": (d) => ["ok", "Finished " + (d.name ? "“" + d.name + "”" : "the path") + (d.total ? ": " + d.reached + " of " + d.total + " stops reached" : "")],
    "waypoint.reached": (d) => ["ok", "Arrived at " + stopName(d)],
    "waypoint.failed": (d) => ["bad", "Could not reach " + stopName(d) + (d.message ? ": " + d.message : "")],
    "goal.preempted": (d) => ["", "Goal " + xy([d.x_m, d.y_m]) + " replaced"],
    "tour.stop": (d) => ["", d.message || "Tour stop " + stopName(d)],
    "tour.loop": (d) => ["", "The tour " + (d.name ? "“" + d.name + "” " : "") + "starts again"],
    "help.requested": (d) => ["bad", /^HELP ME/i.test(d.message || "") ? d.message : "HELP ME: " + (d.message || "the way is blocked")],
    "help.resolved": () => ["ok", "Thanks! The way is clear again"],
    "help.timeout": (d) => ["warn", d.message || "Still waiting for help"],
    "battery.low": (d) => ["bad", "Battery low" + (d.message ? ": " + d.message : "")],
    "battery.ok": (d) => ["ok", "Battery OK again" + (d.voltage_v ? " (" + Number(d.voltage_v).toFixed(1) + " V)" : "")],
    "driver.lidar_lost": (d) => ["bad", "Lidar lost: " + (d.reason || "")],
    "driver.lidar_recovered": () => ["ok", "Lidar back"],
    "driver.imu_lost": (d) => ["bad", "IMU lost: " + (d.reason || "")],
    "driver.imu_recovered": () => ["ok", "IMU back"],
    "paths.load_failed": (d) => ["bad", d.message || "The saved paths could not be read"],
    // After a crash, a power cut or a damaged file: what the rover found at its start.
    "system.unclean_restart": (d) => ["bad", d.message || "Restarted after an unclean stop (crash, kill or power cut)"],
    "data.restored": (d) => ["warn", d.message || "A damaged file was replaced by its backup"],
    "data.reset": (d) => ["bad", d.message || "A file and its backup could not be read: defaults are used"],
    "loop.stalled": (d) => ["warn", d.message || "The rover's loop was blocked for " + Number(d.blocked_s || 0).toFixed(1) + " s"],
    "driver.arduino_reset": () => ["warn", "The motor controller (Arduino) reset: its configuration was sent again"],
    "driver.imu_calibration_saved": () => ["ok", "IMU calibration saved"],
    "driver.imu_calibration_ignored": (d) => ["warn", "IMU calibration not restored" + (d.reason ? ": " + d.reason : "")],
  };
  // Told better by other lines (who changed which path is an operator.path event).
  const QUIET_EVENTS = new Set(["paths.changed"]);
  function eventSentence(ev) {
    const d = ev.detail || {};
    if (ev.kind.startsWith("operator.")) return [ev.kind === "operator.command" && d.action === "estop" ? "bad" : "who", (d.who === S.who.name ? "You (" + d.who + ")" : d.who) + " " + d.what];
    const f = EVENT_TEXT[ev.kind];
    if (f) return f(d);
    if (d.message) return ["", String(d.message)];  // the rover's own sentence
    const parts = Object.entries(d).slice(0, 4).map(([k, v]) => k.replace(/_/g, " ") + " " + (typeof v === "object" ? JSON.stringify(v) : v));
    return ["", ev.kind.replace(/[._]/g, " ") + (parts.length ? ": " + parts.join(", ") : "")];
  }

  function addEvent(ev, history) {
    if (QUIET_EVENTS.has(ev.kind)) return;
    const ol = $("events");
    const li = document.createElement("li");
    const [cls, text] = eventSentence(ev);
    const t = document.createElement("time");
    t.textContent = C.clockTime(ev.wall);
    li.appendChild(t);
    const span = document.createElement("span");
    span.textContent = text;
    li.appendChild(span);
    li.className = cls ? "ev-" + cls : "";
    li.title = ev.kind;
    li.dataset.kind = ev.kind;
    ol.insertBefore(li, ol.firstChild);
    while (ol.children.length > 150) ol.removeChild(ol.lastChild);
    if (!history) reactToEvent(ev, text);
  }

  function reactToEvent(ev, text) {
    const d = ev.detail || {};
    if (ev.kind === "bt.command_rejected" || ev.kind === "bt.command_accepted") {
      const ok = ev.kind === "bt.command_accepted";
      if (!C.answer(d.request_id, ok, d.message) && d.action === "select_path" && !ok && String(d.source).endsWith(":" + S.who.name)) {
        C.showMsg($("pathMsg"), d.message || "The rover refused the path.", "error", 20);
      }
    } else if ((ev.kind === "nav.goal_accepted" || ev.kind === "nav.goal_rejected") &&
               String(d.tag || "").endsWith(":" + S.who.name + " goto")) {
      // A single goal is answered by the navigator (the tree answers only when it leaves a path).
      const ok = ev.kind === "nav.goal_accepted";
      C.answerAction("goto", ok, ok ? "Driving to " + lastGoal(d) + "." : "The rover refused the goal: " + (d.message || d.code || "") );
    } else if (ev.kind.startsWith("operator.") && d.who !== S.who.name) {
      C.toast(text);  // someone else did something: every page says who
    } else if (ev.kind === "help.resolved") {
      S.thanksUntil = Date.now() + 15000;
      setTimeout(renderHelp, 15100);
    } else if (ev.kind === "tour.stop" && d.message) {
      C.toast(d.message);
    } else if (ev.kind === "battery.low") {
      C.toast(text, true);
    }
  }

  // ----- health: every part with its age ------------------------------------------------------------
  function fmtNum(v) {
    if (v === null || v === undefined) return "—";
    return Math.abs(v) >= 100 || Number.isInteger(v) ? String(Math.round(v)) : v.toFixed(2);
  }
  // One block per part, kept and updated in place (an opened list of figures stays open), in a
  // stable order by name: problems stand out by colour and in the summary line, and nothing
  // jumps under the operator's finger.
  const healthRows = new Map();
  function healthRow(box, name) {
    let row = healthRows.get(name);
    if (row) return row;
    row = document.createElement("div");
    row.dataset.name = name;
    const line = document.createElement("div");
    line.className = "hline";
    const pill = document.createElement("span");
    const label = document.createElement("b");
    label.className = "hname"; label.textContent = name;
    const age = document.createElement("span"); age.className = "hage";
    const rate = document.createElement("span"); rate.className = "hrate";
    line.append(pill, label, age);
    const msg = document.createElement("span"); msg.className = "hmsg";
    const second = document.createElement("div"); second.className = "hsecond";
    second.append(rate, msg);
    const det = document.createElement("details");
    det.append(document.createElement("summary"), document.createElement("ul"));
    row.append(line, second, det);
    healthRows.set(name, row);
    box.appendChild(row);
    return row;
  }
  function renderHealthSummary() {
    const comps = (S.health && S.health.components) || [];
    const bad = comps.filter((c) => ["error", "stale", "degraded"].includes(c.state));
    $("healthSummary").textContent = S.connected ? (bad.length ? "· " + bad.length + " need attention" : "· all parts OK") :
      "· offline: last report " + C.fmtAge(C.ageS("health"));
    $("healthSummary").className = "small " + (bad.length || !S.connected ? "warnText" : "okText");
  }
  function renderHealth() {
    const h = S.health;
    const box = $("health");
    renderHealthSummary();
    if (!h || !$("healthCard").open) return;
    const comps = (h.components || []).slice().sort((a, b) => a.name.localeCompare(b.name));
    const offlineAge = S.connected ? 0 : C.ageS("health");
    const seen = new Set();
    for (const c of comps) {
      const row = healthRow(box, c.name);
      seen.add(c.name);
      if (box.children[seen.size - 1] !== row) box.insertBefore(row, box.children[seen.size - 1] || null);
      row.className = "hpart st-" + c.state + (S.connected ? "" : " stale");
      const [pill, , age] = row.firstChild.children;
      const rate = row.children[1].firstChild;
      pill.className = "pill " + c.state; pill.textContent = c.state;
      age.textContent = c.age_s === null || c.age_s === undefined ? "never" : C.fmtAge(c.age_s + offlineAge);
      age.title = "last sign of life";
      rate.textContent = c.rate !== null && c.rate !== undefined ? fmtNum(c.rate) + " " + (c.what || "msgs") + "/s" : "";
      const msg = row.children[1].lastChild, det = row.children[2];
      msg.textContent = c.message || "";
      if (rate.textContent && c.message) rate.textContent += " · ";
      det.classList.toggle("hidden", !(c.counters && c.counters.length));
      det.firstChild.textContent = (c.counters || []).length + " figures";
      const ul = det.lastChild;
      ul.textContent = "";
      for (const k of c.counters || []) {
        const li = document.createElement("li");
        li.title = k.key;
        if (k.kind === "total") {
          li.textContent = k.label + ": " + (k.rate_per_s !== undefined ? fmtNum(k.rate_per_s) + "/s" : "—/s") + " (total " + fmtNum(k.value) + ")";
        } else li.textContent = k.label + ": " + fmtNum(k.value) + (k.unit ? " " + k.unit : "");
        ul.appendChild(li);
      }
    }
    for (const [name, row] of healthRows) if (!seen.has(name)) { row.remove(); healthRows.delete(name); }
    const bus = h.bus || {};
    const top = (bus.topics || []).slice(0, 3).map((t) => t.name + " " + fmtNum(t.dropped_per_s) + "/s" + (t.reliable ? " (RELIABLE: a fault)" : "")).join(", ");
    $("busNote").textContent = "Bus: " + fmtNum(bus.dropped_per_s || 0) + " messages/s replaced by newer ones before a slow reader took them" +
      (top ? " — " + top : "") + ". Normal for fast sensor streams, where only the newest matters; reliable topics never drop.";
    const sys = h.system || {};
    $("systemNote").textContent = "CPU " + (sys.cpu_fraction !== undefined ? Math.round(sys.cpu_fraction * 100) + " % of " + sys.cpu_count + " cores" : "—") +
      (sys.process_cpu_fraction !== undefined ? " (Curio " + Math.round(sys.process_cpu_fraction * 100) + " % of one core)" : "") +
      " · temperature " + (sys.temperature_c ? sys.temperature_c.toFixed(1) + " °C" : "no sensor") +
      " · event-loop lag " + (sys.loop_lag_ms !== undefined ? sys.loop_lag_ms + " ms" : "—") +
      " · " + (h.web ? h.web.clients : "?") + " page(s) connected";
  }

  // ----- behaviour tree -------------------------------------------------------------------------------
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
  $("treeCard").addEventListener("toggle", renderTree);
  $("healthCard").addEventListener("toggle", renderHealth);

  Object.assign(C, { EVENT_TEXT, renderStatus, renderHelp, renderProgress, renderChips, renderPaths, renderWaypoints,
    renderHealth, renderTree, addEvent, editPath, addWaypoint, moveWaypoint, setPose, renderEstop });
})();
