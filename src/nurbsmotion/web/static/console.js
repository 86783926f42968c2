// The nurbsmotion console: status over the gateway's WebSocket, commands over its HTTP API.
// No build step, no framework: the page and this file ship in the Python package.
"use strict";

const $ = (id) => document.getElementById(id);
const AXES = ["X", "Y", "Z"];
const RENEW_MS = 200;            // continuous jog: renew the daemon's lease (0.5 s) this often
let status = null;               // the daemon's status, kept current from the pushed changes
let ws = null;
let program = null;              // {name, text, moves}
let trail = [];                  // executed tool positions of the running job (machine XY)
let view = { scale: 1, x: 0, y: 0, fitted: false };
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
  $("spindle").textContent = status.spindle ? (status.spindle.direction || status.spindle.state || JSON.stringify(status.spindle)) : "none";
  $("coolant").textContent = status.coolant ? (status.coolant.mode || JSON.stringify(status.coolant)) : "off";
  const homing = status.homing && status.homing.axes ? status.homing.axes : {};
  $("homed").textContent = Object.keys(homing).length
    ? Object.entries(homing).map(([k, v]) => k + " " + v).join(", ") : "";
  if (job) {
    $("progress-bar").style.width = (job.percent || 0) + "%";
    $("progress").textContent = "job " + job.id + " " + job.name + ": " + (job.percent || 0).toFixed(1) + " %, at " + (job.line || "–");
    const x = status.axes[0] ? status.axes[0].commanded_mm : 0, y = status.axes[1] ? status.axes[1].commanded_mm : 0;
    const last = trail[trail.length - 1];
    if (!last || Math.hypot(last[0] - x, last[1] - y) > 1e-3) trail.push([x, y]);
  } else {
    const done = status.last_job;
    $("progress-bar").style.width = done && done.outcome === "completed" ? "100%" : "0";
    $("progress").textContent = done ? "last job " + done.id + " " + done.name + ": " + done.outcome
      + (done.line_reached ? " at " + done.line_reached : "") : "";
  }
  const running = ["running", "pausing", "held", "stopping"].includes(status.state);
  $("btn-start").disabled = !program || running || status.state === "fault";
  $("btn-hold").disabled = status.state !== "running";
  $("btn-resume").disabled = status.state !== "held";
  $("btn-stop").disabled = !running;
  const override = status.override ? status.override.requested_percent : 100;
  if (document.activeElement !== $("override")) { $("override").value = override; $("override-value").textContent = override + " %"; }
  drawPreview();
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
    if (m.notify === "status") { merge(status, m.changes); render(); return; }
    if (m.notify === "event") {
      addLog(m.line, m.level === "WARNING" || m.level === "ERROR" ? "bad" : "");
      if (m.event === "job_started") trail = [];
      if (m.event === "job_ended" || m.event === "submit_rejected") loadJobs();
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
$("file").addEventListener("change", async () => {
  const file = $("file").files[0];
  if (!file) return;
  const text = await file.text();
  program = { name: file.name.replace(/[^A-Za-z0-9._-]/g, "_"), text, moves: parseGcode(text) };
  $("program-name").textContent = program.name + ": " + program.moves.length + " moves";
  $("check").textContent = ""; $("check").className = "check";
  view.fitted = false; trail = [];
  render();
});

$("btn-start").addEventListener("click", async () => {
  if (!program) return;
  const answer = await api("POST", "jobs?name=" + encodeURIComponent(program.name), program.text, "text/plain");
  const check = $("check");
  if (answer.ok === false) { check.textContent = [answer.error].concat(answer.errors).join("\n"); check.className = "check bad"; }
  else { check.textContent = "checked and started: job " + answer.job.id; check.className = "check"; }
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

// ------------------------------------------------------------------ preview (top view)
function parseGcode(text) {
  // G0/G1/G2/G3 in XY(Z) with G90/G91 and G20/G21; arcs by I J (or R) as short chords.
  const moves = [];
  let pos = [0, 0, 0], absolute = true, scale = 1, mode = 0;
  for (const raw of text.split(/\r?\n/)) {
    const line = raw.replace(/\(.*?\)/g, "").replace(/;.*/, "").toUpperCase();
    const words = {}; const gs = [];
    for (const m of line.matchAll(/([A-Z])\s*([-+]?\d*\.?\d+)/g)) {
      if (m[1] === "G") gs.push(Number(m[2])); else words[m[1]] = Number(m[2]);
    }
    for (const g of gs) {
      if (g === 90) absolute = true; else if (g === 91) absolute = false;
      else if (g === 20) scale = 25.4; else if (g === 21) scale = 1;
      else if ([0, 1, 2, 3].includes(g)) mode = g;
    }
    if (!("X" in words || "Y" in words || "Z" in words)) continue;
    const end = AXES.map((a, i) => a in words ? (absolute ? words[a] * scale : pos[i] + words[a] * scale) : pos[i]);
    if (mode === 2 || mode === 3) {
      const cx = pos[0] + (words.I || 0) * scale, cy = pos[1] + (words.J || 0) * scale;
      const a0 = Math.atan2(pos[1] - cy, pos[0] - cx); let a1 = Math.atan2(end[1] - cy, end[0] - cx);
      let sweep = a1 - a0;
      if (mode === 2 && sweep >= 0) sweep -= 2 * Math.PI; if (mode === 3 && sweep <= 0) sweep += 2 * Math.PI;
      const r = Math.hypot(pos[0] - cx, pos[1] - cy), n = Math.max(4, Math.ceil(Math.abs(sweep) * 16));
      let prev = pos;
      for (let k = 1; k <= n; k++) {
        const a = a0 + sweep * k / n, p = [cx + r * Math.cos(a), cy + r * Math.sin(a), pos[2] + (end[2] - pos[2]) * k / n];
        moves.push({ from: prev, to: p, rapid: false }); prev = p;
      }
    } else moves.push({ from: pos, to: end, rapid: mode === 0 });
    pos = end;
  }
  return moves;
}

function fit(canvas) {
  const pts = program.moves.flatMap((m) => [m.from, m.to]);
  const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
  const minX = Math.min(...xs), maxX = Math.max(...xs), minY = Math.min(...ys), maxY = Math.max(...ys);
  const w = Math.max(maxX - minX, 1e-3), h = Math.max(maxY - minY, 1e-3);
  view.scale = 0.9 * Math.min(canvas.width / w, canvas.height / h);
  view.x = canvas.width / 2 - view.scale * (minX + maxX) / 2;
  view.y = canvas.height / 2 + view.scale * (minY + maxY) / 2;
  view.fitted = true;
}

function drawPreview() {
  const canvas = $("preview"), ctx = canvas.getContext("2d");
  ctx.fillStyle = "#0b0d10"; ctx.fillRect(0, 0, canvas.width, canvas.height);
  if (!program || !program.moves.length) {
    ctx.fillStyle = "#8a94a3"; ctx.font = "16px system-ui"; ctx.fillText("choose a program to see its path", 20, 30); return;
  }
  if (!view.fitted) fit(canvas);
  const X = (x) => view.x + view.scale * x, Y = (y) => view.y - view.scale * y;
  ctx.lineWidth = 1.5;
  for (const rapid of [true, false]) {
    ctx.beginPath(); ctx.setLineDash(rapid ? [4, 4] : []); ctx.strokeStyle = rapid ? "#6b7380" : "#3d8bfd";
    for (const m of program.moves) if (m.rapid === rapid) { ctx.moveTo(X(m.from[0]), Y(m.from[1])); ctx.lineTo(X(m.to[0]), Y(m.to[1])); }
    ctx.stroke();
  }
  ctx.setLineDash([]);
  if (trail.length > 1) {
    ctx.beginPath(); ctx.strokeStyle = "#2fa36b"; ctx.lineWidth = 2;
    trail.forEach((p, i) => { const x = X(p[0] - workOffset(0)), y = Y(p[1] - workOffset(1)); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
    ctx.stroke();
  }
  if (status && status.axes && status.axes.length >= 2) {
    const tx = X(status.axes[0].commanded_mm - workOffset(0)), ty = Y(status.axes[1].commanded_mm - workOffset(1));
    ctx.beginPath(); ctx.fillStyle = "#d6a11e"; ctx.arc(tx, ty, 5, 0, 2 * Math.PI); ctx.fill();
  }
}

(function panZoom() {
  const canvas = $("preview");
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => { drag = [e.offsetX, e.offsetY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const k = canvas.width / canvas.clientWidth;
    view.x += (e.offsetX - drag[0]) * k; view.y += (e.offsetY - drag[1]) * k; drag = [e.offsetX, e.offsetY]; drawPreview();
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const k = canvas.width / canvas.clientWidth, px = e.offsetX * k, py = e.offsetY * k, f = e.deltaY < 0 ? 1.2 : 1 / 1.2;
    view.x = px - (px - view.x) * f; view.y = py - (py - view.y) * f; view.scale *= f; drawPreview();
  }, { passive: false });
})();

connect();
loadJobs();
drawPreview();
