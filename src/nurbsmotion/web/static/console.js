// The nurbsmotion console: status over the gateway's WebSocket, commands over its HTTP API.
// No build step, no framework: the page and this file ship in the Python package.
"use strict";

const $ = (id) => document.getElementById(id);
const AXES = ["X", "Y", "Z"];
const RENEW_MS = 200;            // continuous jog: renew the daemon's lease (0.5 s) this often
let status = null;               // the daemon's status, kept current from the pushed changes
let ws = null;
let program = null;              // the selected library program: {name, text, path: parseGcode(text), check}
let library = [];                // the daemon's program library (GET programs): name, size, check
let trail = [];                  // executed tool positions of the running job (machine XY)
let view = { scale: 1, x: 0, y: 0, center: [0, 0, 0], yaw: -Math.PI / 4, pitch: Math.PI / 3.3, fitted: false };
let renewTimer = null;

// ------------------------------------------------------------------ HTTP API
function apiKey() { return localStorage.getItem("nurbsmotion-key") || ""; }
async function api(method, path, body, contentType) {
  const headers = {};
  if (apiKey()) headers["Authorization"] = "Bearer " + apiKey();
  let data;
  if (body !== undefined) {
    headers["Content-Type"] = contentType || "application/json";
    data = contentType ? body : JSON.stringify(body);
  }
  const response = await fetch("/api/v1/" + path, { method, headers, body: data });
  let answer = {};
  try { answer = await response.json(); } catch (e) { answer = { error: response.statusText }; }
  if (response.status === 401) $("key-box").hidden = false;
  if (!response.ok) {
    const lines = [answer.error].concat(answer.errors || []).filter((v, i, a) => v && a.indexOf(v) === i);
    addLog("refused: " + method + " " + path + ": " + lines.join("; "), "bad");
    return { ok: false, status: response.status, error: answer.error, errors: answer.errors || [] };
  }
  return answer;
}

// ------------------------------------------------------------------ status
function merge(into, changes) {
  for (const [k, v] of Object.entries(changes)) {
    if (v && typeof v === "object" && !Array.isArray(v) && into[k] && typeof into[k] === "object" && !Array.isArray(into[k]))
      merge(into[k], v);
    else into[k] = v;
  }
}

function spindleText(sp) {
  // status.spindle: commanded_rpm signed (+ M3 clockwise, - M4), actual_rpm, at_speed, drive_state, fault
  if (!sp) return "none";
  if (sp.fault) return "fault: " + sp.fault;
  const rpm = Number(sp.commanded_rpm || 0);
  if (rpm === 0) return "stopped";
  const actual = sp.actual_rpm === null || sp.actual_rpm === undefined ? "" : ", actual " + Math.round(Math.abs(sp.actual_rpm));
  return (rpm > 0 ? "CW " : "CCW ") + Math.round(Math.abs(rpm)) + " rpm" + actual + (sp.at_speed ? "" : " (not at speed)");
}

function coolantText(coolant) {
  // status.coolant: {mist: bool, flood: bool} for the modes this machine has; absent: no coolant output
  if (!coolant || !Object.keys(coolant).length) return "none";
  const on = Object.entries(coolant).filter(([, v]) => v).map(([k]) => k);
  return on.length ? on.join(" + ") : "off";
}

function fmt(v) { return v === null || v === undefined ? "–" : Number(v).toFixed(3); }

function workOffset(i) {
  const c = status && status.coordinates;
  if (!c) return 0;
  return (c.active_offset_mm ? c.active_offset_mm[i] : 0) + (c.g92_applied && c.g92_mm ? c.g92_mm[i] : 0);
}

