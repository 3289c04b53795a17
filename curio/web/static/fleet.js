// Curio — the fleet view (served by the fleet manager, `curio fleet run`): every rover on the shared
// map with its plan, a card per rover (state, battery and dock, tour and stop, right of way, the
// last alerts, a link to its own dashboard, pause / resume / home), the tours to dispatch and the
// jobs. Built on the page kit: pagekit.js makes the header, core.js the REST client and messages.
// The manager's token (printed when it starts; ?token= once) is kept by this browser; without it
// the page is view-only. Everything shown comes from GET /api/fleet, asked every second.
"use strict";

(() => {
  const C = window.curio;
  const { $ } = C;
  const COLOURS = ["#2563eb", "#db2777", "#059669", "#d97706", "#7c3aed", "#0891b2", "#dc2626", "#65a30d"];
  const POLL_MS = 1000;
  const state = { fleet: null, meta: null, img: null, selected: null, colours: {}, failed: 0 };

  // ----- the header: this page's own link and a STOP for every rover ------------------------------
  const nav = document.querySelector(".pageNav");
  nav.textContent = "";
  const here = document.createElement("a");
  here.href = "/"; here.textContent = "Fleet"; here.setAttribute("aria-current", "page");
  nav.append(here);
  document.querySelector(".pageTop .brand").title = "the fleet manager";
  const oldStop = $("estop");
  const stopAll = oldStop.cloneNode(true);  // drop pagekit's one-rover handler
  oldStop.replaceWith(stopAll);
  stopAll.textContent = "STOP ALL";
  stopAll.title = "Emergency stop: every rover of the fleet";
  stopAll.addEventListener("click", async () => {
    try {
      const r = await C.api("POST", "/api/fleet/estop", {});
      C.toast("E-stop sent to " + r.rovers.length + " rovers: each confirms on its card. Release it on each rover's dashboard.", true);
    } catch (e) { C.toast("The e-stop was NOT sent: " + e.message, true); }
  });

  const colourOf = (name) => {
    if (!state.colours[name]) state.colours[name] = COLOURS[Object.keys(state.colours).length % COLOURS.length];
    return state.colours[name];
  };

  // ----- the map ------------------------------------------------------------------------------------
  async function loadMap() {
    try {
      state.meta = await C.api("GET", "/api/fleet/map");
    } catch (e) { $("mapNote").textContent = "The shared map did not load: " + e.message; return; }
    const img = new Image();
    img.onload = () => { state.img = img; $("mapNote").textContent = ""; draw(); };
    img.onerror = () => { $("mapNote").textContent = "The shared map's image did not load."; };
    img.src = "/api/fleet/map.png";
  }

  function view() {  // map metres → canvas pixels
    const c = $("fleetMap"), m = state.meta;
    const s = c.width / m.width;
    return {
      s, k: s / m.resolution_m,
      px: (x, y) => [(x - m.origin[0]) / m.resolution_m * s, (m.height - (y - m.origin[1]) / m.resolution_m) * s],
    };
  }

  function draw() {
    const c = $("fleetMap"), m = state.meta;
    if (!m || !state.img) return;
    const dpr = window.devicePixelRatio || 1;
    const cssW = c.clientWidth || c.parentElement.clientWidth;
    const w = Math.round(cssW * dpr), h = Math.round(cssW * dpr * m.height / m.width);
    if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
    const g = c.getContext("2d");
    g.imageSmoothingEnabled = false;
    g.drawImage(state.img, 0, 0, w, h);
    if (!state.fleet) return;
    const v = view();
    for (const r of state.fleet.rovers) drawPlan(g, v, r, dpr);
    for (const r of state.fleet.rovers) drawRover(g, v, r, dpr);
  }

  function drawPlan(g, v, r, dpr) {
    if (!r.online || !r.plan || r.plan.length < 2) return;
    g.strokeStyle = colourOf(r.name);
    g.globalAlpha = 0.7;
    g.lineWidth = 2 * dpr;
    g.setLineDash([6 * dpr, 4 * dpr]);
    g.beginPath();
    r.plan.forEach((p, i) => { const [x, y] = v.px(p[0], p[1]); if (i) g.lineTo(x, y); else g.moveTo(x, y); });
    g.stroke();
    g.setLineDash([]);
    g.globalAlpha = 1;
  }

  function drawRover(g, v, r, dpr) {
    if (!r.pose) return;
    const [x, y] = v.px(r.pose[0], r.pose[1]);
    const rad = Math.max(0.32 * v.k, 6 * dpr);
    const colour = r.online ? colourOf(r.name) : "#9ca3af";
    g.fillStyle = colour;
    g.strokeStyle = r.name === state.selected ? "#111827" : "#fff";
    g.lineWidth = (r.name === state.selected ? 3 : 2) * dpr;
    g.beginPath(); g.arc(x, y, rad, 0, 2 * Math.PI); g.fill(); g.stroke();
    const yaw = r.pose[2];
    g.strokeStyle = "#fff"; g.lineWidth = 2 * dpr;
    g.beginPath(); g.moveTo(x, y); g.lineTo(x + Math.cos(yaw) * rad, y - Math.sin(yaw) * rad); g.stroke();
    if (r.estop || (r.alerts && r.alerts.length && r.online && recentAlert(r))) {
      g.fillStyle = "#dc2626";
      g.beginPath(); g.arc(x + rad * 0.8, y - rad * 0.8, 4 * dpr, 0, 2 * Math.PI); g.fill();
    }
    g.font = `700 ${12 * dpr}px system-ui, sans-serif`;
    g.lineWidth = 3 * dpr; g.strokeStyle = "rgba(255,255,255,.9)"; g.fillStyle = "#111827";
    const label = r.name + (r.online ? "" : " (offline)");
    g.strokeText(label, x + rad + 3 * dpr, y - rad);
    g.fillText(label, x + rad + 3 * dpr, y - rad);
  }

  const recentAlert = (r) => {
    const last = r.alerts[r.alerts.length - 1];
    return last && last.t && Date.now() / 1000 - last.t < 300;
  };

  $("fleetMap").addEventListener("click", (ev) => {
    if (!state.fleet || !state.meta) return;
    const c = $("fleetMap"), box = c.getBoundingClientRect(), dpr = c.width / box.width, v = view();
    const cx = (ev.clientX - box.left) * dpr, cy = (ev.clientY - box.top) * dpr;
    let best = null, bestD = 24 * dpr;
    for (const r of state.fleet.rovers) {
      if (!r.pose) continue;
      const [x, y] = v.px(r.pose[0], r.pose[1]);
      const d = Math.hypot(x - cx, y - cy);
      if (d < bestD) { best = r.name; bestD = d; }
    }
    if (best) select(best, true);
  });

  function select(name, scroll) {
    state.selected = state.selected === name && !scroll ? null : name;
    for (const el of document.querySelectorAll(".rover")) el.classList.toggle("selected", el.dataset.name === state.selected);
    const card = document.querySelector(`.rover[data-name="${CSS.escape(name)}"]`);
    if (scroll && card) card.scrollIntoView({ block: "nearest", behavior: "smooth" });
    draw();
  }

  // ----- the rovers' cards --------------------------------------------------------------------------
  function el(tag, cls, text) {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined) e.textContent = text;
    return e;
  }

  function batteryText(r) {
    const parts = [];
    if (r.soc !== null && r.soc !== undefined) parts.push(Math.round(r.soc * 100) + " %");
    if (r.battery_v !== null && r.battery_v !== undefined) parts.push(r.battery_v.toFixed(2) + " V");
    let text = parts.length ? parts.join(" · ") : "no reading";
    if (r.charging) text += " · charging";
    if (r.time_left_s && !r.charging) text += " · " + C.fmtDuration(r.time_left_s) + " left";
    return text;
  }

  function dockText(r) {
    if (!r.dock) return null;
    const d = r.dock;
    if (d.state === "docked") return d.charging ? "on the dock" : "on the dock, not charging";
    if (d.state === "idle") return null;
    if (d.state === "failed") return "docking failed";
    return "docking: " + d.state.replace("_", " ") + (d.attempt ? " (attempt " + d.attempt + ")" : "");
  }

  function roverCard(r) {
    const card = el("article", "rover" + (r.online ? "" : " offline") + (r.name === state.selected ? " selected" : ""));
    card.dataset.name = r.name;
    card.style.setProperty("--rover", r.online ? colourOf(r.name) : "#9ca3af");
    const top = el("div", "roverTop");
    const name = el("button", "roverName", r.name);
    name.type = "button"; name.title = "show it on the map";
    name.addEventListener("click", () => select(r.name, false));
    top.append(name);
    if (!r.online) top.append(el("span", "pill offline", r.heard_s_ago === null ? "never heard" : "offline " + C.fmtDuration(r.heard_s_ago)));
    else top.append(el("span", "pill " + (r.ready ? "ok" : "idle"), r.ready ? "ready" : "busy"));
    if (r.estop) top.append(el("span", "pill estop", "E-STOP"));
    if (r.traffic === "yield" || r.traffic === "go") top.append(el("span", "pill " + r.traffic, r.traffic === "yield" ? "giving way" : "has the passage"));
    if (r.map && state.fleet.map && r.map !== state.fleet.map) {
      if (r.map_name && r.map_name === state.fleet.map_name) {  // an older revision: pushed
        const why = (state.fleet.map_refused || {})[r.name];
        const pill = el("span", "pill map", why ? "map update waiting" : "map being sent");
        pill.title = why ? "the rover said: " + why : "the fleet's map is on its way";
        top.append(pill);
      } else top.append(el("span", "pill map", "other map"));
    }
    const zones = state.fleet.zones;
    if (r.online && zones && zones.digest && r.zones && r.zones.map === zones.map && r.zones.digest !== zones.digest) {
      top.append(el("span", "pill map", "zones being sent"));
    }
    if (r.dashboard) {
      const a = el("a", "dash", "Dashboard ↗");
      a.href = r.dashboard; a.target = "_blank"; a.rel = "noopener";
      a.title = "open " + r.name + "'s own dashboard";
      top.append(a);
    }
    card.append(top);
    card.append(el("div", "roverState", r.text || r.state || "—"));
    const facts = el("div", "roverFacts");
    const bat = el("span", "battery" + (r.power_level === "low" || r.power_level === "critical" ? " low" : "") + (r.charging ? " charging" : ""), "Battery " + batteryText(r));
    facts.append(bat);
    const dock = dockText(r);
    if (dock) facts.append(el("span", "", dock));
    if (r.tour !== null && r.tour !== undefined) {
      const stop = r.stop !== null && r.stop !== undefined ? " · stop " + (r.stop + 1) + " of " + r.stops : "";
      facts.append(el("span", "", "Tour: " + (r.tour_name || "#" + r.tour) + stop));
    } else if (!r.ready && r.why_not_ready && r.online) facts.append(el("span", "", "Not ready: " + r.why_not_ready));
    if (r.loc && r.loc !== "ok" && r.loc !== "unknown") facts.append(el("span", "warnText", "localisation " + r.loc));
    card.append(facts);
    const alerts = (r.alerts || []).slice(-3).reverse();
    if (alerts.length) {
      const ul = el("ul", "alerts");
      for (const a of alerts) {
        const li = el("li");
        li.append(el("time", "", C.clockTime(a.t)), alertText(a));
        ul.append(li);
      }
      card.append(ul);
    }
    card.append(actions(r));
    return card;
  }

  function alertText(a) {
    const d = a.detail || {};
    const why = d.message || d.reason || d.text || "";
    return a.kind + (why ? ": " + why : "");
  }

  function actions(r) {
    const row = el("div", "roverActions");
    const may = C.mayOffline("command") && r.online;
    const home = r.dock ? ["dock", "Dock"] : ["go_home", "Go home"];
    for (const [action, label] of [["pause", "Pause"], ["resume", "Resume"], home]) {
      const b = el("button", "", label);
      b.type = "button"; b.disabled = !may;
      b.title = !C.mayOffline("command") ? "needs the fleet manager's token" : (!r.online ? r.name + " is offline" : label + " " + r.name);
      b.addEventListener("click", () => send(r.name, action, label));
      row.append(b);
    }
    return row;
  }

  async function send(rover, action, label) {
    try {
      await C.api("POST", "/api/fleet/rovers/" + encodeURIComponent(rover) + "/command", { action, request_id: C.newRequestId() });
      C.showMsg($("fleetMsg"), label + " sent to " + rover + " (signed). A refusal shows in its alerts.", "ok", 10);
    } catch (e) { C.showMsg($("fleetMsg"), label + " was not sent to " + rover + ": " + e.message, "error", 20); }
  }

  // ----- tours and jobs -----------------------------------------------------------------------------
  function renderTours(f) {
    const box = $("tours");
    const key = JSON.stringify([f.tours, C.mayOffline("command")]);
    if (box.dataset.key === key) return;
    box.dataset.key = key;
    box.textContent = "";
    for (const t of f.tours) {
      const b = el("button", "", t.name);
      b.type = "button"; b.disabled = !C.mayOffline("command");
      b.title = C.mayOffline("command") ? "send this tour to the best rover" : "needs the fleet manager's token";
      b.append(el("span", "", t.stops + " stops"));
      b.addEventListener("click", () => dispatch(t));
      box.append(b);
    }
    if (!f.tours.length) box.append(el("span", "small", "No tours yet: make them on a rover's dashboard or in the manager's tours file."));
  }

  async function dispatch(t) {
    try {
      const job = await C.api("POST", "/api/fleet/tours/" + t.id + "/dispatch", { source: "fleet page" });
      C.showMsg($("tourMsg"), "'" + t.name + "' is job " + job.id + ": it goes to the best rover.", "ok", 10);
      refresh();
    } catch (e) { C.showMsg($("tourMsg"), "'" + t.name + "' was not sent: " + e.message, "error", 20); }
  }

  function renderJobs(f) {
    const tb = $("jobs").tBodies[0];
    tb.textContent = "";
    for (const j of f.jobs.slice().reverse().slice(0, 30)) {
      const tr = tb.insertRow();
      tr.className = j.state;
      tr.insertCell().textContent = j.id;
      tr.cells[0].className = "num";
      tr.insertCell().textContent = j.tour;
      const st = tr.insertCell(); st.className = "state"; st.textContent = j.state;
      tr.insertCell().textContent = j.rover || "—";
      const src = tr.insertCell(); src.className = "optional"; src.textContent = j.source;
      tr.insertCell().textContent = j.reason || "";
    }
    if (!f.jobs.length) {
      const td = tb.insertRow().insertCell();
      td.colSpan = 6; td.className = "small"; td.textContent = "No tours asked for yet.";
    }
  }

  function renderSummary(f) {
    const online = f.rovers.filter((r) => r.online).length;
    const ready = f.rovers.filter((r) => r.online && r.ready).length;
    const touring = f.rovers.filter((r) => r.online && r.tour !== null && r.tour !== undefined).length;
    const s = $("fleetSummary");
    s.textContent = "";
    const add = (n, text) => { const b = el("b", "", String(n)); s.append(b, " " + text + "  "); };
    add(online + " / " + f.rovers.length, "online");
    add(ready, "ready");
    add(touring, "on a tour");
    add(f.summary.redispatches, "re-dispatched");
  }

  function render(f) {
    state.fleet = f;
    renderSummary(f);
    const list = $("rovers");
    list.textContent = "";
    for (const r of f.rovers) list.append(roverCard(r));
    if (!f.rovers.length) list.append(el("div", "card small", "No rover has been heard yet: rovers appear here when they connect (fleet.enabled on the rover)."));
    renderTours(f);
    renderJobs(f);
    draw();
  }

  async function refresh() {
    try {
      render(await C.api("GET", "/api/fleet"));
      if (state.failed) C.showMsg($("fleetMsg"), "The fleet manager answers again.", "ok", 5);
      state.failed = 0;
    } catch (e) {
      state.failed += 1;
      C.showMsg($("fleetMsg"), "The fleet manager did not answer (" + e.message + "): what is shown is " + state.failed + " s old.", "error");
    }
  }

  window.addEventListener("resize", draw);
  C.fleet = state;
  C.whoAmI().then(() => { loadMap(); refresh(); setInterval(refresh, POLL_MS); });
})();
