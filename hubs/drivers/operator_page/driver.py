"""The operator's device in mode `real`: the operator's page (and its pushbutton) is the operator.

To the hub it is a driver like any other: `write` takes `instr_c` (the instruction shown), `read` gives
`done_m` (the button). The page shows who is verified (the badge reader's `verified_m`, which the hub
follows for it, and the name where the reader runs in this hub), the instruction of the station's table
with its picture and step, what the robot does, and the Confirm button, enabled only while the model's
confirm condition holds on what the hub sees (the variables the condition reads are this driver's
`Inputs`: measured ones from their hubs' states, estimated ones from the controller's state snapshots).

Safe state: the instruction withdrawn (`instr_c = none`), which releases the button."""

from __future__ import annotations

import asyncio
import logging
import ssl
from collections.abc import Mapping
from pathlib import Path

from common.config.modes import SecurityMode
from common.config.security import SecurityError, cert_dir, identity_of, tls_files
from common.model import Value
from common.resources.operator import NO_TASK
from common.stations.instructions import InstructionTable, load_instructions
from hubs.drivers import badge_readers
from hubs.drivers.base import (
    CallsSupervisor,
    Driver,
    Inputs,
    InStation,
    Observes,
    SelftestReport,
    StationContext,
)
from hubs.drivers.nutrunner_mcp23017 import BusFactory, default_bus_factory, parse_pin

from .button import OperatorButton
from .params import OperatorPageParams
from .pushbutton import Pushbutton
from .server import PageServer, PressOutcome, Refusal
from .tokens import DeviceTokens
from .view import Badge, PageView, page_view

log = logging.getLogger(__name__)

OPERATOR_TYPE = "operator"


