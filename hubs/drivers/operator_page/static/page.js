// The operator's page: renders what the hub pushes (server-sent events, /events) and sends the two
// things the page may do: press Confirm, call the supervisor. Every decision is the hub's (view.py).
"use strict";

const token = new URLSearchParams(window.location.search).get("token") || "";
const $ = (id) => document.getElementById(id);

function post(path, body) {
  const headers = { "Content-Type": "application/json" };
  if (token) headers["Authorization"] = "Bearer " + token;
  return fetch(path, { method: "POST", headers, body: body === undefined ? "" : JSON.stringify(body) })
    .then((response) => response.json().catch(() => ({ accepted: false, reason: response.statusText })))
    .then((answer) => { $("message").textContent = answer.reason || ""; return answer; })
    .catch(() => { $("message").textContent = "No connection to the station"; });
}

let view = null;

function render(next) {
  view = next;
  const who = $("operator");
  who.textContent = view.greeting || "";
  who.dataset.verified = String(view.verified);
  $("step").textContent = view.step ? `Step ${view.step} of ${view.steps}` : "";
  $("instruction").textContent = view.instruction;
  const picture = $("picture");
  if (view.picture) {
    if (picture.getAttribute("src") !== view.picture) picture.src = view.picture;
    picture.alt = view.task.replace(/_/g, " ");
    picture.hidden = false;
  } else {
    picture.hidden = true;
    picture.removeAttribute("src");
  }
  const robot = $("robot");
  robot.textContent = view.robot;
  robot.dataset.waits = String(view.robot_waits);
  const confirm = $("confirm");
  confirm.disabled = !view.can_confirm;
  confirm.textContent = view.done ? "Confirmed" : "Confirm";
  $("reason").textContent = view.can_confirm ? "" : view.reason;
  const call = $("call");
  call.dataset.called = String(view.supervisor_called);
  call.textContent = view.supervisor_called ? "Supervisor called" : "Call supervisor";
}

function connect() {
  const events = new EventSource("events");
  events.onopen = () => { $("connection").hidden = true; };
  events.onmessage = (event) => render(JSON.parse(event.data));
  events.onerror = () => { $("connection").hidden = false; };  // EventSource reconnects by itself
}

$("confirm").addEventListener("click", () => {
  post("api/confirm", view && view.task !== "none" ? { task: view.task } : undefined);
});
$("call").addEventListener("click", () => post("api/call-supervisor"));
connect();
