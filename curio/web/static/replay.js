// Curio operator dashboard — the replay's timeline, shown only when the page is served by
// `curio replay --web` (GET /api/replay says so): pause and play, the speed, and a slider to
// seek. A seek forwards is computed at full speed up to the chosen time; a seek backwards
// restarts the replay from there (the page reconnects by itself). Finish ends the replay and
// the command prints its comparison report.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  let bar = null, status = null, dragging = false, restarts = 0, timer = null;

  const mmss = (s) => {
    if (s === null || s === undefined) return "?";
    const m = Math.floor(s / 60), r = Math.floor(s % 60);
    return m + ":" + String(r).padStart(2, "0");
  };

  function build() {
    bar = document.createElement("div");
    bar.id = "replayBar";
    bar.className = "replayBar";
    bar.setAttribute("role", "group");
    bar.setAttribute("aria-label", "replay timeline");
    bar.innerHTML = `
      <span class="replayTag" title="what you see was recorded: nothing here moves a rover">REPLAY</span>
      <button id="replayPlay" type="button" title="pause or play the replay">❚❚</button>
      <input id="replaySeek" type="range" min="0" max="1" step="0.1" value="0" aria-label="position in the recording">
      <span id="replayTime" class="replayTime mono"></span>
      <select id="replaySpeed" aria-label="replay speed"></select>
      <button id="replayFinish" type="button" title="end the replay; the command prints its report">Finish</button>`;
    $("sticky").appendChild(bar);
    $("replayPlay").addEventListener("click", () => send({ action: status && status.paused ? "play" : "pause" }));
    const seek = $("replaySeek");
    seek.addEventListener("input", () => { dragging = true; $("replayTime").textContent = mmss(Number(seek.value)) + " / " + mmss(status.end_s); });
    seek.addEventListener("change", async () => {
      dragging = false;
      const out = await send({ action: "seek", t_s: Number(seek.value) });
      if (out && out.seek === "restart") C.toast("Replaying again from " + mmss(Number(seek.value)) + " (a replay cannot run backwards: it restarts there).");
    });
    $("replaySpeed").addEventListener("change", () => {
      const v = $("replaySpeed").value;
      send({ action: "speed", speed: v === "max" ? "max" : Number(v) });
    });
    $("replayFinish").addEventListener("click", async () => {
      if (await C.confirmBox("End the replay? The command prints its report and this page goes offline.", "Finish", "Keep watching")) send({ action: "finish" });
    });
  }

  async function send(body) {
    try {
      const out = await C.api("POST", "/api/replay", body);
      show(out);
      return out;
    } catch (e) { C.toast(e.message, true); return null; }
  }

  function show(st) {
    status = st;
    if (!bar) build();
    const seek = $("replaySeek");
    seek.max = String(st.end_s || Math.max(1, st.position_s));
    if (!dragging) seek.value = String(st.position_s);
    $("replayTime").textContent = mmss(st.position_s) + " / " + mmss(st.end_s) + (st.at_end ? " · end" : "") +
      (st.seeking_to_s !== null && st.seeking_to_s !== undefined ? " · seeking to " + mmss(st.seeking_to_s) : "");
    $("replayPlay").textContent = st.paused ? "▶" : "❚❚";

    const sel = $("replaySpeed");
    if (!sel.options.length) {
      for (const v of st.speeds) {
        const o = document.createElement("option");
        o.value = v === null ? "max" : String(v);
        o.textContent = v === null ? "max" : v + "×";
        sel.appendChild(o);
      }
    }
    if (document.activeElement !== sel) sel.value = st.speed === null ? "max" : String(st.speed);
    const may = C.may("command");  // a token that may send commands; not while offline
    for (const id of ["replaySeek", "replaySpeed", "replayFinish"]) $(id).disabled = !may;
    $("replayPlay").disabled = !may || st.at_end;
    bar.title = "Replay of " + st.file;
    if (st.restarts !== restarts) {  // a new run: what the map drew before is another run's
      restarts = st.restarts;
      S.trail = []; S.plan = []; S.localPlan = [];
      C.view.dirty = true;
    }
  }

  async function poll() {
    try {
      const st = await C.api("GET", "/api/replay");
      C.replayPolls = (C.replayPolls || 0) + 1;
      if (!st.active) { clearInterval(timer); return; }
      show(st);
    } catch (e) { /* offline while the replay restarts: the next poll finds it again */ }
  }
  poll().then(() => { if (status) timer = setInterval(poll, 500); });
})();
