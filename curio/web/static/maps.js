// Curio — the maps page: the library grouped by floor (switch, edit, rename, relabel, delete),
// the pose asked for after a switch, a mapping run (the map growing live, saved under a new
// name), map uploads, and the cell editor (mapedit.js). Switching, a mapping run and saving an
// edit of the active map rebuild the rover's software: the page keeps asking until the rover
// answers again (about a second), then shows the new state.
"use strict";

(() => {
  const C = window.curio;
  const { $ } = C;
  let data = null;          // the last GET /api/maps
  let busyUntilGen = null;  // waiting for the rover to come back with this App generation
  let editing = null;       // the name of the map in the editor
  let thumbs = new Map();   // "name@revision" → a GridImage
  let live = null;          // the live view while mapping
  let librarySig = "";      // the library as last drawn (redrawn only when it changes)
  const editor = new C.CellEditor($("edCanvas"), () => editorChanged());

  const floorOf = (m) => m.floor || "No floor set";
  const mayEdit = () => C.mayOffline("maps");

  function say(text, kind, secs) { C.showMsg($("mapsMsg"), text, kind, secs); }

  async function refresh() {
    try {
      data = await C.api("GET", "/api/maps");
    } catch (e) {
      $("mapsState").textContent = busyUntilGen !== null ? "The rover is changing maps… (reconnecting)" : "The rover did not answer: " + e.message;
      $("mapsState").className = "mapsState wait";
      return;
    }
    const st = data.state || {};
    if (busyUntilGen !== null && (st.generation || 0) >= busyUntilGen && !st.switching) {
      busyUntilGen = null;
      if (st.message) say(st.message, st.message.includes("NOT") ? "error" : "ok", 20);
    }
    render();
  }

  function render() {
    const st = data.state || {};
    const active = data.maps.find((m) => m.active) || {};
    const s = $("mapsState");
    s.className = "mapsState" + (st.mapping ? " mapping" : "");
    s.textContent = "";
    const b = document.createElement("b");
    b.textContent = st.mapping ? "Mapping a new map" : data.active;
    s.append(st.mapping ? "" : "Active map: ", b, st.mapping ? " (from " + data.active + ")" : " · " + floorOf(active));
    if (st.switching || busyUntilGen !== null) s.append(" · changing maps…");
    $("poseNeeded").classList.toggle("hidden", !st.pose_needed || !!st.mapping);
    $("relocalise").disabled = !C.mayOffline("initial_pose");
    const sig = JSON.stringify([data.maps, !!st.switching, !!st.mapping, busyUntilGen]);
    if (sig !== librarySig) { librarySig = sig; renderLibrary(); }
    renderMapping(st);
    $("upSend").disabled = !mayEdit();
  }

  function renderLibrary() {
    const lib = $("library");
    lib.textContent = "";
    const floors = new Map();
    for (const m of data.maps) {
      if (!floors.has(floorOf(m))) floors.set(floorOf(m), []);
      floors.get(floorOf(m)).push(m);
    }
    const order = [...floors.keys()].sort((a, b) => (a === "No floor set") - (b === "No floor set") || a.localeCompare(b, "en", { numeric: true }));
    for (const floor of order) {
      const sec = document.createElement("section");
      sec.className = "floor";
      sec.dataset.floor = floor;
      const h = document.createElement("h2");
      h.textContent = floor;
      const cards = document.createElement("div");
      cards.className = "mapCards";
      for (const m of floors.get(floor)) cards.append(card(m));
      sec.append(h, cards);
      lib.append(sec);
    }
  }

  function button(label, onClick, opts) {
    const b = document.createElement("button");
    b.type = "button"; b.textContent = label;
    if (opts && opts.cls) b.className = opts.cls;
    if (opts && opts.title) b.title = opts.title;
    b.disabled = !!(opts && opts.disabled);
    b.addEventListener("click", onClick);
    return b;
  }

  function card(m) {
    const el = document.createElement("article");
    el.className = "mapCard" + (m.active ? " active" : "");
    el.dataset.name = m.name;
    const cv = document.createElement("canvas");
    cv.className = "thumb"; cv.width = 160; cv.height = 100;
    drawThumb(m, cv);
    const info = document.createElement("div");
    info.className = "mapInfo";
    const name = document.createElement("div");
    name.className = "mapName";
    name.textContent = m.name;
    if (m.active) { const p = document.createElement("span"); p.className = "pill activePill"; p.textContent = "active"; name.append(" ", p); }
    const facts = document.createElement("div");
    facts.className = "small";
    facts.textContent = m.error ? m.error : m.width_m.toFixed(1) + " × " + m.height_m.toFixed(1) + " m · " + m.resolution_m + " m cells · revision " + m.revision +
      " · " + ({ shipped: "shipped", mapping: "mapped here", upload: "uploaded" }[m.source] || m.source || "");
    info.append(name, facts);
    const acts = document.createElement("div");
    acts.className = "mapActions";
    const busy = !!(data.state && (data.state.switching || data.state.mapping)) || busyUntilGen !== null;
    if (!m.active) {
      acts.append(button("Switch to", () => switchTo(m), { cls: "primary", disabled: !mayEdit() || busy || !data.switching_available,
        title: "make this the rover's map (the rover stops)" }));
    }
    acts.append(button("Edit cells", () => openEditor(m.name), { disabled: !!m.error }));
    acts.append(button("Rename / floor…", () => renameForm(el, m), { disabled: !mayEdit() }));
    if (!m.active) acts.append(button("Delete", () => remove(m), { cls: "dangerBtn", disabled: !mayEdit() }));
    el.append(cv, info, acts);
    return el;
  }

  async function drawThumb(m, cv) {
    if (m.error) return;
    const key = m.name + "@" + m.revision;
    let g = thumbs.get(key);
    if (!g) {
      try { g = new C.GridImage(await C.api("GET", "/api/maps/" + encodeURIComponent(m.name) + "/cells")); } catch (e) { return; }
      thumbs.set(key, g);
    }
    const ctx = cv.getContext("2d"), k = Math.min(cv.width / g.w, cv.height / g.h);
    ctx.fillStyle = "#e5e7eb"; ctx.fillRect(0, 0, cv.width, cv.height);
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(g.canvas, (cv.width - g.w * k) / 2, (cv.height - g.h * k) / 2, g.w * k, g.h * k);
  }

  async function switchTo(m) {
    const ok = await C.confirmBox("Switch the rover to " + m.name + " (" + floorOf(m) + ")? It stops now; then tell it where it is on the new map.", "Switch", "Cancel");
    if (!ok) return;
    await change("POST", "/api/maps/active", { name: m.name });
  }

  async function change(method, path, body) {  // a request that rebuilds the rover's software
    try {
      const r = await C.api(method, path, body);
      busyUntilGen = ((data.state && data.state.generation) || 0) + 1;
      say(r.message, "wait");
      render();
      return r;
    } catch (e) { say(e.message, "error", 20); return null; }
  }

  function renameForm(el, m) {
    if (el.querySelector(".renameForm")) return;
    const f = document.createElement("div");
    f.className = "renameForm formRow";
    const mk = (label, value, max) => {
      const l = document.createElement("label"); l.textContent = label;
      const i = document.createElement("input"); i.value = value; i.maxLength = max; i.autocomplete = "off";
      l.append(i); return [l, i];
    };
    const [ln, n] = mk("Name", m.name, 40), [lf, fl] = mk("Floor", m.floor || "", 30);
    n.disabled = m.active; if (m.active) ln.title = "switch to another map before renaming this one";
    const save = button("Save", async () => {
      const body = { floor: fl.value };
      if (!m.active && n.value !== m.name) body.name = n.value;
      try { await C.api("PATCH", "/api/maps/" + encodeURIComponent(m.name), body); say("Saved.", "ok", 8); await refresh(); } catch (e) { say(e.message, "error", 20); }
    }, { cls: "primary" });
    const cancel = button("Cancel", () => f.remove());
    f.append(ln, lf, save, cancel);
    el.append(f);
    fl.focus();
  }

  async function remove(m) {
    if (!await C.confirmBox("Delete the map " + m.name + " with its revisions and zones? Its paths and tours go too.", "Delete", "Keep it")) return;
    try { const r = await C.api("DELETE", "/api/maps/" + encodeURIComponent(m.name)); say(r.message, "ok", 10); if (editing === m.name) closeEditor(true); await refresh(); } catch (e) { say(e.message, "error", 20); }
  }

  // ----- mapping -------------------------------------------------------------------------------------
  function renderMapping(st) {
    $("mappingIdle").classList.toggle("hidden", !!st.mapping);
    $("mappingLive").classList.toggle("hidden", !st.mapping);
    $("mapStart").disabled = !mayEdit() || !data.switching_available || !!st.switching || busyUntilGen !== null;
    $("mapSave").disabled = $("mapDiscard").disabled = !mayEdit() || busyUntilGen !== null;
    if (st.mapping && !live) { live = new C.GridView($("liveMap")); pollLive(); }
    if (!st.mapping) live = null;
  }

  async function pollLive() {
    while (live) {
      try {
        const g = await C.api("GET", "/api/maps/live");
        if (!live) break;
        live.marker = g.pose;
        live.show(new C.GridImage(g), true);
      } catch (e) { /* the rover is rebuilding: keep asking */ }
      await new Promise((r) => setTimeout(r, 1000));
    }
  }

  $("mapStart").addEventListener("click", async () => {
    if (!await C.confirmBox("Start mapping? The rover stops, forgets where it is and maps from here while you drive it with the dashboard's joystick.", "Start mapping", "Cancel")) return;
    await change("POST", "/api/maps/mapping", { action: "start" });
  });
  $("mapSave").addEventListener("click", () => change("POST", "/api/maps/mapping", { action: "save", name: $("mapName").value.trim(), floor: $("mapFloor").value }));
  $("mapDiscard").addEventListener("click", async () => {
    if (await C.confirmBox("Throw this map away?", "Discard", "Keep mapping")) await change("POST", "/api/maps/mapping", { action: "discard" });
  });
  $("relocalise").addEventListener("click", async () => {
    try { const r = await C.api("POST", "/api/relocalise"); say(r.message + " Watch the rover turn in place.", "ok", 15); await refresh(); } catch (e) { say(e.message, "error", 20); }
  });

  // ----- upload --------------------------------------------------------------------------------------
  $("upSend").addEventListener("click", async () => {
    const y = $("upYaml").files[0], im = $("upImage").files[0];
    if (!y || !im) { C.showMsg($("upMsg"), "Choose the YAML file and its image.", "error", 10); return; }
    const form = new FormData();
    form.append("name", $("upName").value.trim()); form.append("floor", $("upFloor").value);
    form.append("yaml", y, y.name); form.append("image", im, im.name);
    C.showMsg($("upMsg"), "Sending…", "wait");
    try {
      const resp = await fetch("/api/maps/import", { method: "POST", body: form, headers: C.S.token ? { Authorization: "Bearer " + C.S.token } : {} });
      const r = await resp.json();
      if (!resp.ok) throw new Error(r.error || resp.statusText);
      C.showMsg($("upMsg"), "Added " + r.map.name + ".", "ok", 10);
      await refresh();
    } catch (e) { C.showMsg($("upMsg"), e.message, "error", 30); }
  });

  // ----- the editor ----------------------------------------------------------------------------------
  function editorChanged() {
    const n = editor.changedCount();
    $("edChanged").textContent = n ? n + " cells changed (not saved)" : "no changes";
    $("edUndo").disabled = !editor.undoStack.length;
    $("edRedo").disabled = !editor.redoStack.length;
    $("edSave").disabled = !n || !mayEdit();
  }

  async function openEditor(name) {
    if (editing && editing !== name && editor.changedCount() && !await C.confirmBox("Drop the unsaved changes to " + editing + "?", "Drop them", "Keep editing")) return;
    try {
      const meta = await C.api("GET", "/api/maps/" + encodeURIComponent(name) + "/cells");
      editing = name;
      $("editor").classList.remove("hidden");
      $("edTitle").textContent = "Edit " + name + " (revision " + meta.revision + ")";
      $("editor").scrollIntoView({ block: "start" });
      window.scrollBy(0, -($("top").getBoundingClientRect().height + 4));
      editor.load(meta);
      const m = data.maps.find((x) => x.name === name) || { revisions: [] };
      const sel = $("edRevs"); sel.textContent = "";
      for (const r of [...(m.revisions || [])].reverse()) { const o = document.createElement("option"); o.value = r; o.textContent = "revision " + r; sel.append(o); }
      $("edRestore").disabled = !m.revisions || !m.revisions.length || !mayEdit();
      document.querySelector(".edRevs").classList.toggle("hidden", !m.revisions || !m.revisions.length);
      C.showMsg($("edMsg"), m.active ? "This is the active map: saving stops the rover for a moment while it loads the new revision." : "", "warn");
    } catch (e) { say(e.message, "error", 20); }
  }

  async function closeEditor(force) {
    if (!force && editor.changedCount() && !await C.confirmBox("Close without saving " + editor.changedCount() + " changed cells?", "Close", "Keep editing")) return;
    editing = null;
    $("editor").classList.add("hidden");
  }

  for (const t of document.querySelectorAll(".edTools .tool")) {
    t.addEventListener("click", () => {
      for (const o of document.querySelectorAll(".edTools .tool")) o.classList.toggle("active", o === t);
      editor.tool = t.dataset.tool;
    });
  }
  $("edBrush").addEventListener("change", () => { editor.brush = Number($("edBrush").value); });
  $("edUndo").addEventListener("click", () => editor.undo());
  $("edRedo").addEventListener("click", () => editor.redo());
  $("edFit").addEventListener("click", () => editor.view.fit());
  $("edClose").addEventListener("click", () => closeEditor(false));
  document.addEventListener("keydown", (e) => {
    if (!editing || !(e.ctrlKey || e.metaKey) || ["INPUT", "SELECT", "TEXTAREA"].includes(document.activeElement.tagName)) return;
    const k = e.key.toLowerCase();
    if (k === "z" && !e.shiftKey) { e.preventDefault(); editor.undo(); }
    else if (k === "y" || (k === "z" && e.shiftKey)) { e.preventDefault(); editor.redo(); }
  });
  async function backAgain() {  // after a change that rebuilds the rover: wait until it answers again
    for (let i = 0; i < 75 && busyUntilGen !== null; i++) {
      await new Promise((r) => setTimeout(r, 400));
      await refresh();
    }
  }

  $("edSave").addEventListener("click", async () => {
    const name = editing, runs = editor.runs();
    C.showMsg($("edMsg"), "Saving…", "wait");
    $("edSave").disabled = true;
    try {
      const r = await C.api("POST", "/api/maps/" + encodeURIComponent(name) + "/cells", { revision: editor.meta.revision, changes: runs });
      editor.markSaved();  // Close right after "saved" must not ask about unsaved cells
      C.showMsg($("edMsg"), r.message, r.reloading ? "wait" : "ok");
      if (r.reloading) { busyUntilGen = ((data.state && data.state.generation) || 0) + 1; await backAgain(); }
      await refresh();
      await openEditor(name);
      C.showMsg($("edMsg"), r.message, "ok", 20);
    } catch (e) { C.showMsg($("edMsg"), e.message, "error", 30); editorChanged(); }
  });
  $("edRestore").addEventListener("click", async () => {
    const rev = Number($("edRevs").value);
    if (!await C.confirmBox("Make revision " + rev + " of " + editing + " current again? (The current one is kept.)", "Restore", "Cancel")) return;
    const name = editing;
    const r = await change("POST", "/api/maps/" + encodeURIComponent(name) + "/restore", { revision: rev });
    if (r) {
      if (!r.reloading) busyUntilGen = null;
      await backAgain();
      await refresh(); await openEditor(name); C.showMsg($("edMsg"), r.message, "ok", 20);
    }
  });

  C.mapsPage = { editor, refresh, state: () => data };
  C.whoAmI().then(async () => {
    await refresh();
    const loop = async () => { await refresh(); setTimeout(loop, busyUntilGen !== null ? 500 : 2000); };
    setTimeout(loop, 2000);
  });
})();
