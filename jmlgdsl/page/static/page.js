// The operator's page: a live view of one run of a jmlgdsl monitor's store (jmlgdsl/page/server.py).
// Everything a spec or an operator wrote (mode names, descriptions, sensor names, reasons) is put on
// the page as text (textContent), never as markup.
"use strict";

const PALETTE = ["#2e8b57", "#c0392b", "#2874a6", "#d68910", "#7d3c98", "#17a589", "#a04000", "#566573",
                 "#cb4335", "#1f618d", "#b7950b", "#6c3483"];
const LIVE_ROWS = 300;   // rows shown while following the newest
const KEEP_ROWS = 5000;  // rows kept in the browser while live

const state = {
  run: null,
  rows: empty(),
  live: true,
  window: null,      // [first t, last t] shown when not live
  alarms: [],
  selected: null,    // alarm id whose evidence is shown
  drag: null,
};

function empty() {
  return {t: [], time: [], map_mode: [], alarm: [], posterior: [], y: [], y_pred: [], y_sd: [],
          evidence_mode: [], evidence: []};
}

function $(id) { return document.getElementById(id); }

function element(tag, text, className) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = String(text);
  if (className) node.className = className;
  return node;
}

// A fleet's page shows one unit at a time: ?unit=NAME picks it (default the one the server was started on).
const UNIT = new URLSearchParams(location.search).get("unit");

function api(path) {
  return UNIT ? `${path}${path.includes("?") ? "&" : "?"}unit=${encodeURIComponent(UNIT)}` : path;
}

async function getJSON(url) {
  const response = await fetch(url, {cache: "no-store"});
  if (!response.ok) throw new Error((await response.json()).error || response.statusText);
  return response.json();
}

// ------------------------------------------------------------------ start
async function start() {
  state.run = await getJSON(api("api/run"));
  const run = state.run;
  $("plant").textContent = run.plant;
  if (run.fleet.length) {
    const units = $("unit");
    for (const name of run.fleet) units.appendChild(element("option", name)).value = name;
    units.value = run.unit;
    units.hidden = false;
    units.addEventListener("change", () => { location.search = `?unit=${encodeURIComponent(units.value)}`; });
  }
  const source = run.unit ? (run.source || "").replaceAll("{unit}", run.unit) : run.source || "";  // the unit's own
  $("source").textContent = `${source} · filter ${run.filter}${run.lag ? ", lag " + run.lag : ""}`;
  document.title = `${run.plant}: jmlgdsl monitor`;
  $("tokenbox").hidden = !run.token_required;
  $("who").value = localStorage.getItem("jmlgdsl-who") || "";
  $("who").addEventListener("change", () => localStorage.setItem("jmlgdsl-who", $("who").value));
  $("token").value = sessionStorage.getItem("jmlgdsl-token") || "";
  $("token").addEventListener("change", () => sessionStorage.setItem("jmlgdsl-token", $("token").value));
  legend();
  plots();
  for (const canvas of document.querySelectorAll("canvas")) interact(canvas);
  $("live").addEventListener("click", () => goLive());
  window.addEventListener("resize", draw);
  state.rows = await getJSON(api("api/rows"));
  showAlarms(await getJSON(api("api/alarms")));
  draw();
  stream();
}

function stream() {
  const last = state.rows.t.length ? state.rows.t[state.rows.t.length - 1] : 0;
  const source = new EventSource(api(`api/stream?after=${last}`));
  source.addEventListener("rows", (event) => append(JSON.parse(event.data)));
  source.onopen = () => { if (state.live) latest(state.rows); };
  source.addEventListener("alarms", (event) => showAlarms(JSON.parse(event.data)));
  source.onerror = () => { $("status").textContent = "connection lost: trying again"; $("status").className = "stale"; };
}

function append(rows) {
  if (state.live) {
    for (const key of Object.keys(state.rows)) state.rows[key].push(...rows[key]);
    const extra = state.rows.t.length - KEEP_ROWS;
    if (extra > 0) for (const key of Object.keys(state.rows)) state.rows[key].splice(0, extra);
  }
  latest(rows);
  if (state.live) draw();
}

