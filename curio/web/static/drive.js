// Curio operator dashboard — the e-stop, driving by hand and the HELP ME sound.
// The e-stop goes out on the WebSocket and over REST at once (same request id: published once),
// is never blocked by the page, and says so loudly when it could not be sent. Escape presses it,
// except inside a text box. Teleop is a hold-to-drive deadman (zero on release, blur, hidden tab
// and disconnect) under a lease: one driver at a time, "<name> is driving — take over?".
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;

  // ----- the e-stop ----------------------------------------------------------------------------------
  async function pressEstop() {
    stopTeleop();
    if (!C.mayOffline("estop")) {
      showEstopFail(S.who.role === "kiosk" ? "This kiosk cannot use the e-stop: use the rover's own stop button." :
        "Viewing only: the e-stop needs a token. Use the rover's own stop button.");
      return;
    }
    const requestId = C.newRequestId();
    C.expectAnswer(requestId, $("cmdMsg"), "estop");
    C.S.estopPending = true;
    let wsSent = false;
    if (S.ws && S.ws.readyState === WebSocket.OPEN) {
      try { S.ws.send(JSON.stringify({ op: "estop", id: requestId, request_id: requestId })); wsSent = true; } catch (e) { /* REST below */ }
    }
    try {
      await C.api("POST", "/api/estop", { request_id: requestId });  // the same id: published once
      $("estopFail").classList.add("hidden");
    } catch (e) {
      if (!wsSent || e.status === 403 || e.status === 401) {
        showEstopFail("E-STOP NOT SENT: " + e.message + ". Use the rover's own stop button!");
        C.pending.delete(requestId);
      }
    }
  }
  function showEstopFail(text) {
    const el = $("estopFail");
    el.textContent = text;
    el.classList.remove("hidden");
    clearTimeout(showEstopFail.timer);
    showEstopFail.timer = setTimeout(() => el.classList.add("hidden"), 15000);
  }

  async function releaseEstop() {
    const log = S.estopLog || {};
    const by = C.nameOf(log.set_by || (S.estop && S.estop.source));
    const ok = await C.confirmBox("Release the emergency stop set by " + by +
      (log.set_at ? " at " + C.clockTime(log.set_at) : "") + "? The rover may move again (a paused trip stays paused).",
      "Release the e-stop", "Keep it stopped");
    if (ok) C.command("release_estop");
  }
  $("estop").addEventListener("click", pressEstop);
  $("releaseEstop").addEventListener("click", releaseEstop);

  // ----- teleop: joystick and keyboard, deadman, lease ------------------------------------------------
  const stick = { x: 0, y: 0, held: false, pointer: null };
  const keys = new Set();
  let teleopTimer = null, takeOver = false;

  function speedFraction() { return Number($("speed").value) / 100; }
  function setSpeed(pct) {
    const v = Math.max(10, Math.min(100, Math.round(pct / 10) * 10));
    $("speed").value = String(v);
    $("speedText").textContent = v + " %";
    try { localStorage.setItem("curio.speed", String(v)); } catch (e) { /* ignore */ }
  }
  $("speed").addEventListener("input", () => setSpeed(Number($("speed").value)));
  try { const v = localStorage.getItem("curio.speed"); setSpeed(v === null ? 50 : Number(v)); } catch (e) { setSpeed(50); }

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
    return [f, t * 0.8];
  }
  function sendTeleop(lin, ang) {
    if (!S.ws || S.ws.readyState !== WebSocket.OPEN || !C.may("drive")) return;
    S.teleopSeq += 1;
    const msg = { op: "teleop", seq: S.teleopSeq, linear_mps: lin, angular_radps: ang };
    if (takeOver) msg.take_over = true;
    S.ws.send(JSON.stringify(msg));
  }
  function teleopTick() {
    const [f, t] = teleopVector();
    const [vmax, wmax] = limits();
    const k = speedFraction();
    sendTeleop(Math.round(f * vmax * k * 1000) / 1000, Math.round(t * wmax * k * 1000) / 1000);
  }
  const leaseHeldByOther = () => S.lease && S.lease.holder && S.lease.client !== S.clientId;

  async function startTeleop() {
    if (!C.may("drive")) {
      C.toast(S.connected ? (S.who.role === "kiosk" ? "This kiosk cannot drive the rover." : "Viewing only: driving needs an operator token.") : "Offline: the rover cannot be driven now.", true);
      return false;
    }
    if (leaseHeldByOther()) {
      askTakeOver(S.lease.holder);
      return false;  // hold the stick (or key) again once the stick is yours
    }
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

  function onLease(lease) {
    const was = S.lease || {};
    S.lease = lease || { holder: null, client: null, driving: false };
    if (S.lease.client === S.clientId) takeOver = false;
    if (teleopTimer !== null && S.lease.holder && S.lease.client !== S.clientId) {
      clearInterval(teleopTimer); teleopTimer = null;  // someone took over: our stick is dead
      stick.held = false; stick.x = 0; stick.y = 0; keys.clear(); placeKnob();
      C.toast(S.lease.holder + " took over driving.", true);
    }
    renderLease();
    if (was.driving !== S.lease.driving || was.holder !== S.lease.holder) C.renderStatus();
  }
  async function askTakeOver(holder) {
    const ok = await C.confirmBox(holder + " is driving — take over?", "Take over", "Let them drive");
    if (!ok) return;
    takeOver = true;
    sendTeleop(0, 0);  // takes the stick now (the rover stops until you drive)
    C.toast("You have the stick: hold it to drive.");
  }
  function onLeaseRefused(holder) {  // the server refused our teleop: another operator drives
    const driving = teleopTimer !== null;
    const tookOver = S.lease && S.lease.client === S.clientId;  // it was ours: a take-over
    if (driving) { clearInterval(teleopTimer); teleopTimer = null; }
    stick.held = false; stick.x = 0; stick.y = 0; keys.clear(); placeKnob();
    // Ask only when we drove without knowing somebody held the stick. A refusal of a message
    // that was on its way while somebody took over is stale: we were told (or are now).
    if (tookOver && driving) C.toast(holder + " took over driving.", true);
    else if (driving) askTakeOver(holder);
  }
  function renderLease() {
    const l = S.lease || {};
    const el = $("leaseText");
    if (!l.holder) el.textContent = C.may("drive") ? "Hold the stick to drive. Letting go stops." : "";
    else if (l.client === S.clientId) el.textContent = l.driving ? "You are driving." : "You have the stick.";
    else el.textContent = l.holder + (l.driving ? " is driving." : " has the stick.");
    el.className = "leaseText small" + (l.holder && l.client !== S.clientId ? " other" : "");
  }

  const joy = $("joystick"), knob = $("knob");
  function placeKnob() {
    const k = knob.offsetWidth || 48;
    const R = joy.clientWidth / 2 - k / 2;
    knob.style.left = (joy.clientWidth / 2 - k / 2 + stick.x * R) + "px";
    knob.style.top = (joy.clientHeight / 2 - k / 2 - stick.y * R) + "px";
    joy.classList.toggle("held", stick.held);
  }
  function stickFrom(ev) {
    const r = joy.getBoundingClientRect();
    const R = r.width / 2 - (knob.offsetWidth || 48) / 2;
    let dx = (ev.clientX - r.left - r.width / 2) / R, dy = -(ev.clientY - r.top - r.height / 2) / R;
    const m = Math.hypot(dx, dy);
    if (m > 1) { dx /= m; dy /= m; }
    stick.x = Math.abs(dx) < 0.08 ? 0 : dx; stick.y = Math.abs(dy) < 0.08 ? 0 : dy;
    placeKnob();
  }
  joy.addEventListener("pointerdown", async (ev) => {
    ev.preventDefault();
    const pointer = ev.pointerId;
    try { joy.setPointerCapture(pointer); } catch (e) { /* synthetic pointer */ }
    stick.held = true; stick.pointer = pointer;
    stickFrom(ev);
    if (!(await startTeleop())) { stick.held = false; stick.x = 0; stick.y = 0; placeKnob(); }
  });
  joy.addEventListener("pointermove", (ev) => { if (stick.held && ev.pointerId === stick.pointer) stickFrom(ev); });
  for (const t of ["pointerup", "pointercancel", "lostpointercapture"]) {
    joy.addEventListener(t, (ev) => { if (ev.pointerId === stick.pointer) stopTeleop(); });
  }

  // Keyboard: arrows / WASD drive (held), Q/Z change the speed by 10 % (teleop_twist_keyboard),
  // Escape is the e-stop — except inside a text box, where it only leaves the box.
  const KEYMAP = { ArrowUp: "up", KeyW: "up", ArrowDown: "down", KeyS: "down", ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right" };
  const inTextBox = (el) => !!el && (["INPUT", "SELECT", "TEXTAREA"].includes(el.tagName) || el.isContentEditable) && el.type !== "range" && el.type !== "checkbox";
  window.addEventListener("keydown", (ev) => {
    if (ev.key === "Escape" || ev.code === "Escape") {
      if (inTextBox(ev.target)) { ev.target.blur(); return; }
      C.closeModal(false);
      pressEstop();
      return;
    }
    if (inTextBox(ev.target) || ev.ctrlKey || ev.metaKey || ev.altKey) return;
    if (!$("modal").classList.contains("hidden")) return;
    if (ev.code === "KeyQ" || ev.code === "KeyZ") { setSpeed(Number($("speed").value) + (ev.code === "KeyQ" ? 10 : -10)); return; }
    if (ev.code === "KeyM") { setMuted(!sound.muted); return; }
    const k = KEYMAP[ev.code];
    if (!k) return;
    ev.preventDefault();
    if (ev.repeat) return;
    keys.add(k);
    if (teleopTimer === null) startTeleop().then((ok) => { if (!ok) keys.clear(); });
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

  // ----- the HELP ME sound (Web Audio: no file to fetch), with a mute -------------------------------
  const sound = { muted: false, beeps: 0, ticks: 0, ctx: null };
  function setMuted(m) {
    sound.muted = m;
    $("mute").textContent = "";
    const icon = document.createElement("span"); icon.textContent = "♪";
    const word = document.createElement("span"); word.className = "long"; word.textContent = m ? " off" : " on";
    $("mute").append(icon, word);
    $("mute").setAttribute("aria-pressed", String(m));
    $("mute").title = m ? "sound for HELP ME is off (click to turn it on)" : "sound when the rover asks for help (click to mute)";
    try { localStorage.setItem("curio.muted", m ? "1" : "0"); } catch (e) { /* ignore */ }
  }
  try { setMuted(localStorage.getItem("curio.muted") === "1"); } catch (e) { setMuted(false); }
  $("mute").addEventListener("click", () => { unlockAudio(); setMuted(!sound.muted); });
  function unlockAudio() {  // browsers allow sound only after a gesture on the page
    if (sound.ctx) { if (sound.ctx.state === "suspended") sound.ctx.resume(); return; }
    const Ctx = window.AudioContext || window.webkitAudioContext;
    if (Ctx) { try { sound.ctx = new Ctx(); } catch (e) { sound.ctx = null; } }
  }
  window.addEventListener("pointerdown", unlockAudio, { capture: true });
  window.addEventListener("keydown", unlockAudio, { capture: true });
  // Play [frequency Hz, start s] tones of `lengthS` each; false when the page may not sound yet
  // (no gesture on it so far) or is muted.
  function playTones(tones, type, peak, lengthS) {
    const ac = sound.ctx;
    if (!ac || ac.state !== "running" || sound.muted) return false;
    const t0 = ac.currentTime;
    for (const [f, dt] of tones) {
      const osc = ac.createOscillator(), gain = ac.createGain();
      osc.frequency.value = f; osc.type = type;
      gain.gain.setValueAtTime(0.0001, t0 + dt);
      gain.gain.exponentialRampToValueAtTime(peak, t0 + dt + 0.02);
      gain.gain.exponentialRampToValueAtTime(0.0001, t0 + dt + lengthS);
      osc.connect(gain).connect(ac.destination);
      osc.start(t0 + dt); osc.stop(t0 + dt + lengthS + 0.02);
    }
    return true;
  }
  function beep() {
    sound.beeps += 1;
    const ac = sound.ctx;
    if (!ac || ac.state !== "running") return;
    playTones([[880, 0], [660, 0.22], [880, 0.44]], "square", 0.15, 0.18);
  }
  setInterval(() => {
    sound.ticks += 1;
    if (S.help && S.help.active && S.connected && !sound.muted) beep();
  }, 2500);

  Object.assign(C, { pressEstop, stopTeleop, onLease, onLeaseRefused, renderLease, sound, setMuted, setSpeed, playTones });
})();