function render() {
  if (!status) return;
  const banner = $("banner");
  banner.textContent = status.state + (status.job && status.job.paused ? " · " + status.job.paused : "");
  banner.className = "state " + status.state;
  const faults = status.faults || [];
  const fault = $("fault");
  if (faults.length) {
    const f = faults[faults.length - 1];
    fault.textContent = "fault: node " + f.node + " " + (f.kind || "") + (f.code_hex ? " " + f.code_hex : "")
      + (f.message ? ": " + f.message : "") + " — clear the cause, then press Reset";
    fault.hidden = false;
  } else fault.hidden = true;
  (status.axes || []).forEach((a, i) => {
    const name = a.name;
    const machine = a.actual_mm !== null && a.actual_mm !== undefined ? a.actual_mm : a.commanded_mm;
    if ($("dro-" + name)) {
      $("dro-" + name).textContent = fmt(machine - workOffset(AXES.indexOf(name)));
      $("mach-" + name).textContent = fmt(machine);
    }
  });
  const job = status.job;
  $("feed").textContent = job && job.feed_mm_s !== undefined && job.feed_mm_s !== null ? Number(job.feed_mm_s).toFixed(1) : "0.0";
  $("spindle").textContent = spindleText(status.spindle);
  $("coolant").textContent = coolantText(status.coolant);
  const homing = status.homing && status.homing.axes ? status.homing.axes : {};
  $("homed").textContent = Object.keys(homing).length
    ? Object.entries(homing).map(([k, v]) => k + " " + v).join(", ") : "";
  if (job) {
    $("progress-bar").style.width = (job.percent || 0) + "%";
    $("progress").textContent = "job " + job.id + " " + job.name + ": " + (job.percent || 0).toFixed(1) + " %, at " + (job.line || "–");
    const [x, y, z] = [0, 1, 2].map((i) => status.axes[i] ? status.axes[i].commanded_mm : 0);
    const last = trail[trail.length - 1];
    if (!last || Math.hypot(last[0] - x, last[1] - y, last[2] - z) > 1e-3) trail.push([x, y, z]);
  } else {
    const done = status.last_job;
    $("progress-bar").style.width = done && done.outcome === "completed" ? "100%" : "0";
    $("progress").textContent = done ? "last job " + done.id + " " + done.name + ": " + done.outcome
      + (done.line_reached ? " at " + done.line_reached : "") : "";
  }
  const running = ["running", "pausing", "held", "stopping"].includes(status.state);
  $("btn-start").disabled = !program || !library.some((p) => p.name === program.name) || running || status.state === "fault";
  $("btn-hold").disabled = status.state !== "running";
  $("btn-resume").disabled = status.state !== "held";
  $("btn-stop").disabled = !running;
  const override = status.override ? status.override.requested_percent : 100;
  if (document.activeElement !== $("override")) { $("override").value = override; $("override-value").textContent = override + " %"; }
  drawPreview();
}

let renderQueued = false;
function scheduleRender() {
  if (renderQueued) return;
  renderQueued = true;
  requestAnimationFrame(() => { renderQueued = false; render(); });
}

function addLog(text, cls) {
  const li = document.createElement("li");
  li.textContent = new Date().toLocaleTimeString() + " " + text;
  if (cls) li.className = cls;
  const log = $("log");
  log.prepend(li);
  while (log.children.length > 200) log.lastChild.remove();
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  ws = new WebSocket(scheme + location.host + "/api/v1/ws");
  ws.onopen = () => { if (apiKey()) ws.send(JSON.stringify({ auth: apiKey() })); };
  ws.onmessage = (message) => {
    const m = JSON.parse(message.data);
    if (m.error && m.id === undefined) { addLog("connection: " + m.error, "bad"); $("key-box").hidden = false; return; }
    if (m.subscribed) { status = m.status; trail = []; render(); return; }
    if (m.notify === "status") { merge(status, m.changes); scheduleRender(); return; }
    if (m.notify === "event") {
      addLog(m.line, m.level === "WARNING" || m.level === "ERROR" ? "bad" : "");
      if (m.event === "job_started") trail = [];
      if (m.event === "job_ended" || m.event === "submit_rejected") loadJobs();
      if (m.event === "queue_changed") loadQueue();
      if (m.event === "program_added" || m.event === "program_removed") loadPrograms();
      return;
    }
    if (m.id !== undefined && (m.error || (m.response && !m.response.ok)))
      addLog("refused: " + (m.error || m.response.error), "bad");
    if (m.notify === "daemon_gone") { $("banner").textContent = "no daemon"; $("banner").className = "state offline"; }
  };
  ws.onclose = () => {
    $("banner").textContent = "disconnected: retrying"; $("banner").className = "state offline";
    stopContinuousJog();
    setTimeout(connect, 1000);
  };
}

function wsSend(cmd, fields) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(Object.assign({ id: Date.now(), cmd }, fields || {})));
}

