// Curio — the visitors' kiosk (a tablet in the lobby, with the kiosk token): big buttons to
// start one of the tours offered at the kiosk, then the tour in large type — the stop's name
// and its message, and when the rover moves on. Starting and stopping a tour is all it can
// do; every message is the rover's own answer. Its token is kept apart from the dashboard's
// (curio.kioskToken), so an operator's browser keeps its own.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const K = { tours: [], tour: null, tourAt: 0, status: null, estop: null, help: null, starting: null, ws: null, backoff: 250 };

  const fmtIn = (s) => (s < 10 ? "a few seconds" : s < 90 ? "about " + Math.round(s / 5) * 5 + " seconds" :
    "about " + Math.round(s / 60) + " minute" + (Math.round(s / 60) === 1 ? "" : "s"));
  const running = () => K.tour && K.tour.tour_id !== null && K.tour.tour_id !== undefined;

  function notice(text, kind) {
    const el = $("kNotice");
    el.textContent = text || "";
    el.className = "kNotice" + (kind ? " " + kind : "");
  }

  // ----- the tours offered ---------------------------------------------------------------------------
  async function loadTours() {
    try {
      const data = await C.api("GET", "/api/tours");
      K.tours = data.tours.filter((t) => t.kiosk && t.stops.length && !(t.problems || []).length);
      renderChoice();
    } catch (e) { notice("The tours could not be read: " + e.message); }
  }

  function renderChoice() {
    const box = $("kTours");
    box.textContent = "";
    const mayStart = C.may("tour");
    for (const t of K.tours) {
      const b = document.createElement("button");
      b.type = "button"; b.className = "kTour"; b.dataset.id = String(t.id);
      const name = document.createElement("b"); name.textContent = t.name;
      const info = document.createElement("span");
      info.textContent = t.stops.length + " stop" + (t.stops.length === 1 ? "" : "s") + " · about " + Math.max(1, Math.round(t.estimate.total_s / 60)) + " min";
      b.append(name, info);
      b.disabled = !mayStart || !!K.starting || blocked() !== "";
      b.addEventListener("click", () => start(t));
      box.appendChild(b);
    }
    $("kEmpty").classList.toggle("hidden", K.tours.length > 0);
  }

  function blocked() {  // why no tour can start now ("" when one can)
    if (K.estop && K.estop.engaged) return "The guide has been stopped by staff. Please ask at the desk.";
    if (K.help && K.help.active) return "The guide is waiting for staff to help it.";
    return "";
  }

  async function start(t) {
    if (K.starting) return;
    const rid = "kiosk-" + Date.now().toString(36) + "-" + Math.floor(Math.random() * 1e6).toString(36);
    K.starting = { rid, name: t.name, timer: setTimeout(() => { K.starting = null; notice("The guide did not answer. Please ask at the desk."); render(); }, 8000) };
    notice("Starting “" + t.name + "”…", "info");
    render();
    try {
      await C.api("POST", "/api/tours/" + t.id + "/start", { request_id: rid });
    } catch (e) {
      clearTimeout(K.starting.timer); K.starting = null;
      notice("Sorry, the tour could not start: " + e.message);
      render();
    }
  }

  function answered(ev) {
    const d = ev.detail || {};
    if (!K.starting || d.request_id !== K.starting.rid) return;
    clearTimeout(K.starting.timer);
    const name = K.starting.name;
    K.starting = null;
    if (ev.kind === "bt.command_accepted") notice("Tour “" + name + "” starts — please follow the guide!", "ok");
    else notice("Sorry, the tour could not start: " + (d.message || "the guide is busy") + ".");
    render();
  }

  // ----- the running tour ------------------------------------------------------------------------------
  function render() {
    const on = running();
    $("kChoose").classList.toggle("hidden", on);
    $("kRunning").classList.toggle("hidden", !on);
    if (!on) { renderChoice(); return; }
    const t = K.tour;
    $("kTourName").textContent = t.name;
    const dots = $("kDots");
    dots.textContent = "";
    for (let i = 0; i < t.stops_total; i++) {
      const dot = document.createElement("i");
      dot.className = i < t.stop_index || (i === t.stop_index && t.phase === "dwelling") ? "done" : (i === t.stop_index ? "now" : "");
      dots.appendChild(dot);
    }
    const n = t.stop_index === null ? 0 : t.stop_index + 1;
    $("kProgress").textContent = "Stop " + n + " of " + t.stops_total;
    const left = remaining();
    if (t.phase === "dwelling") {
      $("kStop").textContent = t.stop_name;
      $("kMessage").textContent = t.message || "";
      $("kNext").textContent = t.next_stop_name ? "Next stop: " + t.next_stop_name + (left !== null ? " — we move on in " + fmtIn(left) : "") :
        "This is the last stop" + (left !== null ? " — the tour ends in " + fmtIn(left) : "") + ".";
    } else {
      $("kStop").textContent = (t.phase === "moving" ? "On our way to " : "") + t.stop_name;
      $("kMessage").textContent = t.phase === "held" ? "The guide has paused for a moment." :
        t.phase === "failed" ? "The guide is waiting for staff." : "";
      $("kNext").textContent = t.phase === "moving" && left !== null ? "Next stop in " + fmtIn(left) : "";
    }
    $("kStopTour").disabled = !C.may("tour");
    notice(blocked() || (K.starting ? $("kNotice").textContent : ""), blocked() ? "" : "info");
  }

  function remaining() {  // seconds until the ETA, counted down on this tablet
    const t = K.tour;
    if (!t || t.eta_s === null || t.eta_s === undefined) return null;
    return Math.max(0, t.eta_s - (t.age_s || 0) - (Date.now() - K.tourAt) / 1000);
  }

  $("kStopTour").addEventListener("click", async () => {
    if (!(await C.confirmBox("Stop the tour? The guide stops where it is.", "Stop the tour", "Keep going"))) return;
    try { await C.api("POST", "/api/tours/stop"); notice("Stopping the tour…", "info"); } catch (e) { notice(e.message); }
  });

  // ----- the live link ----------------------------------------------------------------------------------
  function connect() {
    const protocols = ["curio.v1"];
    if (S.token) protocols.push("curio.token." + S.token);
    let ws;
    try { ws = new WebSocket((location.protocol === "https:" ? "wss:" : "ws:") + "//" + location.host + "/ws", protocols); } catch (e) { retry(); return; }
    K.ws = ws;
    ws.onopen = () => { K.backoff = 250; };
    ws.onmessage = (ev) => {
      if (typeof ev.data !== "string") return;
      if (!S.connected) { S.connected = true; conn(); }
      S.lastMsgAt = Date.now();
      onJson(JSON.parse(ev.data));
    };
    ws.onclose = () => { if (K.ws === ws) { S.connected = false; conn(); retry(); } };
  }
  function retry() { setTimeout(connect, K.backoff); K.backoff = Math.min(2000, K.backoff * 2); }
  function conn() {
    $("kConn").textContent = S.connected ? "Live" : "Offline";
    $("kConn").className = "conn " + (S.connected ? "ok" : "bad");
    if (!S.connected) notice("The guide cannot be reached right now. Please ask at the desk.");
    else if (/cannot be reached/.test($("kNotice").textContent)) notice("");
    renderChoice();
  }

  function onJson(m) {
    if (m.t === "hello") { S.who = m.who; return; }
    if (m.t === "localization" || m.t === "state" || m.t === "status") renderLost(m);
    if (m.t === "state") {
      K.status = m.status; K.estop = m.estop; K.help = m.help; setTour(m.tour);
      loadTours();
    } else if (m.t === "tour") setTour(m.tour);
    else if (m.t === "status") { K.status = m.status; if (m.help) K.help = m.help; }
    else if (m.t === "estop") K.estop = m.estop;
    else if (m.t === "event") {
      if (m.help) K.help = m.help;
      const k = m.event.kind;
      if (k === "bt.command_accepted" || k === "bt.command_rejected") answered(m.event);
      if (k === "tours.changed") loadTours();
      if (k === "tour.finished") notice("Thank you for touring with Curio!", "ok");
    } else return;
    render();
  }
  function setTour(t) { K.tour = t; K.tourAt = Date.now(); }
  // Lost (the localiser says so, or the tree is looking around): say so in plain words.
  function renderLost(m) {
    if (m.localization) K.loc = m.localization;
    if (m.status) K.status = m.status;
    const lost = (K.loc && K.loc.state === "lost") || (K.status && /^lost\b/i.test(K.status.text || ""));
    $("kLost").classList.toggle("hidden", !lost);
  }

  setInterval(() => {
    if (S.connected && Date.now() - S.lastMsgAt > 2500) { const ws = K.ws; K.ws = null; S.connected = false; conn(); if (ws) ws.close(); retry(); }
    if (K.ws && K.ws.readyState === WebSocket.OPEN) K.ws.send(JSON.stringify({ op: "ping" }));
    if (running()) render();
  }, 1000);

  async function startPage() {
    S.token = C.loadToken("curio.kioskToken");
    if (S.token) {
      try { S.who = (await C.api("GET", "/api/auth")).who; } catch (e) {
        S.token = null;
        try { localStorage.removeItem("curio.kioskToken"); } catch (err) { /* ignore */ }
      }
    }
    if (!C.mayOffline("tour")) notice("This screen shows tours only. To let visitors start them, open it with the kiosk link (curio token create lobby --role kiosk).", "info");
    connect();
  }
  startPage();
  C.kiosk = K;
})();
