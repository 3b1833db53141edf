"""The controller process: the control loop (controller/loop.py) on live state over Zenoh.

It is the composition of the loop's jobs around the `ControlLoop`: the intake of every hub's state
(controller/ingest.py: mirrors, forged seq, the watchdog, held resources), ticks on change and at its
tick rate, the outbox's commands published at once when they change and all of them at the command rate
(controller/commandpublisher.py), the planner off the event loop (controller/planclient.py), the status
(controller/statuspublisher.py), and the estimated variables and operation states persisted on every
change.

On start it restores what it persisted, waits (bounded) for every hub's mirror, takes
the command state from the mirrors, and goes on where it was; a resource whose mirror is
late is held, sent nothing, until it comes (controller/command_hold.py).

Orders (controller/production/): the order book lives in the same SQLite file. A fresh start queues the
run's `ProductionPlan`; the loop finishes and starts orders after each tick; `{station}/ctl/orders` is
answered on this event loop, the thread that owns the SQLite connection, and an order added wakes the loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import time
import uuid
from collections.abc import Iterable
from typing import Any

import msgspec

from common.bus.protocol import Bus
from common.config.hubs_toml import StationConfig
from common.config.modes import Execution
from common.config.production import ProductionPlan
from common.model import Kind, Model, Value
from common.plumbing.sdnotify import Notifier
from common.plumbing.tasks import cancel_and_wait
from common.resources import durations_of
from common.wire.messages import Codec
from controller.command_hold import CommandHold
from controller.recording.hooks import RunRecorder, StepClock, open_recording
from controller.recording.schema import RunMeta
from controller.station_hold import StationHold

from .commandpublisher import CommandPublisher
from .cycle import effect_seconds, shortest_seconds
from .ingest import StateIngest
from .loop import ControlLoop
from .loopmeter import LoopMeter
from .planclient import PlanClient
from .planworker import READY_WAIT_S, PlannerProcess, Timing
from .production.book import REQUESTED_META, OrderBook
from .production.flow import OrderFlow
from .production.service import OrdersService
from .recording.schema import RunOutcome
from .stack import build_controller_stack
from .state import StateStore
from .statuspublisher import StatusPublisher
from .watchdog import Watchdog

log = logging.getLogger("statehub.controller")

TASKS_END_S = 2.0  # for the loop's tasks to end once cancelled, before the state is saved and the hold released


class ControllerService:
    def __init__(self, config: StationConfig, model: Model, bus: Bus, *, db: str | None = None,
                 mirror_wait_s: float = 5.0, requested: Iterable[str] | None = None,
                 planner_process: bool = True, hold: bool = False, record: RunMeta | None = None,
                 production: ProductionPlan | None = None, execution: Execution | None = None,
                 speed: float = 1.0) -> None:
        """`production`: the orders to queue on a fresh start (a book that never had one); `execution`: the order
        plans run in (default: `[controller] execution` of hubs.toml); `speed`: the emulated devices run this many
        times faster than their durations (`hubctl up --speed`), and so do the controller's predictions, bounds and
        timed checks."""
        self.config = config
        self.speed = speed
        self.model = model
        self.bus = bus
        self.keys = config.keys
        self.controller_id = f"{config.controller.name}-{uuid.uuid4().hex[:8]}"
        stack = build_controller_stack(model)
        self.compiled = stack.compiled
        self.clock = StepClock()  # the core's: one reading per step, what the recording and a replay use
        self.core = stack.control_core(self.clock, execution=execution or config.controller.execution)
        self.store = StateStore(db or config.controller.db)
        self.production = production
        self.orders = OrderFlow(OrderBook(self.store, model))
        self.station_hold = StationHold(bus, self.keys, self.store, self.controller_id)
        self.hubs_of = {r: hub.name for r, hub in config.resources.items()}
        self.watchdog = Watchdog(self.hubs_of, stale_after=config.controller.stale_after_s,
                                 mirror_bound=config.controller.mirror_timeout_s)
        self.codecs = {r.name: Codec(r) for r in model.resources if r.name in self.hubs_of}
        self.commanded = {name: c for name, c in self.codecs.items() if c.commands}
        commands = {r: [v.name for v in codec.commands] for r, codec in self.commanded.items()}
        self.command_hold = CommandHold(self.core, commands, self.hubs_of)
        self.mirror_wait = mirror_wait_s
        self.requested = list(requested) if requested is not None else None
        self.hold = hold  # with nothing persisted, request no operation: the console starts them
        self.persisted_indices = [self.compiled.index[p] for p in model.paths_of_kind(Kind.ESTIMATED)]
        self._dirty = asyncio.Event()
        self._last_persisted: dict[int, Value] = {}
        sink = None if record is None else open_recording(config.controller.recording, msgspec.structs.replace(
            record, station=config.station.name, model=config.station.model, config=config.path), model)
        self.recorder = RunRecorder(self.core, self.clock, sink)
        # The plans' predicted finish and bound at the durations the hubs emulate (the model's under hubs.toml's).
        self.loop = ControlLoop(self.core, self.recorder, self.commanded, self.clock.advance,
                                self._at_speed(effect_seconds(model, config.delays)),
                                shortest=self._at_speed(shortest_seconds(model, config.delays)))
        self.meter = LoopMeter()
        self.ingest = StateIngest(self.loop, self.keys, self.codecs, self.controller_id, self.watchdog,
                                  self.command_hold, self.meter, self._forged)
        self.commands = CommandPublisher(bus, self.keys, self.commanded, self.controller_id,
                                         lambda: self.station_hold.epoch, self.watchdog)
        # A search holds the GIL: it runs in a process of its own when the model can be rebuilt there. It checks
        # its plans in time too (controller/planworker.py), against the durations the station's hubs emulate.
        self.planner_process = PlannerProcess(config.station.model, timing=self.timing()) if planner_process else None
        self.planning = PlanClient(self.loop, self.planner_process, self._dirty.set)
        self.status_publisher = StatusPublisher(config.station.name, self.controller_id, self.core, self.watchdog,
                                                self.hubs_of, self.meter, self.orders, self.loop.cycle)
        self.notifier = Notifier()  # systemd's READY=1 and watchdog, under a unit only

    def timing(self) -> Timing:
        """The station's effect durations, from the source the emulator uses (the model's, under hubs.toml's
        `delay`), and the engine's own order: what plans are checked in time against."""
        table = durations_of(self.model, self.config.delays)
        return Timing({key: duration.scaled(self.speed) for key, duration in table.keyed().items()},
                      self.core.engine.execution)

    def _at_speed(self, seconds: dict[str, float]) -> dict[str, float]:
        return {name: value / self.speed for name, value in seconds.items()}

    # --- start-up -------------------------------------------------------------------------
    def _restore(self) -> None:
        values, notes = self.store.load(self.model)
        for note in notes:
            log.warning(note)
        requested = self.store.meta(REQUESTED_META)
        if values:
            self.core.load(values)
            log.info("restored %d persisted values from %s", len(values), self.store.path)
        if self.production is not None:
            queued = self.orders.queue(self.production)
            if queued:
                log.info("queued %d orders: %s", queued, self.production.describe())
        if self.requested is None:
            # A station running orders requests what its running order's start stored (book.next), nothing
            # between two orders; one that never had an order runs every operation once, as it always did.
            orders = not self.orders.book.empty()
            everything = [] if self.hold or orders else [op.name for op in self.model.operations]
            self.requested = list(requested) if isinstance(requested, list) else everything
        self.loop.request(self.requested)
        self.store.save({}, {REQUESTED_META: self.requested})
        self.loop.run_orders(self.orders)
        self._last_persisted = {i: self.core.state[i] for i in self.persisted_indices}

    async def _take_mirrors(self) -> None:
        """Wait for each commanded resource's state; take the command state from its mirror."""
        deadline = time.monotonic() + self.mirror_wait
        mirrors = self.ingest.mirrors
        while time.monotonic() < deadline and set(self.commanded) - set(mirrors):
            await asyncio.sleep(0.05)
        self.command_hold.start(mirrors, self.mirror_wait)

    async def _planner_ready(self, stop: asyncio.Event) -> None:
        """Plan only once the planner process has its tables (it builds them while the hubs' mirrors come):
        a request asked earlier would wait for them, and its first plan with it. Everything else (state
        ingestion, commands, ticks) runs meanwhile."""
        if self.planner_process is not None:
            if await self.planner_process.ready(READY_WAIT_S, stop):
                log.info("planner ready: its tables built in %.2f s", self.planner_process.ready_seconds or 0.0)
            elif not stop.is_set():
                log.warning("the planner process is not ready (gone, or no tables after %.0f s): planning anyway",
                            READY_WAIT_S)
        self.planning.usable = True
        self._dirty.set()

    # --- the loop -------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        await self.station_hold.acquire()  # raises ControllerConflict, naming the holder, before anything is sent
        self._restore()
        # The model, the compiled guards and the planner's tables live as long as the process: kept out
        # of the collector's full passes, which paused the loop for 25-270 ms at 750 resources.
        gc.freeze()
        tasks = [
            asyncio.create_task(self.ingest.run(self.bus, self._dirty.set), name="states"),
            asyncio.create_task(self._watch_hubs(), name="liveliness"),
            asyncio.create_task(self._watch_calls(), name="supervisor calls"),
            asyncio.create_task(self.station_hold.watch(stop), name="holder"),
            asyncio.create_task(self._planner_ready(stop), name="planner ready"),
        ]
        try:
            await self._take_mirrors()
            self.notifier.ready()
            held = self.command_hold
            tasks.append(asyncio.create_task(self.commands.resend(
                self.loop, lambda: held.held, self.config.controller.command_rate_hz, stop), name="resend"))
            tasks.append(asyncio.create_task(self.status_publisher.run(self.bus, self.keys, stop), name="status"))
            requests = self.loop.requests(persist=lambda ops: self.store.save({}, {"requested": ops}),
                                          wake=self._dirty.set)
            tasks.append(asyncio.create_task(requests.serve(self.bus, self.keys.ctl("request")), name="requests"))
            orders = OrdersService(self.orders.book, changed=self._dirty.set)
            tasks.append(asyncio.create_task(orders.serve(self.bus, self.keys), name="orders"))
            await self._tick_loop(stop)
        finally:
            await cancel_and_wait([*tasks, *self.planning.tasks()], TASKS_END_S, log)
            if self.planner_process is not None:
                self.planner_process.close()
            self.station_hold.release()
            self.store.close()
            self.loop.finish(RunOutcome.FINISHED if self.core.all_finished() else RunOutcome.STOPPED)
        if self.station_hold.lost is not None:
            raise self.station_hold.lost

    def _forged(self, resource: str, mirror: Any) -> None:
        """A mirror of a command in our name with a seq we never sent: forged, and it holds back ours."""
        if mirror.epoch == self.station_hold.epoch:  # once per epoch: the new one's commands replace it at once
            self.station_hold.renew(f"{resource}: the hub mirrors seq {mirror.seq} of this controller, which "
                                    f"sent {self.loop.outbox.highest_seq(resource)} at most: a forged command")

    async def _watch_hubs(self) -> None:
        async for event in self.bus.watch_liveliness(self.keys.all_alive):
            hub = self.keys.hub_of(event.key)
            if hub is not None:
                self.watchdog.hub_alive(hub, event.alive)
                self.loop.liveliness(hub, event.alive)
                self._dirty.set()

    async def _watch_calls(self) -> None:
        """Operators' calls for the supervisor (the operator's page): into the event log."""
        async for event in self.bus.watch_liveliness(self.keys.all_calls):
            call = self.keys.call_of(event.key)
            if call is not None:
                hub, resource = call
                if event.alive:
                    log.warning("%s calls the supervisor (hub %s)", resource, hub)
                self.loop.supervisor_call(hub, resource, event.alive)
                self._dirty.set()

    async def _tick_loop(self, stop: asyncio.Event) -> None:
        period = 1.0 / self.config.controller.tick_rate_hz
        meter = self.meter
        while not stop.is_set():
            self.notifier.alive()
            began = time.perf_counter()
            self._tick()
            meter.ticks.append(time.perf_counter() - began)
            self._dirty.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(period):
                    await self._dirty.wait()

    def _tick(self) -> None:
        ticked = self.loop.tick(self.watchdog.unhealthy(), self.command_hold.held)
        result = ticked.result
        for name in result.started:
            log.info("operation %s started", name)
        for name in result.finished:
            log.info("operation %s finished", name)
        for event in ticked.orders:
            log.info("%s", event.text)
        self.status_publisher.ticked(result)
        self._persist()
        self.commands.publish(ticked.commands)
        self.planning.maybe_plan()

    def _persist(self) -> None:
        state = self.core.own_state()  # a forced value is not the variable's: a restart releases forces
        changes = {self.compiled.paths[i]: state[i] for i in self.persisted_indices
                   if self._last_persisted.get(i) != state[i]}
        if changes:
            self.store.save(changes)
            for path in changes:
                self._last_persisted[self.compiled.index[path]] = state[self.compiled.index[path]]