// ------------------------------------------------------------------ jog
function jogStep() { return document.querySelector("input[name=step]:checked").value; }
function jogSpeed() { return Math.max(0.1, Number($("jog-speed").value) || 10); }

function startJog(spec) {
  const axis = spec[0], sign = spec[1];
  if (jogStep() === "cont") {
    wsSend("jog", { axis, direction: sign, speed: jogSpeed() });
    clearInterval(renewTimer);
    renewTimer = setInterval(() => wsSend("jog_renew"), RENEW_MS);
  } else {
    api("POST", "machine/jog", { axis, distance: Number(sign + jogStep()), speed: jogSpeed() });
  }
}

function stopContinuousJog() {
  if (renewTimer !== null) { clearInterval(renewTimer); renewTimer = null; wsSend("jog_stop"); }
}

document.querySelectorAll("[data-jog]").forEach((button) => {
  button.addEventListener("pointerdown", (e) => { e.preventDefault(); button.setPointerCapture(e.pointerId); startJog(button.dataset.jog); });
  for (const end of ["pointerup", "pointercancel", "lostpointercapture"]) button.addEventListener(end, stopContinuousJog);
});

const KEYS = { ArrowLeft: "X-", ArrowRight: "X+", ArrowUp: "Y+", ArrowDown: "Y-", PageUp: "Z+", PageDown: "Z-" };
document.addEventListener("keydown", (e) => {
  if (e.target.tagName === "INPUT" || !KEYS[e.key] || e.repeat) return;
  e.preventDefault(); startJog(KEYS[e.key]);
});
document.addEventListener("keyup", (e) => { if (KEYS[e.key]) stopContinuousJog(); });
window.addEventListener("blur", stopContinuousJog);

// ------------------------------------------------------------------ program and buttons
function showProgram(name, text, check) {
  // the preview of a program's text, drawn now (the daemon's check may follow)
  const started = performance.now();
  program = { name, text, path: parseGcode(text), check };
  // the page's own count: arcs are drawn as chords, so it is not the daemon's block count
  $("program-name").textContent = name + ": " + program.path.count + " preview segments";
  view.fitted = false; trail = [];
  render();
  drawPreview();
  window.previewDrawnMs = performance.now() - started;  // read by the page test and the web benchmark
  markSelected();
}

function clearProgram(label) {
  // no program selected: the panel says why, the preview asks for one, nothing is marked
  program = null;
  $("program-name").textContent = label;
  render();
  markSelected();
}

function extentText(e) {
  return e ? e.axes.map((a, i) => a + " " + e.min_mm[i] + ".." + e.max_mm[i]).join(" ") + " mm" : "";
}

function checkText(name, check) {
  if (!check) return "";
  if (!check.ok) return name + " refused:\n" + check.errors.join("\n");
  const lines = check.lines ? check.lines.last_line + " of " + check.lines.lines_total + " lines" : "";
  return name + " checked: " + check.blocks + " blocks, " + lines + ", extent " + extentText(check.extent);
}

function showCheck(text, bad) { $("check").textContent = text; $("check").className = bad ? "check bad" : "check"; }

$("file").addEventListener("change", async () => {
  // upload into the daemon's library: drawn at once, checked by the daemon once (file:line errors)
  const file = $("file").files[0];
  if (!file) return;
  const text = await file.text();
  const name = file.name.replace(/[^A-Za-z0-9._-]/g, "_").replace(/^[._-]+/, "") || "program.nc";
  showProgram(name, text, null);
  showCheck("checking " + name + "…", false);
  const answer = await api("POST", "programs?name=" + encodeURIComponent(name), text, "text/plain");
  $("file").value = "";
  if (answer.ok === false) {
    showCheck(name + " refused, not added:\n" + [answer.error].concat(answer.errors).filter((v, i, a) => v && a.indexOf(v) === i).join("\n"), true);
    clearProgram(name + " refused: no program selected");  // a refused program has no preview
    return;
  }
  program.check = answer.program.check;
  showCheck(checkText(name, program.check), false);
  await loadPrograms();
});

async function selectProgram(name) {
  const answer = await api("GET", "programs/" + encodeURIComponent(name));
  if (!answer.program) return;
  showProgram(name, answer.program.text, answer.program.check);
  showCheck(checkText(name, answer.program.check), false);
}