function latest(rows) {
  const i = rows.t.length - 1;
  if (i < 0) {
    $("status").textContent = "waiting for the first row";
    return;
  }
  $("status").textContent = `row ${rows.t[i]}${stamp(rows.time[i])}`;
  $("status").className = "";
  const run = state.run, mode = rows.map_mode[i], k = run.modes.indexOf(mode);
  $("mode").textContent = mode;
  $("mode").className = "mode " + (run.healthy.includes(mode) ? "healthy" : "faulty");
  $("probability").textContent = `p = ${rows.posterior[i][k].toFixed(3)}`;
  $("description").textContent = run.descriptions[mode] || "";
}

function stamp(time) {
  if (time === null || time === undefined) return "";
  return time > 1e8 ? ", " + new Date(time * 1000).toISOString().replace("T", " ").slice(0, 19) + " UTC"
                    : `, time ${time} s`;
}

// ------------------------------------------------------------------ windows: live, zoom and pan
function shown() {
  const t = state.rows.t;
  if (!t.length) return [0, 1];
  if (state.live || !state.window) {
    const last = t[t.length - 1];
    return [Math.max(t[0], last - LIVE_ROWS + 1), last];
  }
  return state.window;
}

function goLive() {
  state.live = true;
  state.window = null;
  $("live").className = "on";
  getJSON(api("api/rows")).then((rows) => { state.rows = rows; draw(); });
}

let pending = null;
function moveTo(first, last) {
  state.live = false;
  $("live").className = "";
  state.window = [Math.round(first), Math.round(last)];
  draw();
  clearTimeout(pending);
  pending = setTimeout(async () => {   // the rows of the new window, thinned to the page's width
    const [a, b] = state.window;
    state.rows = await getJSON(api(`api/rows?first=${Math.max(1, a)}&last=${b}&limit=1500`));
    draw();
  }, 120);
}

function interact(canvas) {
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const [a, b] = shown();
    const box = canvas.getBoundingClientRect();
    const at = a + (b - a) * (event.clientX - box.left) / box.width;
    const factor = event.deltaY > 0 ? 1.25 : 0.8;
    moveTo(at - (at - a) * factor, at + (b - at) * factor);
  }, {passive: false});
  canvas.addEventListener("mousedown", (event) => { state.drag = {x: event.clientX, window: shown(), canvas}; });
  window.addEventListener("mouseup", () => { state.drag = null; });
  window.addEventListener("mousemove", (event) => {
    const drag = state.drag;
    if (!drag || drag.canvas !== canvas) return;
    const [a, b] = drag.window;
    const shift = (drag.x - event.clientX) / canvas.getBoundingClientRect().width * (b - a);
    if (Math.abs(shift) >= 1) moveTo(a + shift, b + shift);
  });
}

// ------------------------------------------------------------------ drawing
function legend() {
  const box = $("legend");
  state.run.modes.forEach((mode, k) => {
    const item = element("span", mode);
    item.style.setProperty("--swatch", PALETTE[k % PALETTE.length]);
    item.title = state.run.descriptions[mode] || "";
    box.appendChild(item);
  });
}

function plots() {
  const box = $("plots");
  state.run.outputs.forEach((name, i) => {
    const plot = element("div", null, "plot");
    const unit = state.run.units[name];
    plot.appendChild(element("div", unit ? `${name} [${unit}]` : name, "name"));
    const canvas = element("canvas");
    canvas.height = 90;
    canvas.dataset.output = i;
    plot.appendChild(canvas);
    box.appendChild(plot);
  });
}

function sized(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth, height = Number(canvas.getAttribute("height"));
  canvas.width = width * ratio;
  canvas.style.height = height + "px";
  canvas.height = height * ratio;
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  return [g, width, height];
}

const LEFT = 74;  // room for the mode names and the sensor scales

function draw() {
  const [a, b] = shown();
  drawStrip(a, b);
  for (const canvas of $("plots").querySelectorAll("canvas")) drawSensor(canvas, Number(canvas.dataset.output), a, b);
}

function xOf(t, a, b, width) { return LEFT + (t - a + 0.5) / (b - a + 1) * (width - LEFT); }

function visible(a, b) {
  const t = state.rows.t, out = [];
  for (let j = 0; j < t.length; j++) if (t[j] >= a && t[j] <= b) out.push(j);
  return out;
}

