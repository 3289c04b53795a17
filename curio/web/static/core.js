// Curio operator dashboard — core: the state (everything comes from the rover), the REST
// client, messages that always end with the rover's real answer, toasts and the confirm box.
// Hand-written, no libraries, no build step. The other scripts add to window.curio.
"use strict";

(() => {
  const $ = (id) => document.getElementById(id);

  // ----- state (all from the rover) -------------------------------------------------------------
  const S = {
    token: null, who: { name: "viewer", role: "viewer", permissions: [] }, requireToken: true,
    connected: false, everConnected: false, ws: null, lastMsgAt: 0, offlineSince: null,
    status: null, progress: null, help: { active: false }, estop: null, estopLog: null,
    lease: { holder: null, client: null, driving: false }, clientId: null,
    goal: null, blocker: null, bounds: null, paths: [], grids: {}, images: {},
    pose: null, truth: null, scan: null, plan: [], localPlan: [], obstacles: null, trail: [],
    tree: null, health: null, robot: null, battery: null, loc: null, cmdVel: null,
    rx: {}, editPathId: null, thanksUntil: 0, teleopSeq: 0,
  };
  // How old (wall seconds) each kind of live data may be before it is shown as stale.
  const STALE_AFTER_S = { pose: 3, scan: 3, battery: 10, loc: 10, cmdVel: 3 };

  const may = (permission) => S.connected && S.who.permissions.includes(permission);
  const mayOffline = (permission) => S.who.permissions.includes(permission);
  const now = () => Date.now();
  const ageS = (kind) => (S.rx[kind] ? (now() - S.rx[kind]) / 1000 : Infinity);
  const isStale = (kind) => !S.connected || ageS(kind) > (STALE_AFTER_S[kind] || 5);

  function fmtAge(seconds) {
    if (!isFinite(seconds)) return "never";
    if (seconds < 1.5) return "just now";
    if (seconds < 90) return Math.round(seconds) + " s ago";
    if (seconds < 5400) return Math.round(seconds / 60) + " min ago";
    return Math.round(seconds / 3600) + " h ago";
  }
  function clockTime(wallS) {
    if (wallS === null || wallS === undefined) return "—";
    const d = new Date(wallS * 1000);
    const p = (n) => String(n).padStart(2, "0");
    return p(d.getHours()) + ":" + p(d.getMinutes()) + ":" + p(d.getSeconds());
  }
  const nameOf = (source) => {  // "web:alice" → "alice"; "safety" → "the rover (safety)"
    if (!source) return "someone";
    const [channel, name] = String(source).split(":");
    if (name) return name === S.who.name ? name + " (you)" : name;
    return channel === "safety" ? "the rover (safety)" : channel;
  };

  // ----- token ------------------------------------------------------------------------------------
  function loadToken(key) {  // ?token= (then kept under `key`, and taken out of the URL), or the kept one
    const store = key || "curio.token";
    const url = new URL(location.href);
    const fromUrl = url.searchParams.get("token");
    if (fromUrl) {
      try { localStorage.setItem(store, fromUrl); } catch (e) { /* private mode */ }
      url.searchParams.delete("token");
      history.replaceState(null, "", url.pathname + url.search + url.hash);
      return fromUrl;
    }
    try { return localStorage.getItem(store); } catch (e) { return null; }
  }

  function authHeaders() {
    const h = { "Content-Type": "application/json" };
    if (S.token) h.Authorization = "Bearer " + S.token;
    return h;
  }

  async function api(method, path, body) {
    let resp;
    try {
      resp = await fetch(path, { method, headers: authHeaders(), cache: "no-store",
        body: body === undefined ? undefined : JSON.stringify(body) });
    } catch (e) {
      const err = new Error("the rover did not answer (is it on, and is this device on its network?)");
      err.status = 0;
      throw err;
    }
    let data = null;
    try { data = await resp.json(); } catch (e) { data = null; }
    if (!resp.ok) {
      const err = new Error((data && data.error) || (resp.status + " " + resp.statusText));
      err.status = resp.status;
      throw err;
    }
    return data;
  }

  // ----- messages, toasts, the confirm box -------------------------------------------------------
  const msgTimers = new WeakMap();
  function showMsg(el, text, kind, clearAfterS) {
    el.textContent = text || "";
    el.className = "msg" + (kind ? " " + kind : "");
    clearTimeout(msgTimers.get(el));
    if (text && clearAfterS) {
      msgTimers.set(el, setTimeout(() => { el.textContent = ""; el.className = "msg"; }, clearAfterS * 1000));
    }
  }
  let toastTimer = null;
  function toast(text, isError) {
    const t = $("toast");
    t.textContent = text;
    t.className = "toast" + (isError ? " error" : "");
    clearTimeout(toastTimer);
    toastTimer = setTimeout(() => t.classList.add("hidden"), isError ? 7000 : 4000);
  }

  let modalResolve = null;
  function confirmBox(text, okLabel, cancelLabel) {
    if (modalResolve) modalResolve(false);
    $("modalText").textContent = text;
    $("modalOk").textContent = okLabel || "OK";
    $("modalCancel").textContent = cancelLabel || "Cancel";
    $("modal").classList.remove("hidden");
    $("modalOk").focus();
    return new Promise((resolve) => { modalResolve = resolve; });
  }
  function closeModal(answer) {
    $("modal").classList.add("hidden");
    const r = modalResolve;
    modalResolve = null;
    if (r) r(answer);
  }
  $("modalOk").addEventListener("click", () => closeModal(true));
  $("modalCancel").addEventListener("click", () => closeModal(false));

  // ----- commands: every message ends with the rover's answer -------------------------------------
  // A command waits for the behaviour tree's bt.command_accepted / bt.command_rejected with its
  // request id (or, for the e-stop, the e-stop state); without an answer in ANSWER_S it says so.
  const ANSWER_S = 6;
  const pending = new Map();  // request_id → {el, action, timer, onAnswer}

  function newRequestId() {
    return "web-" + Date.now().toString(36) + "-" + Math.floor(Math.random() * 1e9).toString(36);
  }

  function expectAnswer(requestId, el, action, onAnswer) {
    const timer = setTimeout(() => {
      if (!pending.has(requestId)) return;
      pending.delete(requestId);
      showMsg(el, "No answer from the rover within " + ANSWER_S + " s — check the status line before trying again.", "error", 20);
    }, ANSWER_S * 1000);
    pending.set(requestId, { el, action, timer, onAnswer });
  }

  function answer(requestId, ok, message) {
    const p = pending.get(requestId);
    if (!p) return false;
    pending.delete(requestId);
    clearTimeout(p.timer);
    showMsg(p.el, message || (ok ? "Done." : "The rover refused."), ok ? "ok" : "error", ok ? 10 : 20);
    if (p.onAnswer) p.onAnswer(ok, message);
    return true;
  }

  function answerAction(action, ok, message) {  // answers without a request id (e-stop state)
    for (const [id, p] of pending) if (p.action === action) answer(id, ok, message);
  }

  async function command(action, extra, msgEl, onAnswer) {
    const el = msgEl || $("cmdMsg");
    const permission = action === "start_tour" || action === "stop_tour" ? "tour" : "command";
    if (!mayOffline(permission)) {
      showMsg(el, S.who.role === "kiosk" ? "This kiosk may only start and stop tours." :
        "Viewing only: open the link with a token (from the rover's start-up log or 'curio token create') to control it.", "error", 15);
      return false;
    }
    if (!S.connected) { showMsg(el, "Offline: nothing was sent. The page reconnects by itself.", "error", 15); return false; }
    const body = Object.assign({ action, request_id: newRequestId() }, extra || {});
    showMsg(el, "Sent — waiting for the rover…", "wait");
    expectAnswer(body.request_id, el, action, onAnswer);
    try {
      await api("POST", "/api/command", body);
      return true;
    } catch (e) {
      pending.delete(body.request_id);
      showMsg(el, e.message, "error", 20);
      return false;
    }
  }

  // Other modules listen to the rover's messages by type ("event", "tour", "state", ...).
  const listeners = {};
  const on = (type, fn) => { (listeners[type] = listeners[type] || []).push(fn); };

  window.curio = Object.assign(window.curio || {}, {
    listeners, on,
    $, S, STALE_AFTER_S, may, mayOffline, ageS, isStale, fmtAge, clockTime, nameOf,
    loadToken, api, showMsg, toast, confirmBox, closeModal, newRequestId, expectAnswer,
    answer, answerAction, command, pending,
  });
})();
