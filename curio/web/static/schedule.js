// Curio operator dashboard — the schedule: tours at set local times on set weekdays, in the
// building's time zone (shown with the rover's own time: the rover's clock decides), closed days,
// and the next starts (with the ones the rover is still waiting to start, and why). An overlap
// is refused by the rover with the day, both times and the earliest time that fits.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const DAYS = [["mon", "Mon"], ["tue", "Tue"], ["wed", "Wed"], ["thu", "Thu"], ["fri", "Fri"], ["sat", "Sat"], ["sun", "Sun"]];
  const card = $("scheduleCard");
  const body = document.createElement("div");
  body.innerHTML = `
    <div id="schedClock" class="small schedClock"></div>
    <h4>Next tours</h4>
    <ol id="upcoming" class="upcoming"></ol>
    <h4>Schedules</h4>
    <table id="schedTable" class="schedTable"><tbody></tbody></table>
    <form id="schedForm" class="schedForm" autocomplete="off">
      <div class="row"><label for="schedTour">Tour</label><select id="schedTour"></select></div>
      <div class="days" role="group" aria-label="weekdays"></div>
      <div class="row"><button type="button" id="schedWeekdays">Mon–Fri</button><button type="button" id="schedDaily">Every day</button></div>
      <div class="row"><label for="schedTimes">Times</label><input id="schedTimes" placeholder="10:00, 14:00, 16:00" aria-describedby="schedMsg"></div>
      <div class="row"><input id="schedNote" placeholder="note (optional)" maxlength="200" aria-label="note"><button id="schedAdd" type="submit" class="primary">Add</button></div>
      <div id="schedMsg" class="msg" aria-live="polite"></div>
    </form>
    <h4>Closed days</h4>
    <ul id="closedList" class="closedList"></ul>
    <div class="row"><input id="closedDate" type="date" aria-label="closed day"><input id="closedNote" placeholder="why (e.g. holiday)" maxlength="200" aria-label="why closed"><button id="closedAdd" type="button">Close</button></div>
    <div id="closedMsg" class="msg" aria-live="polite"></div>`;
  card.appendChild(body);
  const dayBox = body.querySelector(".days");
  for (const [key, label] of DAYS) {
    const l = document.createElement("label");
    l.className = "day";
    const cb = document.createElement("input");
    cb.type = "checkbox"; cb.value = key;
    l.append(cb, document.createTextNode(" " + label));
    dayBox.appendChild(l);
  }
  const checked = () => [...dayBox.querySelectorAll("input:checked")].map((c) => c.value);
  const setDays = (keys) => { for (const c of dayBox.querySelectorAll("input")) c.checked = keys.includes(c.value); };
  const D = { schedules: [], closed: [], upcoming: [], waiting: [], tz: "", nowLocal: "", nowAt: 0, nowWall: 0 };

  // "2025-06-02T10:30:00+01:00" → "Mon 2 Jun 10:30" (the building's local time, as the rover says it)
  function localText(iso, withDay) {
    const m = /^(\d{4})-(\d\d)-(\d\d)T(\d\d):(\d\d)/.exec(iso || "");
    if (!m) return iso || "";
    const d = new Date(Date.UTC(+m[1], +m[2] - 1, +m[3]));
    const day = d.toLocaleDateString("en-GB", { weekday: "short", day: "numeric", month: "short", timeZone: "UTC" });
    return (withDay === false ? "" : day + " ") + m[4] + ":" + m[5];
  }

  async function load() {
    try {
      const [list, next] = await Promise.all([C.api("GET", "/api/schedules"), C.api("GET", "/api/schedule/upcoming?count=8&days=14")]);
      Object.assign(D, { schedules: list.schedules, closed: list.closed, tz: list.timezone, upcoming: next.upcoming,
        waiting: next.waiting, nowLocal: next.now_local, nowWall: next.now_wall_s, nowAt: Date.now() });
      render();
    } catch (e) {
      C.showMsg($("schedMsg"), e.status === 503 ? "Schedules are not available on this rover." : "Could not read the schedule: " + e.message, "error");
    }
  }

  function render() {
    $("schedClock").textContent = "Building time: " + localText(D.nowLocal) + " (" + D.tz + ", the rover's clock)";
    const edit = C.may("tours");
    // tours to choose from
    const sel = $("schedTour");
    const keep = sel.value;
    sel.textContent = "";
    for (const t of (C.tours && C.tours.list) || []) {
      const o = document.createElement("option");
      o.value = String(t.id); o.textContent = t.name;
      sel.appendChild(o);
    }
    if (keep) sel.value = keep;
    for (const el of body.querySelectorAll("#schedForm input, #schedForm button, #schedForm select, #closedAdd, #closedDate, #closedNote")) el.disabled = !edit;
    // next starts, the waiting ones first
    const ol = $("upcoming");
    ol.textContent = "";
    for (const w of D.waiting) {
      const li = document.createElement("li");
      li.className = "waiting";
      li.textContent = localText(w.local, false) + " " + w.tour + " — " + (w.starting ? "starting…" : "waiting: " + w.reason + " (until " + localText(w.until_local, false) + ")");
      ol.appendChild(li);
    }
    for (const u of D.upcoming) {
      const li = document.createElement("li");
      li.textContent = localText(u.local) + " · " + (u.tour || "tour " + u.tour_id);
      ol.appendChild(li);
    }
    if (!ol.children.length) {
      const li = document.createElement("li");
      li.className = "small empty";
      li.textContent = "No scheduled tours in the next 14 days.";
      ol.appendChild(li);
    }
    $("scheduleSummary").textContent = D.upcoming.length ? "· next " + localText(D.upcoming[0].local) : "";
    // the schedules
    const tb = $("schedTable").tBodies[0];
    tb.textContent = "";
    for (const s of D.schedules) {
      const tr = tb.insertRow();
      tr.dataset.id = String(s.id);
      tr.className = s.enabled ? "" : "off";
      tr.insertCell().textContent = s.tour || "tour " + s.tour_id;
      tr.insertCell().textContent = daysText(s.days);
      tr.insertCell().textContent = s.times.join(", ");
      const on = tr.insertCell();
      const cb = document.createElement("input");
      cb.type = "checkbox"; cb.checked = s.enabled; cb.disabled = !edit; cb.title = "on or off";
      cb.addEventListener("change", () => change("PATCH", "/api/schedules/" + s.id, { enabled: cb.checked }, cb.checked ? "Schedule on." : "Schedule off."));
      on.appendChild(cb);
      const del = tr.insertCell();
      const b = document.createElement("button");
      b.type = "button"; b.textContent = "×"; b.title = "delete this schedule"; b.disabled = !edit;
      b.addEventListener("click", async () => {
        if (await C.confirmBox("Delete the schedule of “" + (s.tour || s.tour_id) + "” at " + s.times.join(", ") + "?", "Delete", "Keep it")) {
          change("DELETE", "/api/schedules/" + s.id, undefined, "Schedule deleted.");
        }
      });
      del.appendChild(b);
      if (s.note) tr.title = s.note;
    }
    // closed days
    const ul = $("closedList");
    ul.textContent = "";
    for (const c of D.closed) {
      const li = document.createElement("li");
      li.textContent = c.date + (c.note ? " — " + c.note : "") + " ";
      const b = document.createElement("button");
      b.type = "button"; b.textContent = "Reopen"; b.disabled = !edit;
      b.addEventListener("click", () => change("PUT", "/api/closed-days", { dates: [c.date], closed: false }, "Reopened " + c.date + ".", $("closedMsg")));
      li.appendChild(b);
      ul.appendChild(li);
    }
  }

  function daysText(days) {
    const k = days.join(",");
    if (k === "mon,tue,wed,thu,fri,sat,sun") return "every day";
    if (k === "mon,tue,wed,thu,fri") return "Mon–Fri";
    if (k === "sat,sun") return "weekends";
    return days.map((d) => d[0].toUpperCase() + d.slice(1)).join(" ");
  }

  async function change(method, path, payload, okText, el) {
    const out = el || $("schedMsg");
    if (!C.may("tours")) { C.showMsg(out, S.connected ? "Editing the schedule needs an operator token." : "Offline: nothing was sent.", "error", 15); return false; }
    try {
      await C.api(method, path, payload);
      C.showMsg(out, okText, "ok", 10);
      await load();
      return true;
    } catch (e) {
      C.showMsg(out, e.message, "error", 30);
      load();
      return false;
    }
  }

  $("schedForm").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const el = $("schedMsg");
    const days = checked();
    const times = $("schedTimes").value.split(/[,\s]+/).filter(Boolean);
    if (!$("schedTour").value) { C.showMsg(el, "Make a tour first (Tours, above).", "error", 15); return; }
    if (!days.length) { C.showMsg(el, "Tick at least one day.", "error", 15); return; }
    if (!times.length) { C.showMsg(el, "Type one or more times, e.g. 10:00, 14:00.", "error", 15); return; }
    const ok = await change("POST", "/api/schedules", { tour_id: Number($("schedTour").value), days, times,
      note: $("schedNote").value.trim() }, "Scheduled at " + times.join(", ") + ".");
    if (ok) { $("schedTimes").value = ""; $("schedNote").value = ""; }
  });
  $("schedWeekdays").addEventListener("click", () => setDays(["mon", "tue", "wed", "thu", "fri"]));
  $("schedDaily").addEventListener("click", () => setDays(DAYS.map((d) => d[0])));
  $("closedAdd").addEventListener("click", () => {
    const date = $("closedDate").value;
    if (!date) { C.showMsg($("closedMsg"), "Choose a date first.", "error", 10); return; }
    change("PUT", "/api/closed-days", { dates: [date], note: $("closedNote").value.trim(), closed: true },
      "No scheduled tours on " + date + ".", $("closedMsg")).then((ok) => { if (ok) $("closedNote").value = ""; });
  });

  // The rover's time ticks on between reads; the list is read again when it changes.
  let reloadTimer = null;
  const reloadSoon = () => { clearTimeout(reloadTimer); reloadTimer = setTimeout(load, 200); };
  C.on("state", () => load());
  C.on("tours", () => render());  // the tours to choose from
  C.on("event", (m) => {
    const k = m.event.kind;
    if (k === "schedules.changed" || k === "tours.changed" || k.startsWith("tour.")) reloadSoon();
  });
  setInterval(() => { if (card.open && S.connected) load(); }, 30000);
  card.addEventListener("toggle", () => { if (card.open) load(); });
  Object.assign(C, { loadSchedule: load });
})();
