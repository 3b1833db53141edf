// The line's site view: draws the SitePicture the server sends on /events (controller/overview/site.py).
// Read-only: this script only listens; it never sends anything to the server but the one GET of its stream.
"use strict";

function cell(row, text, title) {
  const td = document.createElement("td");
  td.textContent = text;
  if (title) td.title = title;
  row.appendChild(td);
  return td;
}

function carriedText(carried) {
  const names = Object.keys(carried).sort();
  return names.length ? names.length + (names.length === 1 ? " value" : " values") : "-";
}

function drawSite(p) {
  document.getElementById("station").textContent = "line " + p.line;
  const headline = document.getElementById("headline");
  headline.textContent = p.unreachable.length ? "unreachable: " + p.unreachable.join(", ") : p.headline;
  headline.className = p.unreachable.length ? "alarm" : "";
  document.getElementById("counters").textContent = p.unreachable.length ? p.headline : "";
  document.getElementById("stations-count").textContent = p.stations.length + " stations";
  document.title = (p.unreachable.length ? "(" + p.unreachable.length + ") " : "") + "line " + p.line;
  const rows = p.stations.map((s) => {
    const tr = document.createElement("tr");
    tr.dataset.station = s.station;
    tr.dataset.state = s.state;
    tr.className = s.severity === "normal" ? s.state : s.severity;
    cell(tr, s.station);
    cell(tr, s.state);
    cell(tr, s.product || "-");
    cell(tr, s.cycle_s === null ? "-" : s.cycle_s.toFixed(1) + " s");
    cell(tr, String(s.done));
    cell(tr, s.unhealthy.length ? "unhealthy: " + s.unhealthy.join(", ") : "ok");
    const carried = Object.keys(s.carried).sort().map((k) => k + "=" + s.carried[k]).join(" ");
    cell(tr, carriedText(s.carried), carried);
    return tr;
  });
  document.querySelector("#stations tbody").replaceChildren(...rows);
}

function connect() {
  const events = new EventSource("/events");
  events.addEventListener("site", (e) => drawSite(JSON.parse(e.data)));
  events.onerror = () => {
    const headline = document.getElementById("headline");
    headline.textContent = "the overview is not answering: reconnecting ...";
    headline.className = "alarm";
  };
}

connect();
