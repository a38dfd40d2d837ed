// The operator's page: a live view of one run of a jmlgdsl monitor's store (jmlgdsl/page/server.py),
// or, for a fleet, the overview of every unit worst first, from which a unit's page opens.
// Everything a spec or an operator wrote (mode names, descriptions, sensor names, reasons) is put on
// the page as text (textContent), never as markup.
"use strict";

// Modes and alarms speak two visual languages that never share a colour: a mode is a swatch and a band
// of its colour (greens for the healthy modes, blues, purples, teals and greys for the others: no red,
// orange or amber), an alarm is a red or amber badge with an icon and an outline (page.css).
const HEALTHY_COLOURS = ["#3a9a4a", "#7cb342", "#2e6b3a"];
const MODE_COLOURS = ["#2f6fb0", "#7b52ab", "#1f9e9a", "#27405e", "#9a7fd1", "#4fa3d8", "#5d6d7e", "#6872c8",
                      "#0f6b63", "#3c2a78"];
const LIVE_ROWS = 300;   // rows shown while following the newest
const KEEP_ROWS = 5000;  // rows kept in the browser while live
const MIN_ROWS = 10;     // the narrowest window zooming in reaches
const FLEET_POLL = 2000; // ms between the overview's looks at the fleet

const state = {
  run: null,
  rows: empty(),
  live: true,
  window: null,      // [first t, last t] shown when not live
  newest: null,      // the newest row: {t, time, mode}
  clock: false,      // whether the run's times are clock times
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

// A mode's colour in a run of these modes, the healthy ones given: the k-th healthy mode's or the k-th other's.
function modeColour(modes, healthy, mode) {
  const palette = healthy.includes(mode) ? HEALTHY_COLOURS : MODE_COLOURS;
  const k = Math.max(0, modes.filter((m) => healthy.includes(m) === healthy.includes(mode)).indexOf(mode));
  return palette[k % palette.length];
}

function colour(mode) { return modeColour(state.run.modes, state.run.healthy, mode); }

function swatch(node, colour) {
  node.classList.add("swatch");
  node.style.setProperty("--swatch", colour);
  return node;
}

// A fleet's page shows one unit at a time: ?unit=NAME picks it (default the one the server was started
// on); ?fleet, or a fleet's page started on no unit, shows the overview of every unit.
const QUERY = new URLSearchParams(location.search);
const UNIT = QUERY.get("unit");

function api(path) {
  return UNIT ? `${path}${path.includes("?") ? "&" : "?"}unit=${encodeURIComponent(UNIT)}` : path;
}

async function getJSON(url) {
  const response = await fetch(url, {cache: "no-store"});
  if (!response.ok) throw new Error((await response.json()).error || response.statusText);
  return response.json();
}

// ------------------------------------------------------------------ times
// A row's time is a clock time (seconds since 1970, UTC) from CLOCK on, shown as the browser's local
// time with its zone and the row number on hover; a smaller one counts seconds from a recording's
// start, and rows are shown by their number (t 405).
const CLOCK = 1e8;  // 1973-03-03: no recording's own seconds reach it
const TICK_STEPS = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400,
                    172800, 604800, 2592000];  // seconds between the time axis's ticks, the fewest that give <= 7

function isClock(time) { return typeof time === "number" && time >= CLOCK; }

function pad(n) { return String(n).padStart(2, "0"); }

