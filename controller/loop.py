"""The controller's loop without I/O: what the Zenoh controller (controller/service.py), the in-process
runner (deploy/local/inprocess.py) and `hubctl replay` (deploy/replay/replay.py) each drive.

One step at a time, each in its order: measured values and the hubs' states in (`ingest`), a tick with
the watchdog's unhealthy resources and the held ones (`tick`: the engine, then the commands that
changed), the periodic resend of every command (`resend`), a plan request when one is due
(`plan_request`) and its answers (`adopt` the first, `improve` with a shorter one). At each, the run
recording hears what it took in and what was decided (controller/recording/hooks.py): since every shell goes
through here, a replay's records compare one to one with the recording's.

It owns no clock and no bus: `clock` is read once as each ingest and tick begins (the live controller's
`StepClock.advance`, a virtual clock elsewhere), and it returns the commands to send (the outbox's
`Command`s) and the events logged, for its shell to publish, print or only record.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from common.model import Value
from common.wire.ctl import ConsoleEvent, ConsoleReply, ConsoleRequest, HubAlive, HubGone, PlannedAlone
from controller.recording.hooks import ALL_HEALTHY, RunRecorder
from controller.recording.schema import HubState

from .control import ControlCore, PlanRequest
from .engine import TickResult
from .outbox import Command, CommandVariable, Outbox
from .outcome import RunOutcome
from .planner import NoPlan, Plan
from .requests import Requests

NOT_HELD: frozenset[str] = frozenset()


@dataclass(frozen=True)
class Ticked:
    """A tick's result, and the commands whose values it (or anything since the last send) changed."""

    result: TickResult
    commands: list[Command]


@dataclass(frozen=True)
class Adopted:
    """A plan answer handed to the core: whether it was taken, and the events the core logged for it."""

    taken: bool
    events: list[ConsoleEvent]


class ControlLoop:
    def __init__(self, core: ControlCore, recorder: RunRecorder, commanded: Iterable[str],
                 clock: Callable[[], float]) -> None:
        """`commanded`: the resources whose commands are sent (in the model's order, whichever order this is);
        `clock`: read as each step begins."""
        self.core = core
        self.recorder = recorder
        self.clock = clock
        model, index = core.model, core.compiled.index
        chosen = set(commanded)
        self.outbox = Outbox({r.name: [CommandVariable(v.name, v.path, index[v.path]) for v in r.commands]
                              for r in model.resources if r.name in chosen})

    # --- inputs -------------------------------------------------------------------------
    def request(self, operations: Sequence[str]) -> None:
        """The operations requested at start (persisted, or every one)."""
        self.core.request(*operations)
        self.recorder.requested(operations)

    def ingest(self, measured: Mapping[str, Value], hub_states: Sequence[HubState] = ()) -> dict[str, Value]:
        """Measured values (and each hub state's status and mirrored seq, for the recording); what changed."""
        self.clock()
        changed = self.core.ingest(measured) if measured else {}
        self.recorder.ingested(changed, hub_states)
        return changed

    def liveliness(self, hub: str, alive: bool) -> None:
        self.recorder.liveliness(hub, alive)
        self.core.events.log.emit(HubAlive(hub) if alive else HubGone(hub))

    def requests(self, *, persist: Callable[[list[str]], None] = lambda _: None,
                 wake: Callable[[], None] = lambda: None) -> Requests:
        """The console's requests, applied to this loop's core and recorded."""
        return Requests(self.core, persist=persist, wake=wake, answered=self._answered)

    def _answered(self, request: ConsoleRequest, reply: ConsoleReply) -> None:
        self.recorder.request(request, reply)

    # --- the tick and the commands ------------------------------------------------------
    def tick(self, unhealthy: Mapping[str, str] = ALL_HEALTHY, held: frozenset[str] = NOT_HELD) -> Ticked:
        """A tick with the watchdog's verdicts (resource -> why unhealthy) and the held resources disabled."""
        core = self.core
        self.clock()
        core.set_disabled(frozenset(unhealthy) | held)
        result = core.tick()
        self.recorder.ticked(unhealthy)
        return Ticked(result, self._recorded(self.outbox.changed(core.state, held)))

    def resend(self, held: frozenset[str] = NOT_HELD, resources: Iterable[str] | None = None) -> list[Command]:
        """Every command (of `resources`, if given) again, at the command rate: between ticks, so a value
        changed since the last tick (a mirror taken, a force) goes out with its new seq here."""
        return self._recorded(self.outbox.every(self.core.state, held, resources))

    def _recorded(self, commands: list[Command]) -> list[Command]:
        for command in commands:
            if command.changed:
                self.recorder.command(command.resource, command.seq)
        return commands

    # --- planning -----------------------------------------------------------------------
    def plan_request(self) -> PlanRequest | None:
        """A planning job, if one is due and none is under way."""
        request = self.core.plan_request()
        if request is not None:
            self.recorder.plan_request(request)
        return request

    def note(self, event: PlannedAlone) -> None:
        """The planner's note on an answer (a goal planned alone), logged before the answer is handed over."""
        self.core.events.log.emit(event)

    def adopt(self, request: PlanRequest, result: Plan | NoPlan | None, note: PlannedAlone | None = None) -> Adopted:
        """The first answer to `request`."""
        log = self.core.events.log
        cursor = log.total
        taken = self.core.adopt(request, result)
        self.recorder.plan(request, result, taken=taken, note=note)
        return Adopted(taken, log.since(cursor).events)

    def improve(self, request: PlanRequest, better: Plan) -> bool:
        """A shorter plan for `request`, after its first answer; True if taken."""
        taken = self.core.improve(request, better)
        self.recorder.plan(request, better, taken=taken, improvement=True)
        return taken

    def solve(self, request: PlanRequest) -> Adopted:
        """Plan `request` here and now, within the core's budget (virtual time: counts, not seconds)."""
        return self.adopt(request, self.core.solve(request))

    # --- the end ------------------------------------------------------------------------
    def finish(self, outcome: RunOutcome, note: str = "") -> None:
        self.recorder.finish(outcome, note)