function drawStrip(a, b) {
  const canvas = $("strip");
  const [g, width, height] = sized(canvas);
  const modes = state.run.modes, rowHeight = (height - 24) / modes.length;
  g.clearRect(0, 0, width, height);
  g.font = "11px system-ui, sans-serif";
  g.textBaseline = "middle";
  modes.forEach((mode, k) => {
    g.fillStyle = "#6b7785";
    g.fillText(mode.length > 11 ? mode.slice(0, 10) + "…" : mode, 2, k * rowHeight + rowHeight / 2);
  });
  const rows = visible(a, b), step = Math.max(1, (width - LEFT) / (b - a + 1));
  for (const j of rows) {
    const x = xOf(state.rows.t[j], a, b, width) - step / 2;
    state.rows.posterior[j].forEach((p, k) => {
      g.globalAlpha = Math.max(0, Math.min(1, p));
      g.fillStyle = PALETTE[k % PALETTE.length];
      g.fillRect(x, k * rowHeight + 1, step + 0.5, rowHeight - 2);
    });
    if (state.rows.alarm[j]) {
      g.globalAlpha = 1;
      g.fillStyle = "#c0392b";
      g.fillRect(x, height - 22, Math.ceil(step) + 0.5, 6);
    }
  }
  g.globalAlpha = 1;
  axis(g, a, b, width, height);
}

function axis(g, a, b, width, height) {
  g.fillStyle = "#6b7785";
  g.font = "10px system-ui, sans-serif";
  g.textBaseline = "bottom";
  const ticks = 6;
  for (let i = 0; i <= ticks; i++) {
    const t = Math.round(a + (b - a) * i / ticks);
    g.fillText(`t ${t}`, Math.min(xOf(t, a, b, width), width - 40), height);
  }
}

function drawSensor(canvas, i, a, b) {
  const [g, width, height] = sized(canvas);
  g.clearRect(0, 0, width, height);
  const rows = visible(a, b), R = state.rows;
  const value = (list, j) => (list[j] ? list[j][i] : null);
  let low = Infinity, high = -Infinity;
  for (const j of rows) {
    const y = value(R.y, j), p = value(R.y_pred, j), s = value(R.y_sd, j);
    for (const v of [y, p, p !== null && s !== null ? p - 2 * s : null, p !== null && s !== null ? p + 2 * s : null]) {
      if (v !== null && Number.isFinite(v)) { low = Math.min(low, v); high = Math.max(high, v); }
    }
  }
  if (!Number.isFinite(low)) return;
  const pad = (high - low) * 0.08 || 1;
  low -= pad; high += pad;
  const yOf = (v) => 4 + (high - v) / (high - low) * (height - 8);
  const step = Math.max(1, (width - LEFT) / (b - a + 1));
  g.fillStyle = "rgba(192, 57, 43, 0.10)";   // rows under alarm
  for (const j of rows) if (R.alarm[j]) g.fillRect(xOf(R.t[j], a, b, width) - step / 2, 0, step + 0.5, height);
  g.fillStyle = "rgba(52, 120, 200, 0.18)";  // the band: expected +- 2 sd
  for (const j of rows) {
    const p = value(R.y_pred, j), s = value(R.y_sd, j);
    if (p !== null && s !== null) {
      g.fillRect(xOf(R.t[j], a, b, width) - step / 2, yOf(p + 2 * s), Math.ceil(step), yOf(p - 2 * s) - yOf(p + 2 * s));
    }
  }
  line(g, rows, (j) => value(R.y_pred, j), "#2874a6", a, b, width, yOf);
  g.fillStyle = "#1d2733";
  for (const j of rows) {
    const y = value(R.y, j);
    if (y !== null) g.fillRect(xOf(R.t[j], a, b, width) - 1.5, yOf(y) - 1.5, 3, 3);
  }
  g.fillStyle = "#6b7785";
  g.font = "10px system-ui, sans-serif";
  g.textBaseline = "top";
  g.fillText(high.toPrecision(4), 2, 2);
  g.textBaseline = "bottom";
  g.fillText(low.toPrecision(4), 2, height - 2);
}

function line(g, rows, get, color, a, b, width, yOf) {
  g.strokeStyle = color;
  g.lineWidth = 1.5;
  g.beginPath();
  let pen = false;
  for (const j of rows) {
    const v = get(j);
    if (v === null) { pen = false; continue; }
    const x = xOf(state.rows.t[j], a, b, width);
    if (pen) g.lineTo(x, yOf(v)); else g.moveTo(x, yOf(v));
    pen = true;
  }
  g.stroke();
}

