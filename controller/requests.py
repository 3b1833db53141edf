"""The console's requests at the controller: check one against the running station, apply it, say why not.

A console asks on `{station}/ctl/request` (a Zenoh query carrying a `ConsoleRequest`) and
gets one `ConsoleReply`: accepted, or refused with the reason. Every request and its
answer goes into the controller's event log. What each action means:

* **start** an operation: it is requested, and goes `executing` as soon as its precondition
  holds (the reply says which part of the precondition it waits for).
* **stop** an executing (or erroneous) operation, or a started one still waiting for its
  precondition: back to `initial`, no longer requested, and the current plan (made for its
  goal too) is dropped. Abilities already under way run to their end through their
  automatic transitions; nothing new is started for the operation.
* **reset** a finished (or erroneous) operation to `initial`, not requested: start it again
  to repeat it. What its finish recorded stays recorded.
* **pause** / **resume** automatic execution: while paused no deliberate transition fires
  (neither plan steps nor operation starts), but automatic transitions, tracking and
  operation finishes still follow the measured state, so a device that was started
  finishes and resets as its model says, and nothing is lost. Resuming plans afresh.
* **confirm**: the operator's confirm button (the smartwatch of the demonstrator). The
  operator's model (common/resources/operator.py) confirms task T by the measured
  `done_m` becoming true while `instr_c == T`; the automatic transition that then
  withdraws the instruction records what the operator did. The console stands in for
  the button: the controller holds `done_m` true until the instruction is withdrawn, then
  `done_m` is the hub's measurement again (an emulated operator that never confirmed
  reads false: the button is released). A confirmation the model would not allow yet
  (its `confirm_when`, e.g. the frame not seated) is refused with the unmet condition,
  so that the console never records work that was not done.
* **force** a variable to a value of its domain, and **unforce** it (undo). A forced
  variable holds its value whatever happens: a measured one ignores its hub, a command
  one is sent to its hub as forced, and no ability transition that writes it fires
  (a plan step that would waits). Unforcing gives the variable its own value back: a
  measured one the hub's newest measurement, an estimated or command one its value from
  before the force (nothing wrote it meanwhile). Operation states are not forced (start,
  stop and reset change them). Forces are not persisted: a restarted controller holds
  none, and what it persisted are the variables' own values. A force that would make one
  of the model's specifications hold in the current state is refused, naming it, unless the
  request says `override` (then it is applied and logged at WARNING with who asked);
  `controller/safety.py` then stops deliberate transitions until the state leaves it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from common.bus.protocol import Bus, Request
from common.model import Kind, OperationState, Value
from common.model.predicates import format_value
from common.resources.operator_confirm import condition_refusal, confirmation_effect, instruction_refusal, unmet
from common.wire.ctl import ACTIONS, ConsoleReply, ConsoleRequest, ReplanCause, ReplanReason, RequestAnswered
from common.wire.messages import MessageError, decode, encode

from .control import ControlCore

log = logging.getLogger("statehub.controller.requests")

OPERATOR_TYPE = "operator"


def refused(reason: str) -> ConsoleReply:
    return ConsoleReply(accepted=False, reason=reason)


def accepted(note: str = "") -> ConsoleReply:
    return ConsoleReply(accepted=True, reason=note)


def coerce(value: Value) -> Value:
    """A value typed as text (`true`, `3`) as the model's value; anything else unchanged."""
    if isinstance(value, str):
        if value in ("true", "false"):
            return value == "true"
        if value.lstrip("-").isdigit():
            return int(value)
    return value