function markSelected() {
  for (const li of $("programs").children) li.classList.toggle("selected", !!program && li.dataset.program === program.name);
  $("queue-add").disabled = !program || !library.some((p) => p.name === program.name);
}

function smallButton(label, title, onClick) {
  const b = document.createElement("button");
  b.className = "small"; b.textContent = label; b.title = title; b.addEventListener("click", onClick);
  return b;
}

async function loadPrograms() {
  const answer = await api("GET", "programs");
  if (!answer.programs) return;
  library = answer.programs;
  const list = $("programs");
  list.innerHTML = "";
  if (!library.length) { const li = document.createElement("li"); li.className = "muted"; li.textContent = "the library is empty"; list.append(li); }
  for (const p of library) {
    const li = document.createElement("li");
    li.dataset.program = p.name;
    const pick = document.createElement("button");
    pick.className = "pick"; pick.textContent = p.name; pick.title = "select: preview and start";
    pick.addEventListener("click", () => selectProgram(p.name));
    const info = document.createElement("span");
    info.className = "info";
    info.textContent = p.check ? p.check.blocks + " blocks · " + extentText(p.check.extent) : "";
    li.append(pick, info, smallButton("+ queue", "add to the job queue", () => api("POST", "queue", { program: p.name })),
      smallButton("✕", "remove from the library", async () => {
        if (!confirm("Remove " + p.name + " from the library?")) return;
        await api("DELETE", "programs/" + encodeURIComponent(p.name));
        if (program && program.name === p.name) clearProgram("no program selected");
        loadPrograms();
      }));
    list.append(li);
  }
  markSelected();
}

async function loadQueue() {
  const answer = await api("GET", "queue");
  if (!answer.queue) return;
  const q = answer.queue, list = $("queue");
  $("queue-state").textContent = q.paused ? "paused: " + q.paused : (q.entries.length ? "runs when idle" : "empty");
  list.innerHTML = "";
  q.entries.forEach((e, i) => {
    const li = document.createElement("li");
    const text = document.createElement("span");
    text.textContent = e.program + (e.start_line ? " from line " + e.start_line : "");
    li.append(text);
    if (i > 0) li.append(smallButton("↑", "run earlier", () => api("PUT", "queue/" + e.id, { position: i })));
    li.append(smallButton("✕", "take out of the queue", () => api("DELETE", "queue/" + e.id)));
    li.dataset.entry = e.id;
    list.append(li);
  });
}

$("queue-add").addEventListener("click", () => { if (program) api("POST", "queue", { program: program.name }); });
$("queue-pause").addEventListener("click", () => api("POST", "queue/pause"));
$("queue-resume").addEventListener("click", () => api("POST", "queue/resume"));
$("queue-clear").addEventListener("click", () => { if (confirm("Remove every queue entry?")) api("DELETE", "queue"); });

$("btn-start").addEventListener("click", async () => {
  if (!program) return;
  const line = Number($("start-line").value);
  const body = { program: program.name };
  if (Number.isInteger(line) && line > 1) body.start_line = line;  // restart after a broken tool
  const answer = await api("POST", "jobs", body);
  if (answer.ok === false) showCheck([answer.error].concat(answer.errors).filter((v, i, a) => v && a.indexOf(v) === i).join("\n"), true);
  else showCheck("started: job " + answer.job.id + (answer.job.summary.checked_from_store ? " (checked when added)" : ""), false);
});
$("btn-hold").addEventListener("click", () => api("POST", "machine/hold"));
$("btn-resume").addEventListener("click", () => api("POST", "machine/resume"));
$("btn-stop").addEventListener("click", () => api("POST", "machine/stop"));
$("btn-abort").addEventListener("click", () => api("POST", "machine/abort"));
$("btn-reset").addEventListener("click", () => api("POST", "machine/reset"));
$("btn-home").addEventListener("click", () => api("POST", "machine/home", {}));
let overrideTimer = null;
$("override").addEventListener("input", () => {
  $("override-value").textContent = $("override").value + " %";
  clearTimeout(overrideTimer);
  overrideTimer = setTimeout(() => api("PUT", "machine/override", { percent: Number($("override").value) }), 150);
});
$("api-key").addEventListener("change", () => { localStorage.setItem("nurbsmotion-key", $("api-key").value); if (ws) ws.close(); });

