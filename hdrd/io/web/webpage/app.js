// hdrd web: the live page. Reads the server's event stream (/events) and shows the latest
// message. Every value from a message is checked for its type and shown with textContent:
// nothing from a datagram is ever parsed as markup. No build step, no library.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const STALE_MIN_S = 3; // "no data" after this long without a message (or 3 intervals)
const HISTORY_S = 600;
const TRACE_STEP_S = 0.5;

const MODES = {
  // data-mode: [the word shown, what it means]
  calibrating: ["calibrating", "measuring the bias: keep the vehicle still"],
  ok: ["ok", "heading from the gyro"],
  aided: ["aided", "aligned to the GPS course"],
  "dead-reckoning": ["dead-reckoning", "GPS not usable: carried by the gyro"],
  stale: ["stale", "no data from the gyro: the heading is held"],
  unknown: ["unknown", "status not understood: the rate is not trusted"],
  nodata: ["no data", "nothing received lately (see above)"],
  none: ["waiting", "no message received yet"],
};
const BIAS_SOURCES = {
  calibration: "calibration",
  stops: "learned at stops",
  driving: "learned while driving",
  gps: "learned from GPS",
};

const state = {
  offset: 0, // server clock minus this page's clock, s
  lastRx: null, // server time of the last message, s
  interval: 1, // seconds between messages, smoothed
  connected: false,
  udp: "",
  trace: [],
  angle: null, // the needle's angle, unwrapped (it turns the short way round)
};

const $ = (id) => document.getElementById(id);
const num = (v) => (typeof v === "number" && Number.isFinite(v) ? v : null);
const str = (v) => (typeof v === "string" ? (v.length > 200 ? v.slice(0, 199) + "\u2026" : v) : null);
const serverNow = () => Date.now() / 1000 + state.offset;
const wrap180 = (d) => ((((d + 180) % 360) + 360) % 360) - 180;
// A compass heading or course, deg: a finite number in [0, 360], else null (not a heading: it
// is never drawn, and the needle's unwrapped angle never leaves the range a float keeps exact).
const compass = (v) => (typeof v === "number" && v >= 0 && v <= 360 ? v : null);
// A compass heading as text: rounded first, then wrapped (359.96 is "0.0", as hdrd tail and
// NMEA write it, never "360.0").
const compassText = (d, digits) => {
  const r = Number(d.toFixed(digits));
  return (r >= 360 ? r - 360 : r).toFixed(digits);
};

function setText(id, text) {
  const el = $(id);
  if (el.textContent !== text) el.textContent = text;
}

function clock(t) {
  return new Date(t * 1000).toLocaleTimeString([], { hour12: false });
}

function age(s) {
  if (s === null) return "\u2013";
  if (s < 60) return `${s.toFixed(0)} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${Math.floor(s % 60)} s`;
  if (s < 86400) return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
  return `${Math.floor(s / 86400)} d ${Math.floor((s % 86400) / 3600)} h`;
}

function fixed(v, digits, unit) {
  return v === null ? "\u2013" : `${v.toFixed(digits)}${unit}`;
}

// -- the dial --------------------------------------------------------------------------------

function drawTicks() {
  const g = $("ticks");
  for (let d = 0; d < 360; d += 10) {
    const major = d % 30 === 0;
    const a = (d * Math.PI) / 180;
    const line = document.createElementNS(SVG, "line");
    const r0 = major ? 88 : 94;
    line.setAttribute("x1", (Math.sin(a) * r0).toFixed(2));
    line.setAttribute("y1", (-Math.cos(a) * r0).toFixed(2));
    line.setAttribute("x2", (Math.sin(a) * 102).toFixed(2));
    line.setAttribute("y2", (-Math.cos(a) * 102).toFixed(2));
    line.setAttribute("class", major ? "tick major" : "tick");
    g.appendChild(line);
    if (major) {
      const names = { 0: "N", 90: "E", 180: "S", 270: "W" };
      const text = document.createElementNS(SVG, "text");
      text.setAttribute("x", (Math.sin(a) * 77).toFixed(2));
      text.setAttribute("y", (-Math.cos(a) * 77).toFixed(2));
      text.setAttribute("class", d in names ? "label cardinal" : "label");
      text.textContent = d in names ? names[d] : String(d);
      g.appendChild(text);
    }
  }
}

