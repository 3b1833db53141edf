// The overview page: draws what the server sends on /events (controller/overview/picture.py's Picture and
// Gantt, as JSON). Read-only: this script only listens; it never sends anything to the server but the one
// GET of its event stream.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const NAME_W = 160, LANE_H = 13, AXIS_H = 18, RIGHT_PAD = 12;
const ABILITY_FILL = { done: "#8c8c8c", running: "#4d4d4d", aborted: "#f0b400" };
const OPERATION_FILL = { executing: "#4d4d4d", finished: "#b0b0b0", error: "#d21f1f" };
let lastGantt = null;

function cell(row, text, title) {
  const td = document.createElement("td");
  td.textContent = text;
  if (title) td.title = title;
  row.appendChild(td);
  return td;
}

function fill(tbodySelector, items, makeRow) {
  const tbody = document.querySelector(tbodySelector);
  const rows = items.map(makeRow);
  tbody.replaceChildren(...rows);
}

function drawPicture(p) {
  document.getElementById("station").textContent = p.station;
  const headline = document.getElementById("headline");
  headline.textContent = p.headline;
  headline.className = p.severity === "normal" ? "" : p.severity;
  document.getElementById("production").textContent = p.production;
  document.getElementById("counters").textContent = p.counters;
  document.title = (p.alarms ? "(" + p.alarms + ") " : "") + p.station + " overview";

  fill("#operations tbody", p.operations, (op) => {
    const tr = document.createElement("tr");
    tr.dataset.name = op.name;
    tr.dataset.state = op.state;
    tr.className = op.severity === "normal" ? op.state : op.severity;
    cell(tr, op.name);
    cell(tr, op.state).className = "state";
    cell(tr, op.in_state);
    cell(tr, op.error || op.goal, op.error || op.goal);
    return tr;
  });
  const counts = {};
  for (const op of p.operations) counts[op.state] = (counts[op.state] || 0) + 1;
  document.getElementById("operations-count").textContent =
    Object.entries(counts).map(([state, n]) => n + " " + state).join(", ");

  fill("#resources tbody", p.resources, (r) => {
    const tr = document.createElement("tr");
    tr.dataset.resource = r.resource;
    tr.className = r.severity;
    cell(tr, r.resource);
    cell(tr, r.hub);
    cell(tr, r.mode);
    cell(tr, r.health, r.health).className = "health";
    cell(tr, r.age);
    cell(tr, r.mirror);
    return tr;
  });

  document.getElementById("plan-summary").textContent = p.plan.summary;
  fill("#plan tbody", p.plan.steps, (s) => {
    const tr = document.createElement("tr");
    tr.className = s.done ? "done" : "pending";
    cell(tr, String(s.number));
    cell(tr, s.done ? "\u2714" : "\u00b7");
    cell(tr, s.transition, s.transition).className = "step";
    cell(tr, s.kind);
    cell(tr, s.waits_for, s.waits_for).className = "waits";
    return tr;
  });

  fill("#events", p.events.slice().reverse(), (e) => {  // newest first: what just happened is on top
    const li = document.createElement("li");
    li.textContent = e.text;
    li.title = e.text;
    if (e.severity !== "normal") li.className = e.severity;
    return li;
  });
}

function el(name, attrs, parent, text) {
  const node = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  if (parent) parent.appendChild(node);
  return node;
}

function tip(node, text) {
  el("title", {}, node, text);
  return node;
}

function niceStep(seconds, pixels) {
  const wanted = seconds / Math.max(1, pixels / 70);
  for (const step of [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 1200, 1800, 3600]) if (step >= wanted) return step;
  return 7200;
}