const mdiHistory = JSON.parse(localStorage.getItem("nurbsmotion-mdi") || "[]");
function showMdiHistory() { $("mdi-history").innerHTML = ""; mdiHistory.forEach((l) => { const o = document.createElement("option"); o.value = l; $("mdi-history").append(o); }); }
showMdiHistory();
$("mdi-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  const text = $("mdi").value.trim();
  if (!text) return;
  const answer = await api("POST", "machine/mdi", { text });
  if (answer.ok !== false) {
    mdiHistory.unshift(text); mdiHistory.splice(20);
    localStorage.setItem("nurbsmotion-mdi", JSON.stringify(mdiHistory)); showMdiHistory(); $("mdi").value = "";
  }
});

async function loadJobs() {
  const answer = await api("GET", "jobs?limit=15");
  if (!answer.jobs) return;
  const list = $("jobs");
  list.innerHTML = "";
  for (const job of answer.jobs) {
    const li = document.createElement("li");
    const outcome = job.outcome || (job.running ? "running" : "?");
    li.innerHTML = "";
    li.append(document.createTextNode((job.name || job.id) + " "));
    const span = document.createElement("span");
    span.className = "outcome-" + outcome; span.textContent = outcome;
    li.append(span);
    const plot = document.createElement("a");
    plot.href = "/api/v1/jobs/" + encodeURIComponent(job.id) + "/files/plot.png"; plot.textContent = " plot"; plot.target = "_blank";
    li.append(plot);
    li.dataset.job = job.id;
    list.append(li);
  }
}

// ------------------------------------------------------------------ preview (3-D, Canvas 2D)
// The path as one Float32Array of segment end points (x0 y0 z0 x1 y1 z1 per move) with a
// rapid flag each; drawn by an orthographic projection that orbits (yaw, pitch), pans and
// zooms, so a 100,000-line program is parsed and drawn in well under a second without WebGL.
function parseGcode(text) {
  // G0/G1/G2/G3 with G90/G91, G20/G21, G17 arcs by I J (or R) as chords; comments removed.
  const segs = [], rapid = [];
  let pos = [0, 0, 0], absolute = true, scale = 1, mode = 0;
  const push = (a, b, isRapid) => { segs.push(a[0], a[1], a[2], b[0], b[1], b[2]); rapid.push(isRapid ? 1 : 0); };
  const word = /([A-Z])\s*([-+]?\d*\.?\d+)/g;
  for (const raw of text.split("\n")) {
    let line = raw.toUpperCase();
    if (line.includes("(")) line = line.replace(/\(.*?\)/g, "");
    if (line.includes(";")) line = line.slice(0, line.indexOf(";"));
    const words = {}; const gs = [];
    word.lastIndex = 0;
    for (let m = word.exec(line); m !== null; m = word.exec(line)) {
      if (m[1] === "G") gs.push(Number(m[2])); else words[m[1]] = Number(m[2]);
    }
    for (const g of gs) {
      if (g === 90) absolute = true; else if (g === 91) absolute = false;
      else if (g === 20) scale = 25.4; else if (g === 21) scale = 1;
      else if (g === 0 || g === 1 || g === 2 || g === 3) mode = g;
    }
    if (!("X" in words || "Y" in words || "Z" in words)) continue;
    const end = AXES.map((a, i) => a in words ? (absolute ? words[a] * scale : pos[i] + words[a] * scale) : pos[i]);
    if (mode === 2 || mode === 3) {
      let cx, cy;
      if ("R" in words) {
        const r = words.R * scale, dx = end[0] - pos[0], dy = end[1] - pos[1], d = Math.hypot(dx, dy);
        const h = Math.sqrt(Math.max(r * r - d * d / 4, 0)) * ((mode === 2) === (r > 0) ? -1 : 1);
        cx = pos[0] + dx / 2 - h * dy / d; cy = pos[1] + dy / 2 + h * dx / d;
      } else { cx = pos[0] + (words.I || 0) * scale; cy = pos[1] + (words.J || 0) * scale; }
      const a0 = Math.atan2(pos[1] - cy, pos[0] - cx), a1 = Math.atan2(end[1] - cy, end[0] - cx);
      let sweep = a1 - a0;
      if (mode === 2 && sweep >= 0) sweep -= 2 * Math.PI;
      if (mode === 3 && sweep <= 0) sweep += 2 * Math.PI;
      const r = Math.hypot(pos[0] - cx, pos[1] - cy), n = Math.max(4, Math.ceil(Math.abs(sweep) * 16));
      let prev = pos;
      for (let k = 1; k <= n; k++) {
        const a = a0 + sweep * k / n, p = [cx + r * Math.cos(a), cy + r * Math.sin(a), pos[2] + (end[2] - pos[2]) * k / n];
        push(prev, p, false); prev = p;
      }
    } else push(pos, end, mode === 0);
    pos = end;
  }
  return { segs: new Float32Array(segs), rapid: new Uint8Array(rapid), count: rapid.length };
}

