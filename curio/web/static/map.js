// Curio operator dashboard — the map: pan and zoom, an adaptive scale bar, a grid and axes in
// the map frame, the cursor's coordinates, the rover with its trail, plans, goal, laser,
// obstacles, costmap, what blocks the rover, waypoints with headings; tools to send a goal,
// edit waypoints (add, drag, insert), set the pose and measure. Clicks off the map are refused
// here, before anything is sent. Map frame: metres, x right, y up, yaw counter-clockwise.
"use strict";

(() => {
  const C = window.curio;
  const { $, S } = C;
  const canvas = $("map");
  const ctx = canvas.getContext("2d");
  const view = { cx: 0, cy: 0, scale: 60, fitted: false, zoomedOnRover: false, dirty: true };
  // Other modules add map tools ({hint, hit(sx, sy), onAction(kind, x, y, yaw, index)}) and
  // layers ((ctx, kit) => draw) here before the page starts.
  C.mapTools = C.mapTools || {};
  C.mapLayers = C.mapLayers || [];
  let W = 0, H = 0, dpr = 1;
  let tool = "look";
  let measure = null;  // {ax, ay, bx, by} in map
  let flash = null;    // {x, y, yaw, until} — a pose just set, drawn for a moment

  function resize() {
    const r = canvas.getBoundingClientRect();
    dpr = window.devicePixelRatio || 1;
    W = r.width; H = r.height;
    canvas.width = Math.max(1, Math.round(W * dpr));
    canvas.height = Math.max(1, Math.round(H * dpr));
    view.dirty = true;
  }
  const toScreen = (x, y) => [W / 2 + (x - view.cx) * view.scale, H / 2 - (y - view.cy) * view.scale];
  const toWorld = (sx, sy) => [view.cx + (sx - W / 2) / view.scale, view.cy - (sy - H / 2) / view.scale];

  // ----- the map's bounds --------------------------------------------------------------------------
  function bounds() {
    const g = S.grids.map;
    if (!g) return S.bounds ? { origin: S.bounds.origin, w: S.bounds.width_m, h: S.bounds.height_m } : null;
    return { origin: g.origin, w: g.width * g.resolution_m, h: g.height * g.resolution_m };
  }
  function onMap(x, y) {
    const b = bounds();
    if (!b) return true;
    const [ox, oy, oyaw] = b.origin;
    const c = Math.cos(oyaw), s = Math.sin(oyaw);
    const u = c * (x - ox) + s * (y - oy), v = -s * (x - ox) + c * (y - oy);
    return u >= 0 && u <= b.w && v >= 0 && v <= b.h;
  }
  function describeBounds() {
    const b = bounds();
    if (!b) return "";
    const [ox, oy, oyaw] = b.origin;
    const xs = [], ys = [];
    for (const [u, v] of [[0, 0], [b.w, 0], [0, b.h], [b.w, b.h]]) {
      xs.push(ox + Math.cos(oyaw) * u - Math.sin(oyaw) * v);
      ys.push(oy + Math.sin(oyaw) * u + Math.cos(oyaw) * v);
    }
    return "x from " + Math.min(...xs).toFixed(2) + " to " + Math.max(...xs).toFixed(2) +
      " m, y from " + Math.min(...ys).toFixed(2) + " to " + Math.max(...ys).toFixed(2) + " m";
  }

  // ----- view -----------------------------------------------------------------------------------------
  function fitView() {
    const b = bounds();
    if (!b || W === 0) return;
    view.cx = b.origin[0] + b.w / 2; view.cy = b.origin[1] + b.h / 2;
    view.scale = Math.max(2, Math.min(W / b.w, H / b.h) * 0.95);
    view.fitted = true; view.dirty = true;
  }
  function closeView() {
    fitView();
    if (!S.pose || W === 0) return;
    view.zoomedOnRover = true;
    const minScale = Math.min(W, H * 1.5) / 14;  // about 14 m across: the rover is easy to see
    if (view.scale < minScale) { view.scale = minScale; view.cx = S.pose.x; view.cy = S.pose.y; }
  }
  function followRover() {
    if (!S.pose || W === 0) return;
    const [sx, sy] = toScreen(S.pose.x, S.pose.y);
    const margin = Math.min(W, H) * 0.2;
    if (sx < margin || sx > W - margin || sy < margin || sy > H - margin) {
      view.cx = S.pose.x; view.cy = S.pose.y; view.dirty = true;
    }
  }
  function zoomAt(sx, sy, factor) {
    const [wx, wy] = toWorld(sx, sy);
    view.scale = Math.max(2, Math.min(1000, view.scale * factor));
    view.cx = wx - (sx - W / 2) / view.scale;
    view.cy = wy + (sy - H / 2) / view.scale;
    view.dirty = true;
  }

  // ----- grids (map, costmaps) as images ---------------------------------------------------------------
  const gridLoad = {};
  function onGrid(g) {
    const old = S.grids[g.name];
    S.grids[g.name] = g;
    if (old && old.version === g.version && S.images[g.name]) return;
    if (g.name !== "map" && !$("showCostmap").checked) return;
    loadGridImage(g);
  }
  // One image request per grid at a time, at most one a second; the newest version wins.
  function loadGridImage(g) {
    const st = gridLoad[g.name] || (gridLoad[g.name] = { busy: false, last: 0, want: null, timer: null });
    st.want = g;
    if (st.busy || st.timer) return;
    const wait = Math.max(0, st.last + 1000 - Date.now());
    if (wait > 0) { st.timer = setTimeout(() => { st.timer = null; if (st.want) loadGridImage(st.want); }, wait); return; }
    if (S.images[g.name] && S.images[g.name].meta.version === g.version) { st.want = null; return; }
    st.busy = true; st.want = null; st.last = Date.now();
    const img = new Image();
    const done = () => { st.busy = false; if (st.want) loadGridImage(st.want); };
    img.onload = () => {
      S.images[g.name] = { img, meta: g };
      if (g.name === "map" && !view.fitted) closeView();
      view.dirty = true;
      done();
    };
    img.onerror = done;
    img.src = g.url;
  }

  // ----- drawing ---------------------------------------------------------------------------------------
  function niceStep(targetM) {  // 1, 2, 5 × 10^k metres
    const p = Math.pow(10, Math.floor(Math.log10(targetM)));
    for (const m of [1, 2, 5, 10]) if (m * p >= targetM) return m * p;
    return 10 * p;
  }
  const fmtLen = (m) => (m >= 1 ? (Math.round(m * 100) / 100) + " m" : Math.round(m * 100) + " cm");

  function drawGridImage(name, alpha) {
    const m = S.images[name];
    if (!m) return;
    const g = m.meta;
    ctx.save();
    ctx.globalAlpha = alpha;
    ctx.imageSmoothingEnabled = false;
    const [ox, oy] = toScreen(g.origin[0], g.origin[1]);
    ctx.translate(ox, oy);
    ctx.rotate(-g.origin[2]);
    const w = g.width * g.resolution_m * view.scale, h = g.height * g.resolution_m * view.scale;
    ctx.drawImage(m.img, 0, -h, w, h);
    ctx.restore();
  }

  function drawGridLines() {
    const step = niceStep(48 / view.scale);
    const [x0, y1] = toWorld(0, 0), [x1, y0] = toWorld(W, H);
    ctx.lineWidth = 1;
    ctx.strokeStyle = "rgba(30,64,175,.10)";
    ctx.beginPath();
    for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
      const [sx] = toScreen(x, 0); ctx.moveTo(Math.round(sx) + 0.5, 0); ctx.lineTo(Math.round(sx) + 0.5, H);
    }
    for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
      const [, sy] = toScreen(0, y); ctx.moveTo(0, Math.round(sy) + 0.5); ctx.lineTo(W, Math.round(sy) + 0.5);
    }
    ctx.stroke();
    // Axes of the map frame at the origin: x red, y green (RViz colours), 1 m long.
    const [ox, oy] = toScreen(0, 0);
    const len = Math.max(1, niceStep(40 / view.scale));
    const arrow = (tx, ty, color, label) => {
      const [ex, ey] = toScreen(tx, ty);
      ctx.strokeStyle = color; ctx.fillStyle = color; ctx.lineWidth = 2.5;
      ctx.beginPath(); ctx.moveTo(ox, oy); ctx.lineTo(ex, ey); ctx.stroke();
      const a = Math.atan2(ey - oy, ex - ox);
      ctx.beginPath(); ctx.moveTo(ex, ey);
      ctx.lineTo(ex - 8 * Math.cos(a - 0.45), ey - 8 * Math.sin(a - 0.45));
      ctx.lineTo(ex - 8 * Math.cos(a + 0.45), ey - 8 * Math.sin(a + 0.45));
      ctx.closePath(); ctx.fill();
      ctx.font = "bold 12px system-ui, sans-serif";
      ctx.fillText(label, ex + 4 * Math.cos(a) - 3, ey + 4 * Math.sin(a) + (label === "x" ? 14 : -4));
    };
    arrow(len, 0, "#dc2626", "x");
    arrow(0, len, "#16a34a", "y");
  }

  function drawScaleBar() {
    const m = niceStep(80 / view.scale);
    const px = m * view.scale;
    C.scaleBarM = m;
    const x = 12, y = H - 14;
    ctx.fillStyle = "rgba(255,255,255,.85)";
    ctx.fillRect(x - 6, y - 24, px + 12, 30);
    ctx.fillStyle = "#111827";
    ctx.fillRect(x, y - 4, px, 4);
    ctx.fillRect(x, y - 9, 2, 9); ctx.fillRect(x + px - 2, y - 9, 2, 9);
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillText(fmtLen(m), x, y - 10);
  }

  function polyline(xy, color, width, dash) {
    if (!xy || xy.length < 4) return;
    ctx.beginPath();
    for (let i = 0; i < xy.length; i += 2) {
      const [sx, sy] = toScreen(xy[i], xy[i + 1]);
      if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
    }
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.setLineDash(dash || []);
    ctx.stroke(); ctx.setLineDash([]);
  }

  function drawMarker(x, y, color, text, r) {
    const [sx, sy] = toScreen(x, y);
    ctx.beginPath(); ctx.arc(sx, sy, r || 9, 0, 2 * Math.PI);
    ctx.fillStyle = color; ctx.fill(); ctx.strokeStyle = "#fff"; ctx.lineWidth = 2; ctx.stroke();
    if (text) {
      ctx.fillStyle = "#fff"; ctx.font = "bold 11px system-ui, sans-serif";
      ctx.textAlign = "center"; ctx.textBaseline = "middle"; ctx.fillText(text, sx, sy + 0.5);
      ctx.textAlign = "start"; ctx.textBaseline = "alphabetic";
    }
  }

  function drawHeading(x, y, yaw, color, lengthPx) {
    const [sx, sy] = toScreen(x, y);
    const ex = sx + lengthPx * Math.cos(yaw), ey = sy - lengthPx * Math.sin(yaw);
    ctx.strokeStyle = color; ctx.fillStyle = color; ctx.lineWidth = 2.5;
    ctx.beginPath(); ctx.moveTo(sx, sy); ctx.lineTo(ex, ey); ctx.stroke();
    const a = Math.atan2(ey - sy, ex - sx);
    ctx.beginPath(); ctx.moveTo(ex + 2 * Math.cos(a), ey + 2 * Math.sin(a));
    ctx.lineTo(ex - 8 * Math.cos(a - 0.5), ey - 8 * Math.sin(a - 0.5));
    ctx.lineTo(ex - 8 * Math.cos(a + 0.5), ey - 8 * Math.sin(a + 0.5));
    ctx.closePath(); ctx.fill();
  }

  function drawRobot(p, fill, stroke, label) {
    if (label) {
      const [hx0, hy0] = toScreen(p.x, p.y);
      ctx.beginPath(); ctx.arc(hx0, hy0, 22, 0, 2 * Math.PI);
      ctx.fillStyle = fill.replace(/[\d.]+\)$/, ".15)"); ctx.fill();
    }
    const fp = (S.robot && S.robot.footprint) || [[0.33, 0.31], [0.33, -0.31], [-0.33, -0.31], [-0.33, 0.31]];
    const c = Math.cos(p.yaw), s = Math.sin(p.yaw);
    ctx.beginPath();
    fp.forEach(([x, y], i) => {
      const [sx, sy] = toScreen(p.x + c * x - s * y, p.y + s * x + c * y);
      if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
    });
    ctx.closePath();
    ctx.fillStyle = fill; ctx.fill();
    ctx.strokeStyle = stroke; ctx.lineWidth = 2; ctx.stroke();
    drawHeading(p.x, p.y, p.yaw, stroke, Math.max(24, 0.5 * view.scale));
    if (label) {
      const [ax, ay] = toScreen(p.x, p.y);
      ctx.font = "bold 13px system-ui, sans-serif";
      const w = ctx.measureText(label).width;
      const lx = ax + 20 + w > W ? Math.max(2, ax - 20 - w) : ax + 12;  // keep it on the canvas
      ctx.fillStyle = "rgba(255,255,255,.85)"; ctx.fillRect(lx, ay - 28, w + 8, 18);
      ctx.fillStyle = stroke === "#1d4ed8" ? "#111827" : "#4b5563";
      ctx.fillText(label, lx + 4, ay - 14);
    }
  }

  function drawPaths() {
    if (!$("showPaths").checked) return;
    for (const p of S.paths) {
      const sel = p.id === S.editPathId;
      const wps = p.waypoints.map((w, i) => (dragState && dragState.kind === "wp" && sel && dragState.index === i
        ? { x_m: dragState.wx, y_m: dragState.wy, yaw_rad: w.yaw_rad } : w));
      const xy = [];
      for (const w of wps) xy.push(w.x_m, w.y_m);
      polyline(xy, sel ? "#f59e0b" : "rgba(245,158,11,.55)", sel ? 3 : 2, [6, 5]);
      wps.forEach((w, i) => {
        if (w.yaw_rad !== null && w.yaw_rad !== undefined) drawHeading(w.x_m, w.y_m, w.yaw_rad, sel ? "#b45309" : "rgba(180,83,9,.7)", 22);
        drawMarker(w.x_m, w.y_m, sel ? "#d97706" : "rgba(217,119,6,.75)", p.id === 0 ? "H" : String(i + 1), sel ? 10 : 8);
      });
    }
  }

  function drawGoal() {
    const g = S.goal;
    if (!g || !g.poses || !g.poses.length) return;
    const [x, y] = g.poses[g.poses.length - 1];
    const [sx, sy] = toScreen(x, y);
    ctx.strokeStyle = "#111827"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(sx, sy); ctx.lineTo(sx, sy - 30); ctx.stroke();
    for (let r = 0; r < 2; r++) for (let c = 0; c < 3; c++) {  // a chequered flag
      ctx.fillStyle = (r + c) % 2 ? "#111827" : "#fff";
      ctx.fillRect(sx + c * 6, sy - 30 + r * 6, 6, 6);
    }
    ctx.strokeRect(sx, sy - 30, 18, 12);
    ctx.beginPath(); ctx.arc(sx, sy, 5, 0, 2 * Math.PI); ctx.fillStyle = "#16a34a"; ctx.fill();
  }

  function drawObstacles(stale) {
    if (!S.obstacles || !$("showObstacles").checked) return;
    ctx.strokeStyle = stale ? "rgba(107,114,128,.5)" : "rgba(234,88,12,.75)"; ctx.lineWidth = 2;
    for (const [[x1, y1], [x2, y2]] of S.obstacles.segments || []) {
      const [a, b] = toScreen(x1, y1), [c, d] = toScreen(x2, y2);
      ctx.beginPath(); ctx.moveTo(a, b); ctx.lineTo(c, d); ctx.stroke();
    }
    for (const [x, y, r] of S.obstacles.circles || []) {
      const [a, b] = toScreen(x, y);
      ctx.beginPath(); ctx.arc(a, b, Math.max(2, r * view.scale), 0, 2 * Math.PI); ctx.stroke();
    }
  }

  function drawScan(stale) {
    if (!S.scan || !$("showScan").checked) return;
    ctx.fillStyle = stale ? "rgba(107,114,128,.6)" : "#ef4444";
    for (let i = 0; i < S.scan.n; i++) {
      const [sx, sy] = toScreen(S.scan.pts[2 * i], S.scan.pts[2 * i + 1]);
      ctx.fillRect(sx - 1.5, sy - 1.5, 3, 3);
    }
  }

  function drawBlocker() {
    const b = S.blocker;
    if (!b || !b.points || !b.points.length) return;
    ctx.fillStyle = "rgba(220,38,38,.25)"; ctx.strokeStyle = "#b91c1c"; ctx.lineWidth = 2;
    let mx = 0, my = 0;
    for (const [x, y] of b.points) {
      const [sx, sy] = toScreen(x, y);
      ctx.beginPath(); ctx.arc(sx, sy, 7, 0, 2 * Math.PI); ctx.fill();
      mx += sx; my += sy;
    }
    for (const [x, y] of b.points) {
      const [sx, sy] = toScreen(x, y);
      ctx.fillStyle = "#b91c1c"; ctx.fillRect(sx - 2.5, sy - 2.5, 5, 5);
    }
    mx /= b.points.length; my /= b.points.length;
    const text = "in the way" + (b.distance_m !== null && b.distance_m !== undefined ? " (" + b.distance_m.toFixed(2) + " m ahead)" : "");
    ctx.font = "bold 13px system-ui, sans-serif";
    const w = ctx.measureText(text).width;
    const lx = mx + 20 + w > W ? Math.max(2, mx - 20 - w) : mx + 10;
    ctx.fillStyle = "#b91c1c"; ctx.fillRect(lx, my - 30, w + 10, 20);
    ctx.fillStyle = "#fff"; ctx.fillText(text, lx + 5, my - 15);
  }

  function drawMeasure() {
    const m = measure;
    if (!m) return;
    const [ax, ay] = toScreen(m.ax, m.ay), [bx, by] = toScreen(m.bx, m.by);
    ctx.strokeStyle = "#0f172a"; ctx.lineWidth = 2; ctx.setLineDash([8, 4]);
    ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(bx, by); ctx.stroke(); ctx.setLineDash([]);
    for (const [x, y] of [[ax, ay], [bx, by]]) { ctx.beginPath(); ctx.arc(x, y, 4, 0, 2 * Math.PI); ctx.fillStyle = "#0f172a"; ctx.fill(); }
    const d = Math.hypot(m.bx - m.ax, m.by - m.ay);
    const deg = Math.atan2(m.by - m.ay, m.bx - m.ax) * 180 / Math.PI;
    const text = d.toFixed(2) + " m · " + Math.round(deg) + "°";
    ctx.font = "bold 13px system-ui, sans-serif";
    const w = ctx.measureText(text).width;
    const tx = (ax + bx) / 2 + 8, ty = (ay + by) / 2 - 8;
    ctx.fillStyle = "#0f172a"; ctx.fillRect(tx - 4, ty - 15, w + 8, 20);
    ctx.fillStyle = "#fff"; ctx.fillText(text, tx, ty);
  }

  function draw() {
    if (!view.dirty) return;
    view.dirty = false;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#cdcdcd"; ctx.fillRect(0, 0, W, H);
    drawGridImage("map", 1);
    if ($("showCostmap").checked) { drawGridImage("costmap", 0.55); drawGridImage("local_costmap", 0.55); }
    if ($("showGrid").checked) drawGridLines();
    drawPaths();
    if (S.robot && S.robot.home) drawMarker(S.robot.home[0], S.robot.home[1], "#7c3aed", "⌂", 11);
    for (const layer of C.mapLayers) layer(ctx, drawKit);  // other modules' layers (tours, ...)
    const staleData = !S.connected;
    if ($("showTrail").checked && S.trail.length > 3) polyline(S.trail, staleData ? "rgba(107,114,128,.5)" : "rgba(29,78,216,.45)", 3);
    polyline(S.plan, staleData ? "rgba(107,114,128,.7)" : "#16a34a", 3);
    polyline(S.localPlan, staleData ? "rgba(107,114,128,.7)" : "#06b6d4", 2);
    drawGoal();
    drawObstacles(staleData);
    drawScan(C.isStale("scan"));
    drawBlocker();
    if (S.truth) drawRobot(S.truth, "rgba(0,0,0,0)", "rgba(17,24,39,.35)");
    if (S.pose) {
      const stale = C.isStale("pose");
      const home = S.robot && S.robot.home;
      const atHome = home && Math.hypot(S.pose.x - home[0], S.pose.y - home[1]) < 0.3;
      const label = stale ? "Curio — position " + C.fmtAge(C.ageS("pose")) : (atHome ? "Curio (at home)" : "Curio");
      drawRobot(S.pose, stale ? "rgba(107,114,128,.35)" : "rgba(29,78,216,.35)", stale ? "#6b7280" : "#1d4ed8", label);
    }
    if (flash && Date.now() < flash.until) {
      const [fx, fy] = toScreen(flash.x, flash.y);
      ctx.strokeStyle = "#7c3aed"; ctx.lineWidth = 3;
      ctx.beginPath(); ctx.arc(fx, fy, 26, 0, 2 * Math.PI); ctx.stroke();
      drawHeading(flash.x, flash.y, flash.yaw, "#7c3aed", 34);
      view.dirty = true;
    }
    drawMeasure();
    if (dragState && dragState.kind === "arrow") {
      const [ax, ay] = toScreen(dragState.wx0, dragState.wy0);
      ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(dragState.sx, dragState.sy);
      ctx.strokeStyle = tool === "pose" ? "#7c3aed" : "#16a34a"; ctx.lineWidth = 4; ctx.stroke();
      drawMarker(dragState.wx0, dragState.wy0, ctx.strokeStyle, "", 7);
    }
    drawScaleBar();
  }
  function frame() { draw(); requestAnimationFrame(frame); }
  // What other modules' layers may draw with (they are called after the paths, before the rover).
  const drawKit = { toScreen, drawMarker, drawHeading, polyline,
    get drag() { return dragState; }, get width() { return W; } };

  // ----- tools and pointer input ------------------------------------------------------------------------
  const HINTS = {
    look: "Drag to look around. Wheel or pinch to zoom.",
    goal: "Click where the rover should go (drag to choose the direction it faces).",
    waypoint: "Click to add a waypoint · drag one to move it · click a leg to insert one.",
    pose: "Press where the rover really is and drag in the direction it faces.",
    measure: "Drag from one point to another to measure the distance.",
  };
  function setTool(t) {
    tool = t;
    for (const b of document.querySelectorAll(".tool")) b.classList.toggle("active", b.dataset.tool === t);
    const hint = $("toolHint");
    const extra = C.mapTools[t];
    hint.textContent = extra ? extra.hint : HINTS[t];
    if (extra && extra.onSelect) extra.onSelect();
    hint.classList.remove("faded");
    clearTimeout(setTool.fade);
    setTool.fade = setTimeout(() => hint.classList.add("faded"), 6000);
    canvas.style.cursor = t === "look" ? "grab" : "crosshair";
    if (t !== "measure") { measure = null; view.dirty = true; }
    if (t === "waypoint" && !C.editPath()) {
      $("pathsCard").open = true;
      C.showMsg($("pathEditMsg"), "Choose a path to edit (or make a new one) first.", "error", 15);
    }
  }

  const pointers = new Map();
  let dragState = null, pinch = null;
  function localXY(ev) { const r = canvas.getBoundingClientRect(); return [ev.clientX - r.left, ev.clientY - r.top]; }

  function hitWaypoint(sx, sy) {
    const p = C.editPath();
    if (!p) return null;
    for (let i = p.waypoints.length - 1; i >= 0; i--) {
      const [wx, wy] = toScreen(p.waypoints[i].x_m, p.waypoints[i].y_m);
      if (Math.hypot(wx - sx, wy - sy) <= 14) return i;
    }
    return null;
  }
  function hitLeg(sx, sy) {
    const p = C.editPath();
    if (!p) return null;
    for (let i = 0; i + 1 < p.waypoints.length; i++) {
      const [ax, ay] = toScreen(p.waypoints[i].x_m, p.waypoints[i].y_m);
      const [bx, by] = toScreen(p.waypoints[i + 1].x_m, p.waypoints[i + 1].y_m);
      const len2 = (bx - ax) ** 2 + (by - ay) ** 2;
      if (len2 < 1) continue;
      const t = ((sx - ax) * (bx - ax) + (sy - ay) * (by - ay)) / len2;
      if (t < 0.1 || t > 0.9) continue;
      if (Math.hypot(ax + t * (bx - ax) - sx, ay + t * (by - ay) - sy) <= 9) return i + 1;
    }
    return null;
  }

  canvas.addEventListener("pointerdown", (ev) => {
    try { canvas.setPointerCapture(ev.pointerId); } catch (e) { /* synthetic or lost pointer */ }
    const [sx, sy] = localXY(ev);
    pointers.set(ev.pointerId, [sx, sy]);
    if (pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      pinch = { d: Math.hypot(a[0] - b[0], a[1] - b[1]) };
      dragState = null;
      return;
    }
    const [wx, wy] = toWorld(sx, sy);
    let kind = tool === "look" || ev.button === 1 || ev.button === 2 ? "pan" : "arrow";
    let index = null;
    if (kind === "arrow" && tool === "waypoint") {
      index = hitWaypoint(sx, sy);
      if (index !== null) kind = "wp";
      else if ((index = hitLeg(sx, sy)) !== null) kind = "insert";
    }
    if (kind === "arrow" && tool === "measure") kind = "measure";
    const extra = C.mapTools[tool];  // another module's tool: it says what was pressed
    const hit = kind === "arrow" && extra && extra.hit ? extra.hit(sx, sy) : null;
    if (hit) { kind = hit.kind; index = hit.index; }
    dragState = { kind, index, sx0: sx, sy0: sy, sx, sy, wx0: wx, wy0: wy, wx, wy, cx: view.cx, cy: view.cy };
    if (kind === "measure") measure = { ax: wx, ay: wy, bx: wx, by: wy };
  });
  canvas.addEventListener("pointermove", (ev) => {
    const [sx, sy] = localXY(ev);
    const [wx, wy] = toWorld(sx, sy);
    $("cursor").textContent = "x " + wx.toFixed(2) + " m, y " + wy.toFixed(2) + " m" + (onMap(wx, wy) ? "" : " (off the map)");
    if (!pointers.has(ev.pointerId)) return;
    pointers.set(ev.pointerId, [sx, sy]);
    if (pinch && pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      const d = Math.hypot(a[0] - b[0], a[1] - b[1]);
      if (pinch.d > 0) zoomAt((a[0] + b[0]) / 2, (a[1] + b[1]) / 2, d / pinch.d);
      pinch.d = d;
      return;
    }
    if (!dragState) return;
    Object.assign(dragState, { sx, sy, wx, wy });
    if (dragState.kind === "pan") {
      view.cx = dragState.cx - (sx - dragState.sx0) / view.scale;
      view.cy = dragState.cy + (sy - dragState.sy0) / view.scale;
    } else if (dragState.kind === "measure") {
      measure.bx = wx; measure.by = wy;
    }
    view.dirty = true;
  });
  const endPointer = (ev) => {
    pointers.delete(ev.pointerId);
    if (pointers.size < 2) pinch = null;
    if (!dragState) return;
    const d = dragState; dragState = null; view.dirty = true;
    if (ev.type === "pointercancel" || d.kind === "pan" || d.kind === "measure") return;
    const dragged = d.kind === "wp" || d.kind === "stop";  // a marker moved by dragging
    const moved = Math.hypot(d.sx - d.sx0, d.sy - d.sy0) > (dragged ? 4 : 12);
    const [wx, wy] = dragged ? [d.wx, d.wy] : [d.wx0, d.wy0];
    if (dragged && !moved) { if (d.kind === "stop") onMapAction("select", wx, wy, null, d.index); return; }
    if (!onMap(wx, wy)) {
      C.toast("That point is off the map (" + describeBounds() + "); nothing was sent.", true);
      return;
    }
    const yaw = moved && d.kind === "arrow" ? Math.atan2(-(d.sy - d.sy0), d.sx - d.sx0) : null;
    onMapAction(d.kind, wx, wy, yaw, d.index);
  };
  canvas.addEventListener("pointerup", endPointer);
  canvas.addEventListener("pointercancel", endPointer);
  canvas.addEventListener("pointerleave", () => { $("cursor").textContent = ""; });
  canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const [sx, sy] = localXY(ev);
    zoomAt(sx, sy, Math.exp(-ev.deltaY * 0.0015));
  }, { passive: false });

  const r3 = (v) => Math.round(v * 1000) / 1000;
  async function onMapAction(kind, x, y, yaw, index) {
    if (tool === "goal") {
      const goal = { x_m: r3(x), y_m: r3(y) };
      if (yaw !== null) goal.yaw_rad = r3(yaw);
      await C.command("goto", { goal });
    } else if (tool === "waypoint") {
      if (kind === "wp") C.moveWaypoint(index, r3(x), r3(y));
      else C.addWaypoint(r3(x), r3(y), yaw === null ? null : r3(yaw), kind === "insert" ? index : null);
    } else if (tool === "pose") {
      C.setPose(r3(x), r3(y), r3(yaw === null ? 0 : yaw));
    } else if (C.mapTools[tool]) {
      C.mapTools[tool].onAction(kind, r3(x), r3(y), yaw === null ? null : r3(yaw), index);
    }
  }

  // ----- buttons and layers ------------------------------------------------------------------------------
  for (const b of document.querySelectorAll(".tool")) b.addEventListener("click", () => setTool(b.dataset.tool));
  $("zoomIn").addEventListener("click", () => zoomAt(W / 2, H / 2, 1.3));
  $("zoomOut").addEventListener("click", () => zoomAt(W / 2, H / 2, 1 / 1.3));
  $("fit").addEventListener("click", () => { $("follow").checked = false; fitView(); });
  for (const id of ["showScan", "showPaths", "follow", "showCostmap", "showGrid", "showTrail", "showObstacles"]) {
    const el = $(id);
    try { const v = localStorage.getItem("curio." + id); if (v !== null) el.checked = v === "1"; } catch (e) { /* ignore */ }
    el.addEventListener("change", () => {
      try { localStorage.setItem("curio." + id, el.checked ? "1" : "0"); } catch (e) { /* ignore */ }
      if (id === "showCostmap" && el.checked) for (const n of ["costmap", "local_costmap"]) if (S.grids[n]) loadGridImage(S.grids[n]);
      view.dirty = true;
    });
  }
  function setLegend(open) {
    $("legend").classList.toggle("hidden", !open);
    $("legendToggle").setAttribute("aria-expanded", String(open));
    try { localStorage.setItem("curio.legend", open ? "1" : "0"); } catch (e) { /* ignore */ }
  }
  $("legendToggle").addEventListener("click", () => setLegend($("legend").classList.contains("hidden")));
  try {
    const v = localStorage.getItem("curio.legend");
    setLegend(v === null ? window.innerWidth > 860 : v === "1");
  } catch (e) { setLegend(window.innerWidth > 860); }

  function onPose(p) {
    S.pose = p;
    const last = S.trail.length;
    if (last < 2 || Math.hypot(S.trail[last - 2] - p.x, S.trail[last - 1] - p.y) > 0.05) {
      S.trail.push(p.x, p.y);
      if (S.trail.length > 4000) S.trail.splice(0, S.trail.length - 4000);
    }
    if (!view.zoomedOnRover && S.images.map) closeView();  // first pose after the map
    if ($("follow").checked && tool === "look" && !dragState) followRover();
    if (C.onPoseForCheck) C.onPoseForCheck(p);
  }

  function flashPose(x, y, yaw) { flash = { x, y, yaw, until: Date.now() + 4000 }; view.dirty = true; }

  window.addEventListener("resize", resize);
  resize();
  setTool("look");
  requestAnimationFrame(frame);
  Object.assign(C, { view, setTool, toWorld, toScreen, onGrid, loadGridImage, onMap, describeBounds,
    onPose, flashPose, resize, fitView });
  Object.defineProperty(C, "tool", { get: () => tool });
  Object.defineProperty(C, "measure", { get: () => measure });
})();