function setNeedle(heading) {
  const dial = $("dial");
  if (heading === null) {
    dial.removeAttribute("data-heading");
    return;
  }
  state.angle = state.angle === null ? heading : state.angle + wrap180(heading - state.angle);
  const needle = $("needle");
  // eased over at most the time to the next message, so a fast stream never leaves it behind
  needle.style.transitionDuration = `${Math.min(0.4, 0.8 * state.interval).toFixed(3)}s`;
  needle.style.transform = `rotate(${state.angle.toFixed(2)}deg)`;
  dial.setAttribute("data-heading", compassText(heading, 2));
}

// -- the message -----------------------------------------------------------------------------

function modeOf(msg) {
  const status = str(msg.status);
  if (status === "calibrating" || status === "stale") return status;
  const mode = str(msg.mode);
  if (mode === "aided" || mode === "dead-reckoning") return mode;
  if (status === "ok" || status === "turning" || status === "standstill") return "ok";
  return "unknown";
}

function showMode(mode) {
  document.body.setAttribute("data-mode", mode);
  setText("mode", MODES[mode][0]);
  setText("mode-why", MODES[mode][1]);
}

function show(msg, rx) {
  const heading = compass(msg.heading);
  setText("heading", heading === null ? "\u2013" : compassText(heading, 1));
  const headingSd = num(msg.heading_sd);  // how well the heading is known, deg (1 sigma)
  setText("heading-sd", heading === null || headingSd === null || headingSd < 0 ? "" : ` \u00b1 ${headingSd.toFixed(1)}`);
  setNeedle(heading);
  showMode(modeOf(msg));
  const omega = num(msg.omega);
  const turn = omega === null || omega === 0 ? "" : omega > 0 ? " (left)" : " (right)";
  setText("omega", omega === null ? "\u2013" : `${omega.toFixed(2)} deg/s${turn}`);
  setText("status", str(msg.status) ?? "\u2013");
  setText("step", num(msg.step) === null ? "\u2013" : String(msg.step));
  setText("last", clock(rx));
  setText("bias", fixed(num(msg.bias), 4, " deg/s") + sd(num(msg.bias_sd)));
  const source = str(msg.bias_source);
  setText("bias-source", source === null ? "\u2013" : (BIAS_SOURCES[source] ?? source));
  const cal = num(msg.calib_age_s);
  setText("calib-age", cal === null ? "\u2013" : `${age(cal)} ago`);
  setText("model", str(msg.model) ?? "\u2013");
  showGps(msg);
  setText("frames", count(msg.frames));
  setText("bad-frames", count(msg.bad_frames));
  setText("reconnects", count(msg.reconnects));
}

function sd(v) {
  return v === null ? "" : ` \u00b1 ${v.toFixed(4)}`;
}

function count(v) {
  return num(v) === null ? "\u2013" : String(v);
}

function showGps(msg) {
  if (str(msg.mode) === null) {
    setText("gps", "no GPS aiding (hdrd run --gpsd)");
    setText("gps-age", "\u2013");
    return;
  }
  const course = compass(msg.gps_course);
  const speed = num(msg.gps_speed);
  const at = speed === null ? "" : ` at ${speed.toFixed(1)} m/s`;
  setText("gps", course === null ? "not in use" + at : `${compassText(course, 1)}\u00b0${at}`);
  const a = num(msg.gps_age_s);
  setText("gps-age", a === null ? "none received" : `${age(a)} ago`);
}

// -- the trace -------------------------------------------------------------------------------

function addPoint(p) {
  const t = state.trace;
  if (t.length && p[0] < t[t.length - 1][0]) t.length = 0;
  if (t.length && p[0] - t[t.length - 1][0] < TRACE_STEP_S) return;
  t.push(p);
  while (t.length && p[0] - t[0][0] > HISTORY_S) t.shift();
}