function softBox() {
  // The soft limits from the status (machine mm), as work coordinates; null where an axis has none.
  if (!status || !status.axes) return null;
  const lim = AXES.map((name, i) => { const a = status.axes.find((x) => x.name === name); return a && a.soft_limits_mm ? a.soft_limits_mm.map((v) => v - workOffset(i)) : null; });
  return lim.every((l) => l) ? lim : null;
}

function project(x, y, z) {
  // orthographic, about the path's centre (on screen at view.x, view.y): turn by yaw about Z,
  // then tilt by pitch (0: seen from above, Y up; pi/2: seen from the front, Z up)
  const c = view.center, dx = x - c[0], dy = y - c[1], dz = z - c[2];
  const cy = Math.cos(view.yaw), sy = Math.sin(view.yaw), cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
  const u = cy * dx - sy * dy, w = sy * dx + cy * dy;
  return [view.x + view.scale * u, view.y - view.scale * (cp * w + sp * dz)];
}

function fit(canvas) {
  const s = program.path.segs, box = [[Infinity, -Infinity], [Infinity, -Infinity], [Infinity, -Infinity]];
  for (let i = 0; i < s.length; i += 3) for (let k = 0; k < 3; k++) { box[k][0] = Math.min(box[k][0], s[i + k]); box[k][1] = Math.max(box[k][1], s[i + k]); }
  const corners = [];
  for (const x of box[0]) for (const y of box[1]) for (const z of box[2]) corners.push([x, y, z]);
  view.center = box.map((b) => (b[0] + b[1]) / 2);
  view.scale = 1; view.x = 0; view.y = 0;
  const pts = corners.map((c) => project(c[0], c[1], c[2]));
  const us = pts.map((p) => p[0]), vs = pts.map((p) => p[1]);
  const w = Math.max(Math.max(...us) - Math.min(...us), 1e-3), h = Math.max(Math.max(...vs) - Math.min(...vs), 1e-3);
  view.scale = 0.9 * Math.min(canvas.width / w, canvas.height / h);
  view.x = canvas.width / 2 - view.scale * (Math.min(...us) + Math.max(...us)) / 2;
  view.y = canvas.height / 2 - view.scale * (Math.min(...vs) + Math.max(...vs)) / 2;
  view.fitted = true;
}

function strokeSegments(ctx, segs, rapid, wantRapid) {
  // project() inlined: 200,000 end points without an array each
  const [c0, c1, c2] = view.center, k = view.scale, cy = Math.cos(view.yaw), sy = Math.sin(view.yaw);
  const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch), ox = view.x, oy = view.y;
  let lastX = NaN, lastY = NaN;
  ctx.beginPath();
  for (let i = 0, n = rapid.length; i < n; i++) {
    if (rapid[i] !== wantRapid) continue;
    const o = 6 * i;
    let dx = segs[o] - c0, dy = segs[o + 1] - c1, dz = segs[o + 2] - c2;
    const ax = ox + k * (cy * dx - sy * dy), ay = oy - k * (cp * (sy * dx + cy * dy) + sp * dz);
    dx = segs[o + 3] - c0; dy = segs[o + 4] - c1; dz = segs[o + 5] - c2;
    const bx = ox + k * (cy * dx - sy * dy), by = oy - k * (cp * (sy * dx + cy * dy) + sp * dz);
    if (ax !== lastX || ay !== lastY) ctx.moveTo(ax, ay);  // a polyline stays one stroke
    ctx.lineTo(bx, by);
    lastX = bx; lastY = by;
  }
  ctx.stroke();
}

let pathLayer = null;  // the path and the soft-limit box drawn once per view: status updates only add the tool
let pathLayerKey = "";

