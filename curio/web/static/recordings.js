// Curio — the recordings page: when each file starts (the building's time), how long and how
// big it is, what happened in it (the event log over the same span, and the file's own events),
// a download for operators, and how to replay it. The page does not start a replay on the rover:
// a replay re-runs the whole stack beside the live one, and the rover's processor is for
// driving safely; it shows the command for a laptop (after the download) or for the rover over
// ssh while it is parked. When this dashboard is itself a replay, the timeline is on the map page.
"use strict";

(() => {
  const C = window.curio;
  const { $ } = C;
  let rows = [];

  function render(data) {
    rows = data.recordings;
    const tb = $("recTable").tBodies[0];
    tb.textContent = "";
    for (const r of rows) {
      const tr = tb.insertRow();
      tr.dataset.name = r.name;
      const t = tr.insertCell(); t.className = "time"; t.textContent = r.start_local ? C.localText(r.start_local, { seconds: false }) : "—"; t.title = r.name;
      const len = tr.insertCell(); len.className = "num"; len.textContent = C.fmtDuration(r.duration_s);
      const size = tr.insertCell(); size.className = "num optional"; size.textContent = C.fmtBytes(r.size_bytes);
      const what = tr.insertCell();
      const main = document.createElement("div");
      main.textContent = r.log ? r.log.text : "(no event log)";
      const sub = document.createElement("div");
      sub.className = "small";
      sub.textContent = "in the file: " + r.summary + (r.messages ? " · " + r.messages.toLocaleString("en-GB") + " messages" : "");
      what.append(main, sub);
      if (!r.complete) {
        const pill = document.createElement("span");
        pill.className = "pill " + (r.writing ? "writing" : "cut");
        pill.textContent = r.writing ? "being written" : "cut short";
        pill.title = r.writing ? "the recorder is writing this file now (or it was cut short): it can still be read" :
          "this file lost its end (a crash or a power cut): it is read up to its last whole chunk";
        main.append(" ", pill);
      }
      const act = tr.insertCell();
      act.className = "actions";
      const dl = document.createElement("button");
      dl.type = "button"; dl.textContent = "Download"; dl.disabled = !C.may("data");
      dl.title = C.may("data") ? "save the MCAP file" : "downloads need an operator token";
      dl.addEventListener("click", () => C.download("/api/recordings/" + encodeURIComponent(r.name), r.name, $("recMsg")));
      const rp = document.createElement("button");
      rp.type = "button"; rp.textContent = "Replay…";
      rp.addEventListener("click", () => showReplay(r));
      act.append(dl, rp);
    }
    if (!rows.length) {
      const td = tb.insertRow().insertCell();
      td.colSpan = 5; td.className = "small"; td.textContent = "No recordings yet.";
    }
    if (data.replay_on_page) {
      $("recNote").textContent += " This dashboard is itself a replay: its timeline is on the dashboard page.";
    }
  }

  function showReplay(r) {
    const box = $("replayHelp");
    box.textContent = "";
    const h = document.createElement("b");
    h.textContent = "Replay " + r.name;
    const why = document.createElement("p");
    why.textContent = "A replay runs the recording through estimation, navigation and the behaviour tree again, and shows it on a dashboard of its own " +
      "with a timeline to pause and seek. It is not started from this page: it re-runs the whole stack, which would compete with the live rover for its " +
      "processor while it may be driving visitors around. Run it on a laptop (download the file first):";
    const code = (text) => {  // a command, and a button that copies it
      const c = document.createElement("code");
      c.textContent = text;
      const b = document.createElement("button");
      b.type = "button"; b.className = "copy"; b.textContent = "Copy";
      b.addEventListener("click", () => copy(c, b));
      const wrap = document.createElement("div");
      wrap.className = "cmd";
      wrap.append(c, b);
      return wrap;
    };
    const c1 = code(r.replay.laptop);
    const also = document.createElement("p");
    also.textContent = "or on the rover over ssh, only while it is parked (another port, so this dashboard stays up):";
    const c2 = code(r.replay.rover);
    const end = document.createElement("p");
    end.textContent = "The command prints a link to its dashboard, and at the end a report of where the new run differs from the recording.";
    box.append(h, why, c1, also, c2, end);
    box.classList.remove("hidden");
    box.scrollIntoView({ block: "nearest" });
  }

  async function copy(el, button) {
    const text = el.textContent;
    let done = false;
    try { if (navigator.clipboard) { await navigator.clipboard.writeText(text); done = true; } } catch (e) { /* not a secure page */ }
    if (!done) {  // plain http on the rover's network: select it and copy the old way
      const range = document.createRange();
      range.selectNodeContents(el);
      const sel = window.getSelection();
      sel.removeAllRanges(); sel.addRange(range);
      try { done = document.execCommand("copy"); } catch (e) { done = false; }
    }
    button.textContent = done ? "Copied" : "Selected: copy it";
    setTimeout(() => { button.textContent = "Copy"; }, 3000);
  }

  async function load() {
    try { render(await C.api("GET", "/api/recordings")); } catch (e) { C.showMsg($("recMsg"), e.message, "error"); }
  }
  C.whoAmI().then(load);
})();