class Requests:
    """Checks and applies console requests to a `ControlCore`.

    `persist(requested)` stores the requested operations (a restart keeps what the operator
    started); `wake()` asks the controller for a tick now rather than at its next period;
    `answered(request, reply)` is told every request and its answer.
    """

    def __init__(self, core: ControlCore, *, persist: Callable[[list[str]], None] = lambda _: None,
                 wake: Callable[[], None] = lambda: None,
                 answered: Callable[[ConsoleRequest, ConsoleReply], None] = lambda _request, _reply: None) -> None:
        self.core = core
        self.answered = answered  # after each request is applied (the run recording)
        self.model = core.model
        self.compiled = core.compiled
        self.persist = persist
        self.wake = wake
        self.operators = [r for r in self.model.resources if r.device_type == OPERATOR_TYPE]
        self._handlers: dict[str, Callable[[ConsoleRequest], ConsoleReply]] = {
            "pause": self._pause, "resume": self._resume, "confirm": self._confirm, "force": self._force,
            "unforce": self._unforce,
        }
        # Called with the operation's name and state, once it is known to exist.
        self._operation_handlers: dict[str, Callable[[str, OperationState], ConsoleReply]] = {
            "start": self._start, "stop": self._stop, "reset": self._reset,
        }

    # --- the bus side ---------------------------------------------------------------------
    async def serve(self, bus: Bus, key: str) -> None:
        """Answer requests on `key` until cancelled."""
        queryable = bus.declare_queryable(key, self.answer)
        try:
            await asyncio.get_running_loop().create_future()  # forever: cancelled with the controller
        finally:
            queryable.undeclare()

    async def answer(self, query: Request) -> bytes:
        if query.payload is None:
            return encode(refused("empty request: expected a ConsoleRequest"))
        try:
            request = decode(query.payload, ConsoleRequest)
        except MessageError as exc:
            log.warning("unreadable console request on %s: %s", query.key, exc)
            return encode(refused(f"unreadable request: {exc}"))
        return encode(self.apply(request))

    # --- the decisions --------------------------------------------------------------------
    def apply(self, request: ConsoleRequest) -> ConsoleReply:
        handler = self._handlers.get(request.action)
        on_operation = self._operation_handlers.get(request.action)
        if on_operation is not None:
            name = request.operation
            if name in self.core.op_index:
                reply = on_operation(name, self.core.op_state(name))
            else:
                reply = refused(f"no operation {name!r} in model {self.model.name}")
        elif handler is None:
            reply = refused(f"unknown action {request.action!r} (one of {', '.join(ACTIONS)})")
        else:
            reply = handler(request)
        event = RequestAnswered(request.describe(), reply.accepted, reply.reason, request.origin)
        self.core.events.log.emit(event)
        log.info("%s", event.text)
        self.answered(request, reply)
        if reply.accepted:
            self.wake()
        return reply

    def _start(self, name: str, state: OperationState) -> ConsoleReply:
        if state is OperationState.FINISHED:
            return refused(f"{name} is finished: reset it to run it again")
        if state is OperationState.EXECUTING:
            return refused(f"{name} is already executing")
        if state is OperationState.ERROR:
            return refused(f"{name} is in error ({self.core.error_text(name)}): stop or reset it first")
        operation = self.model.operation_by_name[name]
        waiting = unmet(operation.pre, self.compiled.unpack(self.core.state))
        if name in self.core.requested:
            return refused(f"{name} is already started and waits for its precondition: {waiting}")
        self.core.request(name)
        self.persist(list(self.core.requested))
        notes = [f"waits for its precondition: {waiting}"] if waiting else []
        if self.core.paused:
            notes.append("paused: it starts on resume")
        return accepted("; ".join(notes))

    def _stop(self, name: str, state: OperationState) -> ConsoleReply:
        if state is OperationState.FINISHED:
            return refused(f"{name} is finished: reset returns it to initial")
        if state is OperationState.INITIAL and name not in self.core.requested:
            return refused(f"{name} is not started")
        running = state is not OperationState.INITIAL
        self.core.withdraw(name, ReplanCause(ReplanReason.STOPPED_BY_OPERATOR, name) if running else None)
        self.persist(list(self.core.requested))
        return accepted("" if running else "it no longer waits to start")

    def _reset(self, name: str, state: OperationState) -> ConsoleReply:
        if state is OperationState.EXECUTING:
            return refused(f"{name} is executing: stop it first")
        if state is OperationState.INITIAL:
            return refused(f"{name} is already initial")
        in_error = state is OperationState.ERROR
        self.core.withdraw(name, ReplanCause(ReplanReason.RESET_BY_OPERATOR, name) if in_error else None)
        self.persist(list(self.core.requested))
        return accepted()

    def _pause(self, _request: ConsoleRequest) -> ConsoleReply:
        if self.core.paused:
            return refused("already paused")
        self.core.pause()
        return accepted()

    def _resume(self, _request: ConsoleRequest) -> ConsoleReply:
        if not self.core.paused:
            return refused("not paused")
        self.core.resume()
        return accepted()

    def _confirm(self, request: ConsoleRequest) -> ConsoleReply:
        if not self.operators:
            return refused(f"model {self.model.name} has no operator resource")
        core = self.core
        values = self.compiled.unpack(core.state)
        if request.resource:
            chosen = [r for r in self.operators if r.name == request.resource]
            if not chosen:
                names = ", ".join(r.name for r in self.operators)
                return refused(f"{request.resource!r} is not an operator (operators: {names})")
        else:
            chosen = [r for r in self.operators if values[f"{r.name}.instr_c"] != "none"] or self.operators[:1]
            if len(chosen) > 1:
                names = ", ".join(r.name for r in chosen)
                return refused(f"several operators have an instruction ({names}): name the one who confirms")
        name = chosen[0].name
        instr_path, done_path = f"{name}.instr_c", f"{name}.done_m"
        task = values[instr_path]
        refusal = instruction_refusal(name, task, values[done_path])
        if refusal is not None:
            return refused(refusal)
        if name in core.disabled:
            return refused(f"{name} is unhealthy: its confirmation could not be followed now")
        confirmation = self.compiled.by_name[confirmation_effect(name, str(task))]
        if not confirmation.guard(core.state):
            refusal = condition_refusal(name, str(task), self.compiled.guard_of(confirmation.source), values)
            return refused(refusal or f"{name} cannot confirm {task} yet")
        instr = self.compiled.index[instr_path]
        core.force(done_path, True, until=lambda state: state[instr] != task)
        return accepted(f"{name} confirmed {task}")

    def _variable(self, path: str) -> Kind | ConsoleReply:
        variable = self.model.variables.get(path)
        if variable is None:
            return refused(f"no variable {path!r} in model {self.model.name}")
        if path.startswith("op.") and path[3:] in self.core.op_index:
            return refused(f"{path} is the state of an operation: start, stop or reset it instead")
        return variable.kind

    def _force(self, request: ConsoleRequest) -> ConsoleReply:
        path = request.path
        kind = self._variable(path)
        if isinstance(kind, ConsoleReply):
            return kind
        if request.value is None:
            return refused(f"force {path}: no value given")
        value = coerce(request.value)
        domain = self.model.variables[path].domain
        if value not in domain:
            return refused(f"{request.value!r} is outside the domain of {path} ({domain.describe()})")
        forbidden = self.core.safety.made_to_hold(self.core.state, {path: value}, self.core.unknown)
        if forbidden:
            what = "; ".join(v.describe() for v in forbidden)
            if not request.override:
                return refused(f"{path} := {format_value(value)} would make specification {what} hold "
                               "(override to force it anyway)")
            log.warning("override by %s: %s makes specification %s hold", request.origin or "an unnamed console",
                        request.describe(), what)
        self.core.force(path, value)
        return accepted({Kind.MEASURED: "its hub's measurement is ignored until unforced",
                         Kind.COMMAND: "sent to its hub as forced; transitions writing it wait",
                         Kind.ESTIMATED: "transitions writing it wait until unforced"}[kind])

    def _unforce(self, request: ConsoleRequest) -> ConsoleReply:
        path = request.path
        kind = self._variable(path)
        if isinstance(kind, ConsoleReply):
            return kind
        if not self.core.unforce(path):
            return refused(f"{path} is not forced")
        own = self.core.state[self.compiled.index[path]]
        return accepted(f"{path} is {format_value(own)} again")