function drawGantt(g) {
  lastGantt = g;
  const box = document.getElementById("gantt");
  const summary = document.getElementById("gantt-summary");
  if (!g.run) {
    summary.textContent = "";
    const svg = el("svg", { width: 600, height: 24 });
    el("text", { x: 8, y: 16, class: "note" }, svg, g.note);
    box.replaceChildren(svg);
    return;
  }
  const spans = g.abilities.length + g.operations.length;
  summary.textContent = "run " + g.run + ", " + g.end.toFixed(0) + " s, " + spans + " spans, " +
    g.markers.filter((m) => m.kind !== "fault").length + " plans" + (g.note ? "; " + g.note : "");
  summary.dataset.end = String(g.end);
  summary.dataset.spans = String(spans);
  const width = Math.max(400, box.clientWidth - 2);
  const height = AXIS_H + LANE_H * g.lanes.length + 4;
  const x0 = NAME_W, span = width - NAME_W - RIGHT_PAD, end = Math.max(g.end, 1);
  const x = (t) => x0 + (t / end) * span;
  const y = (lane) => AXIS_H + lane * LANE_H;
  const svg = el("svg", { width: width, height: height, role: "img", "aria-label": "Gantt chart of the run" });
  g.lanes.forEach((name, i) => {
    if (i % 2 === 0) el("rect", { x: 0, y: y(i), width: width, height: LANE_H, fill: "#dddddd" }, svg);
    el("text", { x: 4, y: y(i) + LANE_H - 3, class: "lane-name" }, svg, name.length > 24 ? name.slice(0, 23) + "\u2026" : name);
  });
  if (g.resources > 0 && g.resources < g.lanes.length)
    el("line", { x1: 0, x2: width, y1: y(g.resources), y2: y(g.resources), stroke: "#9a9a9a" }, svg);
  const step = niceStep(end, span);
  for (let t = 0; t <= end; t += step) {
    el("line", { x1: x(t), x2: x(t), y1: AXIS_H - 4, y2: height, stroke: "#c4c4c4" }, svg);
    el("text", { x: x(t) + 2, y: 10 }, svg, t + " s");
  }
  for (const [lane, label, start, stop, reason] of g.unhealthy)
    tip(el("rect", { x: x(start), y: y(lane), width: Math.max(1, x(stop) - x(start)), height: LANE_H,
      fill: "#d21f1f", "fill-opacity": 0.35, class: "unhealthy" }, svg), label + ": " + reason);
  const bar = (lane, label, start, stop, outcome, colours, pad, title) =>
    tip(el("rect", { x: x(start), y: y(lane) + pad, width: Math.max(1.5, x(stop) - x(start)),
      height: LANE_H - 2 * pad, fill: colours[outcome] || "#777777", class: "span " + outcome }, svg), title);
  for (const [lane, label, start, stop, outcome] of g.abilities)
    bar(lane, label, start, stop, outcome, ABILITY_FILL, 2,
      g.lanes[lane] + "." + label + " " + outcome + ": " + start.toFixed(1) + "-" + stop.toFixed(1) + " s");
  for (const [lane, label, start, stop, outcome] of g.operations)
    bar(lane, label, start, stop, outcome, OPERATION_FILL, 3,
      g.lanes[lane] + " " + outcome + ": " + start.toFixed(1) + "-" + stop.toFixed(1) + " s");
  g.markers.forEach(([t, kind, text, lane]) => {
    if (kind === "fault") {
      const top = lane >= 0 ? y(lane) : AXIS_H, bottom = lane >= 0 ? y(lane) + LANE_H : height;
      tip(el("line", { x1: x(t), x2: x(t), y1: top, y2: bottom, stroke: "#d21f1f", "stroke-width": 2,
        class: "fault" }, svg), t.toFixed(1) + " s fault: " + text);
    } else {
      tip(el("line", { x1: x(t), x2: x(t), y1: AXIS_H - 6, y2: height, stroke: "#7a7a7a",
        "stroke-dasharray": kind === "replan" ? "2,3" : "", class: "plan" }, svg), t.toFixed(1) + " s " + kind + ": " + text);
    }
  });
  box.replaceChildren(svg);
}

function connect() {
  const source = new EventSource("/events");
  source.addEventListener("picture", (e) => drawPicture(JSON.parse(e.data)));
  source.addEventListener("gantt", (e) => drawGantt(JSON.parse(e.data)));
  source.onerror = () => {
    const headline = document.getElementById("headline");
    headline.textContent = "the overview server does not answer: reconnecting ...";
    headline.className = "alarm";
  };
}

window.addEventListener("resize", () => { if (lastGantt) drawGantt(lastGantt); });
connect();