class OperatorPage(Driver, Inputs, Observes, InStation, CallsSupervisor):
    def __init__(self, resource: str, params: OperatorPageParams, *, button_bus: BusFactory | None = None) -> None:
        self.resource = resource
        self.params = params
        self.table: InstructionTable | None = load_instructions(params.instructions) if params.instructions else None
        self.language = params.language or (self.table.languages[0] if self.table and self.table.languages else "")
        self.tokens = DeviceTokens(params.tokens)
        self.button: OperatorButton | None = None
        self.pushbutton: Pushbutton | None = None
        if params.button is not None:
            wired = params.button
            self.pushbutton = Pushbutton(button_bus or default_bus_factory(wired.bus), wired.address,
                                         parse_pin(wired.pin), active_low=wired.active_low, poll_s=wired.poll_s,
                                         on_press=lambda: self._pressed_by("pushbutton"))
        self.supervisor_called = False
        self._calls: asyncio.Queue[bool] = asyncio.Queue()  # the call began (True) or ended, for the hub
        self._changed = asyncio.Event()
        self._tls: ssl.SSLContext | None = None
        self._watched: dict[str, Value] = {}  # the badge reader's and the robot's variables
        self.server: PageServer | None = None

    # --- the station ---------------------------------------------------------------------------
    def join_station(self, station: StationContext) -> None:
        model = station.model
        spec = model.resource_by_name.get(self.resource)
        if spec is None or spec.device_type != OPERATOR_TYPE:
            raise ValueError(f"the operator page serves a resource of type {OPERATOR_TYPE!r}; "
                             f"{self.resource!r} is not one in model {model.name}")
        self.button = OperatorButton(model, self.resource, self._notify)
        for resource, names in ((self.params.badge_reader, ("verified_m",)),
                                (self.params.robot, ("pos_m", "prot_stop_m"))):
            if not resource:
                continue
            if resource not in model.resource_by_name:
                raise ValueError(f"{self.resource}: no resource {resource!r} in model {model.name}")
            for name in names:
                path = f"{resource}.{name}"
                if path in model.variables:
                    self._watched[path] = model.var(path).initial
        if self.table is not None:
            missing = self.table.missing(self.button.tasks)
            if missing:
                log.warning("%s: the instruction table %s has no instruction for %s: the page shows the task's "
                            "name", self.resource, self.params.instructions, ", ".join(missing))
        if station.config.security.mode == SecurityMode.TLS:
            self._tls = _tls_context(station)

    def _model_button(self) -> OperatorButton:
        if self.button is None:
            raise RuntimeError(f"{self.resource}: the operator page was not told its station (join_station)")
        return self.button

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(sorted({*self._model_button().condition_paths, *self._watched}))

    def observe(self, values: Mapping[str, Value], published_at: float | None = None) -> None:
        self._model_button().observe(values)
        changed = False
        for path in self._watched:
            if path in values and values[path] != self._watched[path]:
                self._watched[path] = values[path]
                changed = True
        if changed:
            self._notify()

    # --- Driver --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.server is not None and self.server.bound is not None

    async def connect(self) -> None:
        self._model_button()
        if self.server is None:
            server = PageServer(self, self.tokens, self.params.host, self.params.port, self._tls)
            await server.start()  # a port in use fails the hub's start: nothing else would serve the page
            self.server = server
        if self.pushbutton is not None:
            self.pushbutton.start()

    async def close(self) -> None:
        if self.pushbutton is not None:
            await self.pushbutton.stop()
        server, self.server = self.server, None
        if server is not None:
            await server.stop()

    async def read(self) -> Mapping[str, Value]:
        return {"done_m": self._model_button().done}

    async def write(self, commands: Mapping[str, Value]) -> None:
        button = self._model_button()
        if "instr_c" in commands and commands["instr_c"] != button.instruction:
            if self.supervisor_called:  # the station moved on: the call was answered
                self.supervisor_called = False
                self._calls.put_nowait(False)
            button.command(commands["instr_c"])

    async def enter_safe_state(self) -> Mapping[str, Value]:
        self._model_button().command(NO_TASK)
        return {"instr_c": NO_TASK}

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        report.add("device answers", self.connected,
                   f"page on {self.server.url}" if self.server is not None else "page not served")
        if self.pushbutton is None:
            report.add("inputs read", True, "the page's button (no pushbutton configured)")
        else:
            await asyncio.sleep(3 * self.pushbutton.poll_s)  # one poll at least
            level = "pressed" if self.pushbutton.pressed else "released"
            report.add("inputs read", self.pushbutton.answering, self.pushbutton.last_error or f"pushbutton {level}")
        report.add("outputs read back", True, f"instruction shown: {self._model_button().instruction}")
        return report

    # --- the page ------------------------------------------------------------------------------
    def _notify(self) -> None:
        self._changed.set()
        self._changed = asyncio.Event()

    async def changed(self, timeout: float) -> None:
        try:
            await asyncio.wait_for(self._changed.wait(), timeout)
        except TimeoutError:
            return

    def badge(self) -> Badge:
        reader = self.params.badge_reader
        if not reader:
            return Badge(None)
        verified = bool(self._watched.get(f"{reader}.verified_m"))
        local = badge_readers.find(reader)
        name = (local.operator or "") if local is not None and verified else ""
        return Badge(verified, name)

    def view(self) -> PageView:
        button = self._model_button()
        return page_view(resource=self.resource, values={**button.values, **self._watched},
                         refusal=button.refusal(), badge=self.badge(), table=self.table, language=self.language,
                         robot=self.params.robot, supervisor_called=self.supervisor_called)

    def picture(self, task: str) -> Path | None:
        found = self.table.step_of(task) if self.table is not None else None
        return found[1].picture if found is not None else None

    def press(self, device: str, task: str | None) -> PressOutcome:
        button = self._model_button()
        if task is not None and task not in button.tasks:
            return PressOutcome(False, f"unknown task {task!r} (tasks of {self.resource}: "
                                       f"{', '.join(button.tasks)})", Refusal.UNKNOWN_TASK)
        if task is not None and task != button.instruction:
            return PressOutcome(False, f"{task} is not the instruction standing ({button.instruction})",
                                Refusal.NOT_STANDING)
        refusal = button.press()
        if refusal is not None:
            log.info("%s: press from %s refused: %s", self.resource, device, refusal)
            return PressOutcome(False, refusal, Refusal.CANNOT_CONFIRM)
        log.info("%s: %s confirmed by %s", self.resource, button.instruction, device)
        return PressOutcome(True, f"{self.resource} confirmed {button.instruction}")

    def _pressed_by(self, device: str) -> None:
        self.press(device, None)

    def call_supervisor(self, device: str) -> None:
        log.warning("%s: the operator calls the supervisor (from %s)", self.resource, device)
        if not self.supervisor_called:
            self.supervisor_called = True
            self._calls.put_nowait(True)
        self._notify()

    async def next_call(self) -> bool:
        return await self._calls.get()


def _tls_context(station: StationContext) -> ssl.SSLContext:
    """The hub's own certificate, issued by the station's CA: a tablet that trusts the CA trusts the page."""
    try:
        files = tls_files(cert_dir(station.config, station.certs), identity_of(station.config, station.hub))
    except SecurityError as exc:
        raise ValueError(f"the operator page is served over TLS in mode 'tls': {exc}") from exc
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.load_cert_chain(files.certificate, files.private_key)
    return context


def build(resource: str, params: OperatorPageParams) -> OperatorPage:
    return OperatorPage(resource, params)
