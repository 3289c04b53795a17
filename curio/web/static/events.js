// Curio — the event log page: every record the rover kept (operator commands, tours, schedules,
// help requests and how long they waited, faults, e-stops, distance driven), filtered by time
// (the building's), kind, who and text, newest first, 100 a page; CSV of the same filters for
// operators.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const PAGE = 100;
  let offset = 0, total = 0, tz = "";

  const who = (src) => (src ? C.nameOf(src) : "");
  const num = (v, digits) => (typeof v === "number" ? v.toFixed(digits === undefined ? 1 : digits) : v);
  const ACTIONS = { go_home: "sent the rover home", pause: "paused the rover", resume: "resumed the rover",
    cancel: "stopped the current trip", help_done: "said the way is clear", estop: "pressed the e-stop",
    release_estop: "released the e-stop", start_tour: "started a tour", stop_tour: "stopped the tour",
    select_path: "chose a path", goto: "sent the rover to a point", toggle_pause: "pressed Pause/Resume" };
  // A record as a sentence, and how it reads: ok, bad, warn, who.
  function sentence(r) {
    const d = r.detail || {};
    const k = r.kind;
    if (k.startsWith("operator.")) {
      if (d.what) return ["who", (d.who || who(r.source)) + " " + d.what];
      const action = k.slice(9);
      return ["who", (who(r.source) || "someone") + " " + (ACTIONS[action] || action.replace(/_/g, " ")) +
        (d.tour_id ? " (tour " + d.tour_id + ")" : "") + (d.path_id !== undefined ? " (path " + d.path_id + ")" : "")];
    }
    switch (k) {
      case "tour.started": return ["ok", "Tour “" + (d.tour || "") + "” started" + (d.source ? " by " + who(d.source) : "")];
      case "tour.finished": return ["ok", "Tour “" + (d.tour || "") + "” finished: " + d.stops_reached + " of " + d.stops + " stops" + (d.duration_s ? " in " + C.fmtDuration(d.duration_s) : "")];
      case "tour.stopped": return ["warn", "Tour “" + (d.tour || "") + "” stopped" + (d.reason ? ": " + d.reason : "")];
      case "tour.stop": return ["", "Stop " + (d.name ? "“" + d.name + "”" : "") + " reached"];
      case "tour.scheduled_start": return ["ok", "Scheduled tour “" + (d.tour || "") + "” started" + (d.late_s > 1 ? " " + Math.round(d.late_s) + " s late" : "")];
      case "tour.delayed": return ["warn", d.message || "A scheduled tour waits: " + d.reason];
      case "tour.skipped": return ["bad", d.message || "A scheduled tour was skipped: " + d.reason];
      case "help.requested": return ["bad", "Help requested: " + (d.message || "the way is blocked")];
      case "help.resolved": return ["ok", "Help came" + (d.waited_s !== undefined ? " after " + C.fmtDuration(d.waited_s) : "") + (d.reason ? " (" + d.reason + ")" : "")];
      case "estop.engaged": return ["bad", "E-stop engaged by " + (who(r.source) || "?") + (d.reason ? ": " + d.reason : "")];
      case "estop.released": return ["ok", "E-stop released by " + (who(r.source) || "?")];
      case "fault": return ["bad", "Fault in " + d.name + " (" + d.state + ")" + (d.message ? ": " + d.message : "")];
      case "fault.cleared": return ["ok", d.name + " is OK again"];
      case "collision": return ["bad", "Collision" + (d.message ? ": " + d.message : "")];
      case "motion": return ["", "Drove " + num(d.distance_m, 1) + " m, moving " + C.fmtDuration(d.moving_s)];
      case "tours.changed": return ["who", (d.actor || "someone") + " changed tour " + d.tour_id + " (" + String(d.change).replace(/_/g, " ") + ")"];
      case "schedules.changed": return ["who", (d.actor || "someone") + " changed the schedule (" + d.change + ")"];
      case "system.unclean_restart": case "tour.interrupted": case "data.reset":
        return ["bad", d.message || k.replace(/[._]/g, " ")];
      case "data.restored": case "loop.stalled":
        return ["warn", d.message || k.replace(/[._]/g, " ")];
      default: {
        const parts = Object.entries(d).slice(0, 4).map(([key, v]) => key.replace(/_/g, " ") + " " + (typeof v === "object" ? JSON.stringify(v) : v));
        return ["", (d.message ? d.message : k.replace(/[._]/g, " ") + (parts.length ? ": " + parts.join(", ") : ""))];
      }
    }
  }

  function params() {
    const p = new URLSearchParams();
    for (const id of ["since", "until", "kind", "source", "text"]) {
      const v = $(id).value.trim();
      if (v) p.set(id, v);
    }
    return p;
  }

  async function load() {
    const p = params();
    p.set("limit", String(PAGE)); p.set("offset", String(offset));
    C.showMsg($("logMsg"), "");
    try {
      const page = await C.api("GET", "/api/events?" + p.toString());
      total = page.total; tz = page.timezone;
      render(page.records);
    } catch (e) { C.showMsg($("logMsg"), e.message, "error"); }
  }

  function render(records) {
    const tb = $("log").tBodies[0];
    tb.textContent = "";
    for (const r of records) {
      const [cls, text] = sentence(r);
      const tr = tb.insertRow();
      tr.className = cls;
      tr.dataset.kind = r.kind;
      const t = tr.insertCell(); t.className = "time"; t.textContent = C.localText(r.local); t.title = r.local;
      const w = tr.insertCell(); w.className = "what"; w.textContent = text;
      const k = tr.insertCell(); k.className = "kind optional"; k.textContent = r.kind;
      const s = tr.insertCell(); s.className = "optional"; s.textContent = r.source;
    }
    if (!records.length) {
      const td = tb.insertRow().insertCell();
      td.colSpan = 4; td.className = "small"; td.textContent = "No records match.";
    }
    $("count").textContent = total + " record" + (total === 1 ? "" : "s") + " · times in the building's zone (" + tz + ")";
    $("pageText").textContent = total ? (offset + 1) + "–" + Math.min(total, offset + PAGE) + " of " + total : "";
    $("newer").disabled = offset === 0;
    $("older").disabled = offset + PAGE >= total;
  }

  $("filters").addEventListener("submit", (ev) => { ev.preventDefault(); offset = 0; load(); });
  $("kind").addEventListener("change", () => { offset = 0; load(); });
  $("newer").addEventListener("click", () => { offset = Math.max(0, offset - PAGE); load(); });
  $("older").addEventListener("click", () => { offset += PAGE; load(); });
  $("csv").addEventListener("click", () => {
    if (!C.may("data")) { C.showMsg($("logMsg"), "Downloading the log needs an operator token (open the dashboard's link with a token).", "error", 15); return; }
    C.download("/api/events.csv?" + params().toString(), "curio-events.csv", $("logMsg"));
  });

  C.whoAmI().then(() => { $("csv").disabled = !C.may("data"); load(); });
})();
