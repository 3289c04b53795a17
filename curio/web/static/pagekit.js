// Curio — what the reading pages (event log, daily report, recordings) share. Loaded before
// core.js: it builds the page's header (the pages, who you are, STOP), the confirm box and
// the toast, which core.js then drives; its helpers use core.js (the REST client, messages)
// when called: the dashboard's token (this browser's saved token, or ?token=), who you are,
// STOP (REST, never rate-limited), times in the building's zone, and downloads that carry the
// token in a header (never in a URL).
"use strict";

(() => {
  const PAGES = [["/", "Dashboard"], ["/events", "Event log"], ["/report", "Daily report"], ["/recordings", "Recordings"], ["/maps", "Maps"]];
  const top = document.createElement("header");
  top.id = "top";
  top.className = "pageTop";
  top.innerHTML = `<a class="brand" href="/" title="the operator dashboard">Curio</a><nav class="pageNav" aria-label="pages"></nav>
    <div id="who" class="who" title="who you are on this page">View only</div>
    <button id="estop" class="estop" type="button" title="Emergency stop">STOP</button>`;
  for (const [href, label] of PAGES) {
    const a = document.createElement("a");
    a.href = href; a.textContent = label;
    if (href === location.pathname) a.setAttribute("aria-current", "page");
    top.querySelector("nav").appendChild(a);
  }
  document.body.prepend(top);
  const chrome = document.createElement("div");
  chrome.innerHTML = `<div id="modal" class="modal hidden" role="dialog" aria-modal="true" aria-labelledby="modalText">
    <div class="modalBox"><div id="modalText" class="modalText"></div>
    <div class="modalButtons"><button id="modalCancel" type="button">Cancel</button><button id="modalOk" type="button" class="primary">OK</button></div></div></div>
    <div id="toast" class="toast hidden" role="status"></div>`;
  document.body.append(...chrome.children);
  window.curio = window.curio || {};
  const C = window.curio;
  const $ = (id) => document.getElementById(id);

  async function whoAmI() {
    const S = C.S;
    S.token = C.loadToken();
    if (S.token) {
      try { S.who = (await C.api("GET", "/api/auth")).who; } catch (e) {
        if (e.status === 403) {
          C.toast("The saved token was not accepted: this page is view-only.", true);
          try { localStorage.removeItem("curio.token"); } catch (err) { /* private mode */ }
          S.token = null;
        }
      }
    }
    S.connected = true;  // these pages ask the rover each time; a failed request says so
    const who = $("who");
    who.textContent = S.who.role === "viewer" ? "View only" : S.who.name + " · " + S.who.role;
    who.className = "who " + S.who.role;
    $("estop").disabled = !C.mayOffline("estop");
    return S.who;
  }

  $("estop").addEventListener("click", async () => {
    try {
      await C.api("POST", "/api/estop", { request_id: C.newRequestId() });
      C.toast("E-stop engaged: the rover will not move. Release it on the dashboard.", true);
    } catch (e) { C.toast("The e-stop was NOT confirmed: " + e.message, true); }
  });

  // "2025-06-02T10:30:05+01:00" → "Mon 2 Jun 10:30:05" (the building's time as the rover gave it)
  function localText(iso, opts) {
    const m = /^(\d{4})-(\d\d)-(\d\d)T(\d\d):(\d\d)(?::(\d\d))?/.exec(iso || "");
    if (!m) return iso || "";
    const o = opts || {};
    const d = new Date(Date.UTC(+m[1], +m[2] - 1, +m[3]));
    const day = d.toLocaleDateString("en-GB", { weekday: "short", day: "numeric", month: "short", timeZone: "UTC" });
    return (o.date === false ? "" : day + " ") + m[4] + ":" + m[5] + (o.seconds === false || !m[6] ? "" : ":" + m[6]);
  }

  function fmtDuration(s) {
    if (s === null || s === undefined || !isFinite(s)) return "—";
    if (s < 90) return Math.round(s) + " s";
    if (s < 5400) return Math.round(s / 60) + " min";
    return (s / 3600).toFixed(1) + " h";
  }

  function fmtBytes(n) {
    if (n < 1e3) return n + " B";
    if (n < 1e6) return (n / 1e3).toFixed(0) + " kB";
    if (n < 1e9) return (n / 1e6).toFixed(1) + " MB";
    return (n / 1e9).toFixed(2) + " GB";
  }

  // A download that needs a token: fetched with the Authorization header, saved from a blob.
  async function download(path, fallbackName, msgEl) {
    const S = C.S;
    C.showMsg(msgEl, "Downloading…", "wait");
    let resp;
    try {
      resp = await fetch(path, { headers: S.token ? { Authorization: "Bearer " + S.token } : {}, cache: "no-store" });
    } catch (e) { C.showMsg(msgEl, "The rover did not answer.", "error", 15); return false; }
    if (!resp.ok) {
      let text = resp.status + " " + resp.statusText;
      try { text = (await resp.json()).error || text; } catch (e) { /* not JSON */ }
      C.showMsg(msgEl, text, "error", 20);
      return false;
    }
    const blob = await resp.blob();
    const disp = resp.headers.get("Content-Disposition") || "";
    const m = /filename="([^"]+)"/.exec(disp);
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = m ? m[1] : fallbackName;
    document.body.appendChild(a);
    a.click();
    setTimeout(() => { URL.revokeObjectURL(a.href); a.remove(); }, 60000);
    C.showMsg(msgEl, "Saved " + a.download + " (" + fmtBytes(blob.size) + ").", "ok", 15);
    return true;
  }

  Object.assign(C, { whoAmI, localText, fmtDuration, fmtBytes, download });
})();
