// Curio — the daily report page: one day's figures and tables (tours run and how they ended,
// skipped scheduled tours and why, faults), and the days before as plots (tours per day; the
// median wait for help per day), all computed by the rover from its event log.
"use strict";

(() => {
  const C = window.curio;
  const { $ } = C;
  let days = null, tz = "";

  const addDays = (iso, n) => {
    const d = new Date(iso + "T12:00:00Z");
    d.setUTCDate(d.getUTCDate() + n);
    return d.toISOString().slice(0, 10);
  };
  const short = (iso) => new Date(iso + "T12:00:00Z").toLocaleDateString("en-GB", { day: "numeric", month: "short", timeZone: "UTC" });

  function figure(label, value, bad) {
    const d = document.createElement("div");
    d.className = "figure" + (bad ? " bad" : "");
    const b = document.createElement("b"); b.textContent = value;
    const s = document.createElement("span"); s.textContent = label;
    d.append(b, s);
    return d;
  }

  function rows(table, items, cells, empty) {
    const tb = $(table).tBodies[0];
    tb.textContent = "";
    for (const it of items) {
      const tr = tb.insertRow();
      for (const [text, cls] of cells(it)) { const td = tr.insertCell(); td.textContent = text; if (cls) td.className = cls; }
    }
    if (!items.length) { const td = tb.insertRow().insertCell(); td.colSpan = 9; td.className = "small"; td.textContent = empty; }
  }

  async function loadDay(day) {
    C.showMsg($("reportMsg"), "");
    let r;
    try { r = await C.api("GET", "/api/report" + (day ? "?day=" + day : "")); } catch (e) { C.showMsg($("reportMsg"), e.message, "error"); return; }
    tz = r.timezone;
    $("day").value = r.day;
    $("title").textContent = "Daily report — " + new Date(r.day + "T12:00:00Z").toLocaleDateString("en-GB", { weekday: "long", day: "numeric", month: "long", year: "numeric", timeZone: "UTC" });
    $("tzNote").textContent = "times in " + tz;
    const f = $("figures");
    f.textContent = "";
    f.append(
      figure("tours run", String(r.tours_started)),
      figure("completed", String(r.tours_completed)),
      figure("stopped before the end", String(r.tours_stopped), r.tours_stopped > 0),
      figure("scheduled (started / skipped)", r.tours_scheduled_started + " / " + r.tours_skipped, r.tours_skipped > 0),
      figure("stops visited", String(r.stops_visited)),
      figure("distance driven", r.distance_m.toFixed(0) + " m"),
      figure("time moving", C.fmtDuration(r.moving_s)),
      figure("help requests", String(r.help_requests), r.help_requests > 0),
      figure("median wait for help", r.help_median_wait_s === null ? "—" : C.fmtDuration(r.help_median_wait_s)),
      figure("faults / collisions", r.faults + " / " + r.collisions, r.faults + r.collisions > 0),
      figure("e-stops", String(r.estops), r.estops > 0),
      figure("operator commands", String(r.operator_commands)),
    );
    rows("toursTable", r.tours, (t) => [[t.time, "time"], [t.tour], [t.source, "optional"], [t.outcome + (t.reason ? " (" + t.reason + ")" : "")],
      [t.stops_reached === null || t.stops_reached === undefined ? "—" : t.stops_reached + (t.stops ? " / " + t.stops : ""), "num"], [C.fmtDuration(t.duration_s), "num optional"]], "No tours this day.");
    rows("skippedTable", r.skipped, (s) => [[s.due, "time"], [s.tour], [s.reason]], "None skipped.");
    rows("faultsTable", r.fault_list, (x) => [[x.time, "time"], [x.kind + (x.what ? ": " + x.what : "")], [x.message]], "None.");
    await loadDays(r.day);
  }

  async function loadDays(last) {
    const n = Number($("range").value);
    try {
      days = (await C.api("GET", "/api/report/days?from=" + addDays(last, -(n - 1)) + "&to=" + last)).days;
    } catch (e) { C.showMsg($("reportMsg"), e.message, "error"); return; }
    plot();
  }

  function plot() {
    if (!days) return;
    const labels = days.map((d) => short(d.day));
    C.barChart($("toursPlot"), { labels, stacked: true, integer: true, series: [
      { name: "completed", color: "#16a34a", values: days.map((d) => d.tours_completed) },
      { name: "stopped", color: "#d97706", values: days.map((d) => d.tours_stopped) },
      { name: "skipped", color: "#dc2626", values: days.map((d) => d.tours_skipped) },
    ] });
    C.barChart($("helpPlot"), { labels, unit: "s", series: [
      { name: "median wait (no bar: nobody asked)", color: "#7c3aed", values: days.map((d) => d.help_median_wait_s) },
    ] });
  }

  $("day").addEventListener("change", () => { if ($("day").value) loadDay($("day").value); });
  $("prevDay").addEventListener("click", () => loadDay(addDays($("day").value, -1)));
  $("nextDay").addEventListener("click", () => loadDay(addDays($("day").value, 1)));
  $("today").addEventListener("click", () => loadDay(null));
  $("range").addEventListener("change", () => loadDays($("day").value));
  let resizeTimer = null;
  window.addEventListener("resize", () => { clearTimeout(resizeTimer); resizeTimer = setTimeout(plot, 100); });
  C.whoAmI().then(() => loadDay(new URLSearchParams(location.search).get("day")));
  C.reportDays = () => days;
})();