function drawPathLayer(canvas) {
  const key = [program && program.name, program && program.path.count, view.scale, view.x, view.y, view.yaw, view.pitch,
               JSON.stringify(softBox())].join("|");
  if (pathLayer && key === pathLayerKey) return;
  pathLayer = pathLayer || document.createElement("canvas");
  pathLayer.width = canvas.width; pathLayer.height = canvas.height;
  const ctx = pathLayer.getContext("2d");
  ctx.fillStyle = "#0b0d10"; ctx.fillRect(0, 0, canvas.width, canvas.height);
  const box = softBox();
  if (box) {  // the soft-limit box, faint
    ctx.strokeStyle = "#5a4040"; ctx.lineWidth = 1; ctx.setLineDash([2, 3]); ctx.beginPath();
    const c = (i) => [box[0][i & 1], box[1][(i >> 1) & 1], box[2][(i >> 2) & 1]];
    for (const [a, b] of [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]]) {
      const p = project(...c(a)), q = project(...c(b)); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]);
    }
    ctx.stroke();
  }
  ctx.lineWidth = 1.5;
  ctx.setLineDash([4, 4]); ctx.strokeStyle = "#6b7380"; strokeSegments(ctx, program.path.segs, program.path.rapid, 1);
  ctx.setLineDash([]); ctx.strokeStyle = "#3d8bfd"; strokeSegments(ctx, program.path.segs, program.path.rapid, 0);
  pathLayerKey = key;
}

function drawPreview() {
  const canvas = $("preview"), ctx = canvas.getContext("2d");
  if (!program || !program.path.count) {
    ctx.fillStyle = "#0b0d10"; ctx.fillRect(0, 0, canvas.width, canvas.height);
    ctx.fillStyle = "#8a94a3"; ctx.font = "16px system-ui"; ctx.fillText("choose a program to see its path", 20, 30); return;
  }
  if (!view.fitted) fit(canvas);
  drawPathLayer(canvas);
  ctx.drawImage(pathLayer, 0, 0);
  if (trail.length > 1) {
    ctx.beginPath(); ctx.strokeStyle = "#2fa36b"; ctx.lineWidth = 2.5;
    trail.forEach((p, i) => { const q = project(p[0] - workOffset(0), p[1] - workOffset(1), p[2] - workOffset(2)); if (i) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]); });
    ctx.stroke();
  }
  if (status && status.axes && status.axes.length >= 3) {
    const t = project(status.axes[0].commanded_mm - workOffset(0), status.axes[1].commanded_mm - workOffset(1), status.axes[2].commanded_mm - workOffset(2));
    ctx.beginPath(); ctx.fillStyle = "#d6a11e"; ctx.arc(t[0], t[1], 5, 0, 2 * Math.PI); ctx.fill();
  }
}

function setView(yaw, pitch) { view.yaw = yaw; view.pitch = pitch; view.fitted = false; drawPreview(); }

(function orbitPanZoom() {
  const canvas = $("preview");
  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => { drag = { x: e.offsetX, y: e.offsetY, pan: e.button === 2 || e.shiftKey }; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const k = canvas.width / canvas.clientWidth, dx = (e.offsetX - drag.x) * k, dy = (e.offsetY - drag.y) * k;
    if (drag.pan) { view.x += dx; view.y += dy; }
    else {  // orbit about the path's centre
      view.yaw += dx * 0.01; view.pitch = Math.max(0, Math.min(Math.PI / 2, view.pitch + dy * 0.01));
    }
    drag.x = e.offsetX; drag.y = e.offsetY; drawPreview();
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const k = canvas.width / canvas.clientWidth, px = e.offsetX * k, py = e.offsetY * k, f = e.deltaY < 0 ? 1.2 : 1 / 1.2;
    view.x = px - (px - view.x) * f; view.y = py - (py - view.y) * f; view.scale *= f; drawPreview();
  }, { passive: false });
  $("view-top").addEventListener("click", () => setView(0, 0));
  $("view-front").addEventListener("click", () => setView(0, Math.PI / 2));
  $("view-iso").addEventListener("click", () => setView(-Math.PI / 4, Math.PI / 3.3));
})();

connect();
loadJobs();
loadPrograms();
loadQueue();
drawPreview();