function day(time) {
  const d = new Date(time * 1000);
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())}`;
}

function clockOf(time, seconds = true) {
  const d = new Date(time * 1000);
  return `${pad(d.getHours())}:${pad(d.getMinutes())}` + (seconds ? `:${pad(d.getSeconds())}` : "");
}

function zoneOf(time) {
  const name = Intl.DateTimeFormat().resolvedOptions().timeZone || "local time";
  const offset = -new Date(time * 1000).getTimezoneOffset();
  if (offset === 0 && /^(Etc\/)?(UTC|GMT)$/.test(name)) return "UTC";
  const sign = offset < 0 ? "−" : "+";
  return `${name} (UTC${sign}${pad(Math.floor(Math.abs(offset) / 60))}:${pad(Math.abs(offset) % 60)})`;
}

// The local wall clock's seconds since 1970 (for ticks on whole local minutes, hours and days).
function localSeconds(time) { return time - new Date(time * 1000).getTimezoneOffset() * 60; }

// A row as the page names it: its local clock time (with the date unless it is the newest row's day)
// for clock times, else `t N`; `full` for hover text and titles: the row number, date, time and zone.
function when(t, time) {
  if (!state.clock || !isClock(time)) return `t ${t}`;
  const newest = state.newest && isClock(state.newest.time) ? day(state.newest.time) : null;
  return (day(time) === newest ? "" : day(time) + " ") + clockOf(time);
}

function full(t, time) {
  if (isClock(time)) return `row ${t} · ${day(time)} ${clockOf(time)} ${zoneOf(time)}`;
  return time === null || time === undefined ? `row ${t}` : `row ${t} · time ${time} s`;
}

// ------------------------------------------------------------------ start
async function start() {
  state.run = await getJSON(api("api/run"));
  const run = state.run;
  if (run.fleet.length && !UNIT) {
    const fleet = await getJSON("api/fleet");
    if (QUERY.has("fleet") || fleet.opened === null) return overview(fleet);
  }
  $("plant").textContent = run.plant;
  if (run.fleet.length) {
    const units = $("unit");
    for (const name of run.fleet) units.appendChild(element("option", name)).value = name;
    units.value = run.unit;
    units.hidden = $("allunits").hidden = false;
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
  window.addEventListener("resize", () => { headerHeight(); draw(); });
  headerHeight();
  state.rows = await getJSON(api("api/rows"));
  latest(state.rows);
  showAlarms(await getJSON(api("api/alarms")));
  draw();
  stream();
}

function headerHeight() {
  document.documentElement.style.setProperty("--header", `${document.querySelector("header").offsetHeight}px`);
}

function stream() {
  const last = state.rows.t.length ? state.rows.t[state.rows.t.length - 1] : 0;
  const source = new EventSource(api(`api/stream?after=${last}`));
  source.addEventListener("rows", (event) => append(JSON.parse(event.data)));
  source.onopen = () => { if (state.live) latest(state.rows); };
  source.addEventListener("alarms", (event) => showAlarms(JSON.parse(event.data)));
  source.onerror = () => {
    $("status").textContent = "connection lost: trying again";
    $("status").className = "stale";
  };
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

// The newest of some rows: the mode now, the status line, and the alarms' mode now.
function latest(rows) {
  const i = rows.t.length - 1;
  if (i < 0) {
    if (state.newest === null) $("status").textContent = "waiting for the first row";
    return;
  }
  if (state.newest !== null && rows.t[i] < state.newest.t) return;
  const run = state.run, mode = rows.map_mode[i], k = run.modes.indexOf(mode);
  const changed = state.newest === null || state.newest.mode !== mode;
  state.newest = {t: rows.t[i], time: rows.time[i], mode};
  if (!state.clock && isClock(rows.time[i])) {
    state.clock = true;
    $("zone").textContent = `local time, ${zoneOf(rows.time[i])}; rows on hover`;
  }
  const time = rows.time[i];
  $("status").textContent = `row ${rows.t[i]}` + (isClock(time) ? ` · ${day(time)} ${clockOf(time)}`
                                                                : time === null ? "" : `, time ${time} s`);
  $("status").title = full(rows.t[i], rows.time[i]);
  $("status").className = "";
  $("mode").textContent = mode;
  $("mode").style.setProperty("--swatch", colour(mode));
  $("probability").textContent = `p = ${rows.posterior[i][k].toFixed(3)}`;
  $("description").textContent = run.descriptions[mode] || "";
  if (changed) showAlarms(state.alarms);
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

// A window within the run's rows (1 to the newest): as wide as asked, but no wider than the rows there
// are nor narrower than MIN_ROWS, moved inside them.
function clamp(first, last) {
  const end = state.newest ? state.newest.t : 1;
  const width = Math.min(Math.max(Math.round(last - first), MIN_ROWS - 1), end - 1);
  first = Math.min(Math.max(1, Math.round(first)), end - width);
  return [first, first + width];
}

let pending = null;
function moveTo(first, last) {
  state.live = false;
  $("live").className = "";
  state.window = clamp(first, last);
  draw();
  clearTimeout(pending);
  pending = setTimeout(async () => {   // the rows of the new window, thinned to the page's width
    const [a, b] = state.window;
    state.rows = await getJSON(api(`api/rows?first=${a}&last=${b}&limit=1500`));
    draw();
  }, 120);
}

function interact(canvas) {
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const [a, b] = shown();
    const at = tAt(canvas, event.clientX, a, b);
    const factor = event.deltaY > 0 ? 1.25 : 0.8;
    moveTo(at - (at - a) * factor, at + (b - at) * factor);
  }, {passive: false});
  canvas.addEventListener("mousedown", (event) => { state.drag = {x: event.clientX, window: shown(), canvas}; });
  canvas.addEventListener("mousemove", (event) => hover(canvas, event));
  canvas.addEventListener("mouseleave", () => { $("hover").hidden = true; });
  window.addEventListener("mouseup", () => { state.drag = null; });
  window.addEventListener("mousemove", (event) => {
    const drag = state.drag;
    if (!drag || drag.canvas !== canvas) return;
    const [a, b] = drag.window;
    const shift = (drag.x - event.clientX) / (canvas.getBoundingClientRect().width - LEFT) * (b - a + 1);
    if (Math.abs(shift) >= 1) moveTo(a + shift, b + shift);
  });
}

// The row number under a point of a canvas (fractional).
function tAt(canvas, clientX, a, b) {
  const box = canvas.getBoundingClientRect();
  return a - 0.5 + (clientX - box.left - LEFT) / (box.width - LEFT) * (b - a + 1);
}

// Under the pointer: the nearest row shown, its number, time and most probable mode.
function hover(canvas, event) {
  const t = state.rows.t, tip = $("hover");
  const [a, b] = shown(), at = tAt(canvas, event.clientX, a, b);
  if (!t.length || at < a - 0.5 || at > b + 0.5) { tip.hidden = true; return; }
  let low = 0, high = t.length - 1;
  while (low < high) { const mid = (low + high) >> 1; if (t[mid] < at) low = mid + 1; else high = mid; }
  const j = low > 0 && at - t[low - 1] < t[low] - at ? low - 1 : low;
  const k = state.run.modes.indexOf(state.rows.map_mode[j]);
  tip.textContent = `${full(t[j], state.rows.time[j])} · ${state.rows.map_mode[j]} ` +
                    `${state.rows.posterior[j][k].toFixed(2)}`;
  tip.hidden = false;
  tip.style.left = `${Math.min(event.clientX + 12, window.innerWidth - tip.offsetWidth - 4)}px`;
  tip.style.top = `${event.clientY + 14}px`;
}

// ------------------------------------------------------------------ drawing
function legend() {
  const box = $("legend");
  for (const mode of state.run.modes) {
    const item = swatch(element("span", mode), colour(mode));
    item.title = state.run.descriptions[mode] || "";
    box.appendChild(item);
  }
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
  const rows = visible(a, b);
  drawStrip(a, b, rows);
  for (const canvas of $("plots").querySelectorAll("canvas")) {
    drawSensor(canvas, Number(canvas.dataset.output), a, b, rows);
  }
}

// x of a row's left edge (and, at t + 0.5, of its middle) in a window [a, b] of a canvas `width` wide
function edge(t, a, b, width) { return LEFT + (t - a) / (b - a + 1) * (width - LEFT); }
function xOf(t, a, b, width) { return edge(t + 0.5, a, b, width); }

function visible(a, b) {
  const t = state.rows.t, out = [];
  for (let j = 0; j < t.length; j++) if (t[j] >= a && t[j] <= b) out.push(j);
  return out;
}

// The cells of the shown rows, [left, right) in CSS pixels snapped to whole device pixels, each
// reaching to the next shown row (the rows of a thinned window stand for those between them): cells
// meet without a gap or an overlap, so bands and shading show no stripes.
function cells(rows, a, b, width) {
  const ratio = window.devicePixelRatio || 1, t = state.rows.t;
  const snap = (x) => Math.round(Math.min(Math.max(x, LEFT), width) * ratio) / ratio;
  const stride = rows.length > 1 ? t[rows[1]] - t[rows[0]] : 1;
  return rows.map((j, n) => [snap(edge(t[j], a, b, width)),
                             snap(edge(n + 1 < rows.length ? t[rows[n + 1]] : t[j] + stride, a, b, width))]);
}

// Runs of neighbouring rows of one value, each painted as one rectangle: paint(value, left, right);
// a null value paints nothing.
function runs(rows, spans, value, paint) {
  let from = 0;
  for (let n = 1; n <= rows.length; n++) {
    if (n < rows.length && value(rows[n]) === value(rows[from])) continue;
    const v = value(rows[from]);
    if (v !== null && spans[n - 1][1] > spans[from][0]) paint(v, spans[from][0], spans[n - 1][1]);
    from = n;
  }
}

const SHADES = 64;  // levels of a mode's probability the strip tells apart

function drawStrip(a, b, rows) {
  const canvas = $("strip");
  const [g, width, height] = sized(canvas);
  const modes = state.run.modes, rowHeight = Math.floor((height - 10) / modes.length);
  g.clearRect(0, 0, width, height);
  g.font = "11px system-ui, sans-serif";
  g.textBaseline = "middle";
  modes.forEach((mode, k) => {
    g.fillStyle = "#6b7785";
    g.fillText(mode.length > 11 ? mode.slice(0, 10) + "…" : mode, 2, k * rowHeight + rowHeight / 2);
  });
  const spans = cells(rows, a, b, width);
  modes.forEach((mode, k) => {
    g.fillStyle = colour(mode);
    runs(rows, spans, (j) => Math.round(Math.max(0, Math.min(1, state.rows.posterior[j][k])) * SHADES) || null,
         (level, x0, x1) => {
           g.globalAlpha = level / SHADES;
           g.fillRect(x0, k * rowHeight + 1, x1 - x0, rowHeight - 2);
         });
  });
  g.globalAlpha = 1;
  g.fillStyle = cssColour("--alarm");
  runs(rows, spans, (j) => state.rows.alarm[j] || null,
       (_, x0, x1) => g.fillRect(x0, height - 7, Math.max(x1 - x0, 1), 6));
  axis(a, b, width, rows);
}

// A colour page.css names (the alarms' --alarm and --alarm-shade), for the canvases.
function cssColour(name) { return getComputedStyle(document.documentElement).getPropertyValue(name).trim(); }

// The time axis under the strip: local clock times on whole seconds, minutes, hours or days for clock
// times (the date where a day begins), else row numbers.
function axis(a, b, width, rows) {
  const box = $("axis"), R = state.rows, ticks = [];
  const timed = state.clock ? rows.filter((j) => isClock(R.time[j])) : [];
  if (timed.length > 1) {
    const span = R.time[timed[timed.length - 1]] - R.time[timed[0]];
    const step = TICK_STEPS.find((s) => span / s <= 7) || TICK_STEPS[TICK_STEPS.length - 1];
    for (let n = 1; n < timed.length; n++) {
      const j0 = timed[n - 1], j1 = timed[n], s0 = localSeconds(R.time[j0]), s1 = localSeconds(R.time[j1]);
      const mark = (Math.floor(s0 / step) + 1) * step;
      if (mark > s1 || s1 <= s0) continue;
      const f = (mark - s0) / (s1 - s0), time = R.time[j0] + (mark - s0);
      const midnight = mark % 86400 === 0;
      ticks.push({t: R.t[j0] + f * (R.t[j1] - R.t[j0]), time,
                  text: step >= 86400 || midnight ? day(time).slice(step >= 86400 ? 0 : 5) : clockOf(time, step < 60)});
    }
  } else {
    for (let i = 0; i <= 6; i++) {
      const t = Math.round(a + (b - a) * i / 6);
      ticks.push({t, time: null, text: `t ${t}`});
    }
  }
  box.replaceChildren();
  for (const tick of ticks) {
    const x = Math.min(Math.max(xOf(tick.t, a, b, width), LEFT), width - 20);
    const label = element("span", tick.text);
    label.style.left = `${x}px`;
    label.dataset.t = Math.round(tick.t);
    if (tick.time !== null) label.title = full(Math.round(tick.t), tick.time);
    box.appendChild(label);
  }
}

function drawSensor(canvas, i, a, b, rows) {
  const [g, width, height] = sized(canvas);
  g.clearRect(0, 0, width, height);
  const R = state.rows;
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
  g.fillStyle = cssColour("--alarm-shade");   // rows under alarm
  runs(rows, cells(rows, a, b, width), (j) => R.alarm[j] || null, (_, x0, x1) => g.fillRect(x0, 0, x1 - x0, height));
  band(g, rows, (j) => value(R.y_pred, j), (j) => value(R.y_sd, j), a, b, width, yOf);
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

// The expected value +- 2 sd as one filled area per stretch of rows that have it.
function band(g, rows, mean, sd, a, b, width, yOf) {
  g.fillStyle = "rgba(52, 120, 200, 0.18)";
  let stretch = [];
  const fill = () => {
    if (stretch.length) {
      g.beginPath();
      for (const j of stretch) g.lineTo(xOf(state.rows.t[j], a, b, width), yOf(mean(j) + 2 * sd(j)));
      for (const j of stretch.reverse()) g.lineTo(xOf(state.rows.t[j], a, b, width), yOf(mean(j) - 2 * sd(j)));
      g.fill();
    }
    stretch = [];
  };
  for (const j of rows) if (mean(j) === null || sd(j) === null) fill(); else stretch.push(j);
  fill();
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
function badge(text, kind) { return element("span", text, `badge ${kind.replace(", ", "-").replace(" ", "-")}`); }

function showAlarms(alarms) {
  state.alarms = alarms;
  const body = $("alarmlist");
  body.replaceChildren();
  $("noalarms").hidden = alarms.length > 0;
  for (const alarm of alarms) {
    const row = element("tr", null, alarm.state.replace(", ", "-"));
    row.dataset.alarm = alarm.id;
    if (alarm.id === state.selected) row.classList.add("selected");
    row.appendChild(element("td", alarm.id));
    for (const [t, time] of [[alarm.raised_t, alarm.raised_time], [alarm.cleared_t, alarm.cleared_time]]) {
      const cell = row.appendChild(element("td", t ? when(t, time) : "–"));
      if (t) cell.title = full(t, time);
    }
    row.appendChild(modeCell(alarm));
    const cell = element("td", null, "state");
    cell.appendChild(badge(alarm.state, alarm.state)).classList.add("what");
    const by = alarm.shelved ? `by ${alarm.shelved.who}: ${alarm.shelved.reason}`
                             : alarm.acknowledged ? `by ${alarm.acknowledged.who}` : "";
    if (by) cell.appendChild(element("span", by, "by"));
    cell.appendChild(actions(alarm));
    row.appendChild(cell);
    row.addEventListener("click", (event) => {
      if (event.target.tagName !== "BUTTON" && event.target.tagName !== "INPUT") select(alarm);
    });
    body.appendChild(row);
  }
}

// The mode an alarm was raised in and, while it is active, the mode the plant is in now if another.
function modeCell(alarm) {
  const cell = element("td", null, "mode");
  cell.appendChild(swatch(element("span", alarm.mode || "", "raised"), colour(alarm.mode)));
  const now = state.newest && state.newest.mode;
  if (alarm.cleared_t === null && now && now !== alarm.mode) {
    cell.appendChild(swatch(element("span", `now ${now}`, "now"), colour(now)));
  }
  return cell;
}

function actions(alarm) {
  const box = element("div", null, "act");
  if (!alarm.acknowledged) box.appendChild(button("Acknowledge", () => act(alarm, "acknowledge")));
  if (alarm.shelved) {
    box.appendChild(button("Unshelve", () => act(alarm, "unshelve")));
  } else {
    const reason = element("input");
    reason.placeholder = "reason";
    reason.className = "reason";
    box.appendChild(reason);
    box.appendChild(button("Shelve", () => act(alarm, "shelve", reason.value)));
  }
  return box;
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
  } else {
    box.appendChild(element("p", `log-likelihood ratio of ${found.mode} against the healthy modes, summed over ` +
                                  `${found.rows} row${found.rows === 1 ? "" : "s"} (nats): filled bars speak for ` +
                                  "it, outlined ones against it", "hint"));
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
      fill.style.setProperty("--swatch", colour(found.mode));
      track.appendChild(fill);
      bar.appendChild(track);
      bar.appendChild(element("span", output.nats.toFixed(1), "nats"));
      box.appendChild(bar);
    }
  }
  $("why").scrollIntoView({block: "nearest"});
}

// ------------------------------------------------------------------ a fleet's overview
// Every unit worst first (the server's order): what it needs attention for, its mode now, its open
// alarms; a unit's row opens its page. Looked at again every FLEET_POLL ms.
function overview(fleet) {
  $("unitview").hidden = $("now").hidden = $("live").hidden = true;
  $("fleetview").hidden = false;
  document.querySelector(".controls label").hidden = true;
  $("plant").textContent = [...new Set(fleet.units.map((u) => u.plant))].join(", ");
  $("source").textContent = `a fleet of ${fleet.units.length} units`;
  document.title = "fleet: jmlgdsl monitor";
  showFleet(fleet);
  setInterval(async () => {
    try {
      showFleet(await getJSON("api/fleet"));
    } catch (error) {
      $("status").textContent = `cannot read the fleet: ${error.message}`;
      $("status").className = "stale";
    }
  }, FLEET_POLL);
}

function showFleet(fleet) {
  const body = $("unitlist"), count = {};
  body.replaceChildren();
  const times = fleet.units.map((u) => u.time).filter(isClock);
  state.clock = times.length > 0;
  state.newest = state.clock ? {time: Math.max(...times)} : null;  // the day a time needs no date on
  for (const unit of fleet.units) {
    const need = (unit.attention || "with nothing to do").replace(",", "");
    count[need] = (count[need] || 0) + 1;
    const href = `?unit=${encodeURIComponent(unit.unit)}`;
    const row = element("tr", null, unit.attention ? unit.attention.replace(", ", "-").replace(" ", "-") : "fine");
    row.dataset.unit = unit.unit;
    const name = element("a", unit.unit);
    name.href = href;
    row.appendChild(element("td")).appendChild(name);
    const attention = row.appendChild(element("td", null, "attention"));
    if (unit.attention) attention.appendChild(badge(unit.attention, unit.attention));
    const mode = row.appendChild(element("td", null, "mode"));
    if (unit.mode !== null) {
      mode.appendChild(swatch(element("span", unit.mode), modeColour(unit.modes, unit.healthy, unit.mode)));
    }
    row.appendChild(element("td", unit.probability === null ? "" : unit.probability.toFixed(3), "p"));
    const open = row.appendChild(element("td", null, "alarms"));
    for (const alarm of unit.alarms.slice(0, 3)) {
      const item = open.appendChild(badge(`${alarm.mode || "alarm"} since ${when(alarm.raised_t, alarm.raised_time)}`,
                                          alarm.state));
      item.classList.add("alarm");
      item.title = `alarm ${alarm.id}, ${alarm.state}, raised at ${full(alarm.raised_t, alarm.raised_time)}`;
    }
    if (unit.alarms.length > 3) open.appendChild(element("span", `+${unit.alarms.length - 3} more`, "hint"));
    if (unit.shelved) open.appendChild(element("span", ` ${unit.shelved} shelved`, "hint"));
    row.appendChild(element("td", unit.t === null ? "no row yet" : when(unit.t, unit.time), "newest"))
      .title = unit.t === null ? "" : full(unit.t, unit.time);
    row.addEventListener("click", (event) => { if (event.target.tagName !== "A") location.search = href; });
    body.appendChild(row);
  }
  $("fleetsummary").textContent = `(${fleet.units.length} units: ` +
    Object.entries(count).map(([need, n]) => `${n} ${need}`).join(" · ") + ")";
  $("status").textContent = state.newest ? `newest row ${day(state.newest.time)} ${clockOf(state.newest.time)}` : "";
  $("status").title = state.newest ? zoneOf(state.newest.time) : "";
  $("status").className = "";
}

start().catch((error) => {
  $("status").textContent = `cannot load the page: ${error.message}`;
  $("status").className = "stale";
});