// ------------------------------------------------------------------ alarms
function showAlarms(alarms) {
  state.alarms = alarms;
  const body = $("alarmlist");
  body.replaceChildren();
  $("noalarms").hidden = alarms.length > 0;
  for (const alarm of alarms) {
    const row = element("tr", null, alarm.state.replace(", ", "-"));
    row.dataset.alarm = alarm.id;
    if (alarm.id === state.selected) row.classList.add("selected");
    for (const text of [alarm.id, `t ${alarm.raised_t}`, alarm.cleared_t ? `t ${alarm.cleared_t}` : "–", alarm.mode || ""]) {
      row.appendChild(element("td", text));
    }
    const cell = element("td", null, "state");
    cell.appendChild(element("span", alarm.state, "what"));
    const by = alarm.shelved ? `by ${alarm.shelved.who}: ${alarm.shelved.reason}`
                             : alarm.acknowledged ? `by ${alarm.acknowledged.who}` : "";
    if (by) cell.appendChild(element("span", by, "by"));
    row.appendChild(cell);
    row.appendChild(actions(alarm));
    row.addEventListener("click", (event) => { if (event.target.tagName !== "BUTTON" && event.target.tagName !== "INPUT") select(alarm); });
    body.appendChild(row);
  }
}

function actions(alarm) {
  const cell = element("td", null, "act");
  if (!alarm.acknowledged) cell.appendChild(button("Acknowledge", () => act(alarm, "acknowledge")));
  if (alarm.shelved) {
    cell.appendChild(button("Unshelve", () => act(alarm, "unshelve")));
  } else {
    const reason = element("input");
    reason.placeholder = "reason";
    reason.className = "reason";
    cell.appendChild(reason);
    cell.appendChild(button("Shelve", () => act(alarm, "shelve", reason.value)));
  }
  return cell;
}

function button(text, onclick) {
  const node = element("button", text);
  node.type = "button";
  node.addEventListener("click", onclick);
  return node;
}

async function act(alarm, kind, reason) {
  $("actionerror").textContent = "";
  const headers = {"Content-Type": "application/json"};
  if (state.run.token_required) headers.Authorization = `Bearer ${$("token").value}`;
  const response = await fetch(api(`api/alarms/${alarm.id}/${kind}`), {
    method: "POST", headers, body: JSON.stringify({who: $("who").value, reason})});
  const answer = await response.json();
  if (!response.ok) { $("actionerror").textContent = answer.error; return; }
  showAlarms(answer);
}

async function select(alarm) {
  state.selected = alarm.id;
  for (const row of $("alarmlist").children) row.classList.toggle("selected", Number(row.dataset.alarm) === alarm.id);
  $("whyfor").textContent = `alarm ${alarm.id}: ${alarm.mode || ""}`;
  const found = await getJSON(api(`api/evidence?alarm=${alarm.id}`));
  const box = $("evidence");
  box.replaceChildren();
  if (!found.rows) {
    box.appendChild(element("p", "No evidence was kept for this alarm's rows.", "hint"));
    return;
  }
  box.appendChild(element("p", `log-likelihood ratio of ${found.mode} against the healthy modes, summed over ` +
                                `${found.rows} row${found.rows === 1 ? "" : "s"} (nats):`, "hint"));
  const largest = Math.max(...found.outputs.map((o) => Math.abs(o.nats)), 1e-12);
  for (const output of found.outputs) {
    const bar = element("div", null, "bar");
    bar.dataset.output = output.name;
    const label = element("span", output.name);
    label.title = output.name;
    bar.appendChild(label);
    const track = element("div");
    const fill = element("div", null, "fill" + (output.nats < 0 ? " against" : ""));
    fill.style.width = `${(100 * Math.abs(output.nats) / largest).toFixed(1)}%`;
    track.appendChild(fill);
    bar.appendChild(track);
    bar.appendChild(element("span", output.nats.toFixed(1), "nats"));
    box.appendChild(bar);
  }
}

start().catch((error) => { $("status").textContent = `cannot load the page: ${error.message}`; $("status").className = "stale"; });