function drawTrace(id, scaleId, column, unit, floor) {
  const now = serverNow();
  let span = floor;
  for (const p of state.trace) {
    const v = num(p[column]);
    if (v !== null && now - p[0] <= HISTORY_S) span = Math.max(span, Math.abs(v));
  }
  let d = "";
  let pen = "M";
  for (const p of state.trace) {
    const v = num(p[column]);
    const x = HISTORY_S - (now - p[0]);
    if (v === null || x < 0) {
      pen = "M";
      continue;
    }
    d += `${pen}${x.toFixed(1)} ${(50 - (v / span) * 48).toFixed(2)} `;
    pen = "L";
  }
  $(id).querySelector(".line").setAttribute("d", d.trim());
  setText(scaleId, `(\u00b1${span.toPrecision(2)} ${unit})`);
}

// -- the stream ------------------------------------------------------------------------------

function parse(e) {
  try {
    const v = JSON.parse(e.data);
    return v !== null && typeof v === "object" ? v : null;
  } catch {
    return null;
  }
}

function onHello(e) {
  const hello = parse(e);
  if (hello === null) return;
  const now = num(hello.now);
  state.offset = now === null ? 0 : now - Date.now() / 1000;
  state.udp = str(hello.udp) ?? "";
  state.trace = [];
  state.lastRx = null;
  const version = str(hello.version);
  setText("source", `hdrd web${version ? " " + version : ""}: data from UDP ${state.udp}`);
}

function onHistory(e) {
  const h = parse(e);
  if (h === null || !Array.isArray(h.points)) return;
  for (const p of h.points) {
    if (Array.isArray(p) && num(p[0]) !== null) addPoint(p);
  }
}

function onMessage(e) {
  const m = parse(e);
  if (m === null || num(m.rx) === null || m.msg === null || typeof m.msg !== "object") return;
  if (state.lastRx !== null && m.rx > state.lastRx) {
    state.interval = 0.8 * state.interval + 0.2 * Math.min(m.rx - state.lastRx, 60);
  }
  state.lastRx = m.rx;
  show(m.msg, m.rx);
  const heading = compass(m.msg.heading);
  const course = compass(m.msg.gps_course);
  const aided = m.msg.mode === "aided" && heading !== null && course !== null;
  addPoint([m.rx, num(m.msg.omega), aided ? wrap180(heading - course) : null]);
  tick();
}

function tick() {
  const quiet = state.lastRx === null ? null : serverNow() - state.lastRx;
  const limit = Math.max(STALE_MIN_S, 3 * state.interval);
  const banner = $("banner");
  if (quiet !== null && quiet <= limit && state.connected) {
    banner.hidden = true;
    document.body.classList.remove("nodata");
  } else {
    banner.hidden = false;
    document.body.classList.add("nodata");
    if (state.lastRx !== null) {
      setText("banner", `No data since ${clock(state.lastRx)}`);
    } else if (state.connected) {
      setText("banner", `No data yet: waiting for hdrd run --udp ${state.udp}`);
    } else {
      setText("banner", "No data yet: connecting to hdrd web");
    }
    showMode(state.lastRx === null ? "none" : "nodata");
  }
  drawTrace("trace-omega", "omega-scale", 1, "deg/s", 1);
  drawTrace("trace-dgps", "dgps-scale", 2, "deg", 2);
}

function connect() {
  const es = new EventSource("/events");
  es.addEventListener("open", () => {
    state.connected = true;
  });
  es.addEventListener("hello", onHello);
  es.addEventListener("history", onHistory);
  es.addEventListener("msg", onMessage);
  es.addEventListener("error", () => {
    state.connected = false;
    tick();
    if (es.readyState === EventSource.CLOSED) {
      // refused (too many viewers) or not an event stream: the browser gives up; we do not
      setTimeout(connect, 5000);
    }
  });
}

drawTicks();
showMode("none");
tick();
setInterval(tick, 500);
connect();
