"""The controller process: the engine and planner on live state over Zenoh.

It ingests every hub's state, ticks on change and at its tick rate, publishes changed
commands at once and all commands at the command rate, persists estimated variables
and operation states on every change, runs the planner off the event loop, feeds the
mirror-watchdog, and publishes status and state under `{station}/ctl/`.

On start it restores what it persisted, waits (bounded) for every hub's mirror, takes
the command state from the mirrors, and goes on where it was; a resource whose mirror is
late is held, sent nothing, until it comes (controller/command_hold.py).
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

from common.bus.protocol import Bus, Sample
from common.config.hubs_toml import StationConfig
from common.model import Kind, Model, Value
from common.plumbing.sdnotify import Notifier
from common.plumbing.tasks import cancel_and_wait
from common.wire.badpayload import BadPayloads
from common.wire.ctl import (
    EVENT_WINDOW,
    HubAlive,
    HubGone,
    LoopStats,
    NoPlanFound,
    OperationInfo,
    PlannedAlone,
    ResourceHealthInfo,
    StateSnapshot,
    StatusMessage,
)
from common.wire.messages import Codec, HubStatus, MessageError, encode
from controller.command_hold import CommandHold
from controller.recording.hooks import RunRecorder, StepClock, open_recording
from controller.recording.schema import RunMeta
from controller.station_hold import StationHold

from .control import PlanRequest
from .planner import NoPlan, Plan
from .planworker import READY_WAIT_S, PlannerProcess
from .requests import Requests
from .stack import build_controller_stack
from .state import StateStore
from .statusfeed import PlanBook, StatusDiet
from .watchdog import Watchdog

log = logging.getLogger("statehub.controller")

STATUS_PERIOD_S = 0.25
STATE_SNAPSHOT_PERIOD_S = 1.0
TASKS_END_S = 2.0  # for the loop's tasks to end once cancelled, before the state is saved and the hold released
INGEST_BATCH_S = 0.002  # least time between two state batches: bursts join one batch


class LoopMeter:
    """Tick durations and state ingestion between two statuses (`StatusMessage.loop`)."""

    def __init__(self) -> None:
        self.dropped = 0  # cumulative, set by the ingest loop from its subscription
        self._dropped_before = 0
        self._restart(time.monotonic())

    def _restart(self, now: float) -> None:
        self.since = now
        self.ticks: list[float] = []  # seconds
        self.ages: list[float] = []  # seconds from a state's publication to its ingestion

    def take(self) -> LoopStats:
        now = time.monotonic()
        ticks, ages = sorted(self.ticks), sorted(self.ages)
        stats = LoopStats(
            window_s=now - self.since, ticks=len(ticks), tick_ms_median=_ms(ticks, 0.5), tick_ms_p99=_ms(ticks, 0.99),
            tick_ms_max=_ms(ticks, 1.0), states=len(ages), states_dropped=self.dropped - self._dropped_before,
            state_age_ms_median=_ms(ages, 0.5), state_age_ms_p99=_ms(ages, 0.99), state_age_ms_max=_ms(ages, 1.0))
        self._dropped_before = self.dropped
        self._restart(now)
        return stats


def _ms(ordered: list[float], q: float) -> float:
    return 1000.0 * ordered[min(len(ordered) - 1, int(len(ordered) * q))] if ordered else 0.0


class ControllerService:
    def __init__(self, config: StationConfig, model: Model, bus: Bus, *, db: str | None = None,
                 mirror_wait_s: float = 5.0, requested: Iterable[str] | None = None,
                 planner_process: bool = True, hold: bool = False, record: RunMeta | None = None) -> None:
        self.config = config
        self.model = model
        self.bus = bus
        self.keys = config.keys
        self.controller_id = f"{config.controller.name}-{uuid.uuid4().hex[:8]}"
        stack = build_controller_stack(model)
        self.compiled = stack.compiled
        self.clock = StepClock()  # the core's: one reading per step, what the recording and a replay use
        self.core = stack.control_core(self.clock)
        self.store = StateStore(db or config.controller.db)
        self.station_hold = StationHold(bus, self.keys, self.store, self.controller_id)
        self.hubs_of = {r: hub.name for r, hub in config.resources.items()}
        self.watchdog = Watchdog(self.hubs_of, stale_after=config.controller.stale_after_s,
                                 mirror_bound=config.controller.mirror_timeout_s)
        self.codecs = {r.name: Codec(r) for r in model.resources if r.name in self.hubs_of}
        self.commanded = {name: c for name, c in self.codecs.items() if c.commands}
        self.command_seq = dict.fromkeys(self.commanded, 0)
        self._sent: dict[str, tuple[Value, ...]] = {}  # the values each resource was last sent, under its seq
        commands = {r: [v.name for v in codec.commands] for r, codec in self.commanded.items()}
        self.command_hold = CommandHold(self.core, commands, self.hubs_of)
        self.mirror_wait = mirror_wait_s
        self.requested = list(requested) if requested is not None else None
        self.hold = hold  # with nothing persisted, request no operation: the console starts them
        self.persisted_indices = [self.compiled.index[p] for p in model.paths_of_kind(Kind.ESTIMATED)]
        index = self.compiled.index
        self.command_indices = {
            name: [(v.name, index[v.path]) for v in codec.commands] for name, codec in self.commanded.items()
        }
        self.started = time.monotonic()
        self.op_since: dict[str, float] = {}
        self.mirrors: dict[str, dict[str, Value]] = {}
        self._dirty = asyncio.Event()
        self._status_due = True
        self._last_persisted: dict[int, Value] = {}
        self._bad_states = BadPayloads(log, "dropped state")
        self._planning: asyncio.Task[None] | None = None  # until the request under way has its first answer
        self._solving: set[asyncio.Task[None]] = set()  # requests whose answers are still coming
        self._planner_usable = False  # until the planner process has its tables (`_planner_ready`)
        # A search holds the GIL: it runs in a process of its own when the model can be rebuilt there.
        self.planner_process = PlannerProcess(config.station.model) if planner_process else None
        self.meter = LoopMeter()
        self.notifier = Notifier()  # systemd's READY=1 and watchdog, under a unit only
        self.plan_book = PlanBook(self.compiled, self.core)
        self.status_diet = StatusDiet()
        sink = None if record is None else open_recording(config.controller.recording, msgspec.structs.replace(
            record, station=config.station.name, model=config.station.model, config=config.path), model)
        self.recorder = RunRecorder(self.core, self.clock, sink)

    # --- start-up -------------------------------------------------------------------------
    def _restore(self) -> None:
        values, notes = self.store.load(self.model)
        for note in notes:
            log.warning(note)
        requested = self.store.meta("requested")
        if values:
            self.core.load(values)
            log.info("restored %d persisted values from %s", len(values), self.store.path)
        if self.requested is None:
            everything = [] if self.hold else [op.name for op in self.model.operations]
            self.requested = list(requested) if isinstance(requested, list) else everything
        self.core.request(*self.requested)
        self.recorder.requested(self.requested)
        self.store.save({}, {"requested": self.requested})
        self._last_persisted = {i: self.core.state[i] for i in self.persisted_indices}

    async def _take_mirrors(self) -> None:
        """Wait for each commanded resource's state; take the command state from its mirror."""
        deadline = time.monotonic() + self.mirror_wait
        while time.monotonic() < deadline and set(self.commanded) - set(self.mirrors):
            await asyncio.sleep(0.05)
        self.command_hold.start(self.mirrors, self.mirror_wait)

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
        self._planner_usable = True
        self._dirty.set()

    # --- the loop -------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        await self.station_hold.acquire()  # raises ControllerConflict, naming the holder, before anything is sent
        self._restore()
        # The model, the compiled guards and the planner's tables live as long as the process: kept out
        # of the collector's full passes, which paused the loop for 25-270 ms at 750 resources.
        gc.freeze()
        tasks = [
            asyncio.create_task(self._ingest_states(), name="states"),
            asyncio.create_task(self._watch_hubs(), name="liveliness"),
            asyncio.create_task(self.station_hold.watch(stop), name="holder"),
            asyncio.create_task(self._planner_ready(stop), name="planner ready"),
        ]
        try:
            await self._take_mirrors()
            self.notifier.ready()
            tasks.append(asyncio.create_task(self._resend_commands(stop), name="resend"))
            tasks.append(asyncio.create_task(self._publish_status_loop(stop), name="status"))
            requests = Requests(self.core, persist=lambda ops: self.store.save({}, {"requested": ops}),
                                wake=self._dirty.set, answered=self.recorder.request)
            tasks.append(asyncio.create_task(requests.serve(self.bus, self.keys.ctl("request")), name="requests"))
            await self._tick_loop(stop)
        finally:
            planning = [self._planning] if self._planning is not None else []
            await cancel_and_wait([*tasks, *planning, *self._solving], TASKS_END_S, log)
            if self.planner_process is not None:
                self.planner_process.close()
            self.station_hold.release()
            self.store.close()
            self.recorder.finish("finished" if self.core.all_finished() else "stopped")
        if self.station_hold.lost is not None:
            raise self.station_hold.lost

    async def _ingest_states(self) -> None:
        # In batches: at hundreds of resources at 50 Hz, a loop wake-up, a core update and a tick
        # request per state cost more than decoding the state. Each resource's state key is declared
        # (`expect`): zenoh then routes it without matching it against every command key we publish.
        routes = self._state_routes()
        subscription = self.bus.subscribe(self.keys.all_state, batch_s=INGEST_BATCH_S, expect=routes.keys())
        async for batch in subscription.batches():
            self.meter.dropped = subscription.dropped
            self._ingest_batch(batch, routes)

    def _state_routes(self) -> dict[str, tuple[str, Codec, tuple[tuple[str, str], ...]]]:
        """Per state key: the resource, its codec, and (path, field) of each measured variable."""
        return {self.keys.state(resource): (resource, codec, tuple((v.path, v.name) for v in codec.measured))
                for resource, codec in self.codecs.items()}

    def _ingest_batch(self, samples: list[Sample],
                      routes: dict[str, tuple[str, Codec, tuple[tuple[str, str], ...]]]) -> None:
        """Decode a batch (newest state per resource), feed the watchdog, and merge the measured
        values into the core's state at once. A state that cannot be decoded is dropped (logged
        at most once per key and interval, with a count); the rest of the batch is ingested."""
        watchdog, mirrors, controller_id = self.watchdog, self.mirrors, self.controller_id
        measured: dict[str, Value] = {}
        published: list[float] = []
        hub_states = []
        for sample in samples:
            route = routes.get(sample.key)
            if route is None:
                continue
            resource, codec, fields = route
            try:
                state = codec.decode_state(sample.payload)
            except MessageError as exc:
                self._bad_states.report("an unknown sender", sample.key, str(exc))
                continue
            published.append(state.time)
            mirror = state.mirror
            mirrored_seq = mirror.seq if mirror is not None and mirror.controller == controller_id else None
            if mirrored_seq is not None and mirrored_seq > self.command_seq.get(resource, -1):
                self._forged(resource, mirror)
                mirrored_seq = None  # not a command this controller sent
            if resource not in mirrors:
                if mirror is not None:
                    mirrors[resource] = codec.values(mirror)
                elif state.status == HubStatus.NO_COMMAND:
                    mirrors[resource] = {}
            if resource in self.command_hold.held:
                self.command_hold.arrived(resource, None if mirror is None else codec.values(mirror), state.status)
            watchdog.state_received(resource, state.status, state.detail, mirrored_seq)
            hub_states.append((resource, state.status, state.detail, mirrored_seq))
            for path, name in fields:
                value = getattr(state, name)
                if value is not None:  # unknown (device lost): the last known value stands
                    measured[path] = value
        self.clock.advance()
        changed = self.core.ingest(measured) if measured else {}
        if changed:
            self._dirty.set()
        self.recorder.ingested(changed, hub_states)
        now = time.time()  # ingested now, when the core holds them: the age includes decoding the batch
        self.meter.ages.extend(now - t for t in published)

    def _forged(self, resource: str, mirror: Any) -> None:
        """A mirror of a command in our name with a seq we never sent: forged, and it holds back ours."""
        if mirror.epoch == self.station_hold.epoch:  # once per epoch: the new one's commands replace it at once
            self.station_hold.renew(f"{resource}: the hub mirrors seq {mirror.seq} of this controller, which "
                                    f"sent {self.command_seq.get(resource)} at most: a forged command")

    async def _watch_hubs(self) -> None:
        async for event in self.bus.watch_liveliness(self.keys.all_alive):
            hub = self.keys.hub_of(event.key)
            if hub is not None:
                self.watchdog.hub_alive(hub, event.alive)
                self.recorder.liveliness(hub, event.alive)
                self.core.events.log.append(HubAlive(hub) if event.alive else HubGone(hub))
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
        core = self.core
        self.clock.advance()
        unhealthy = self.watchdog.unhealthy()
        core.set_disabled(frozenset(unhealthy) | self.command_hold.held)
        result = core.tick()
        self.recorder.ticked(unhealthy)
        now = time.monotonic()
        for name in result.started:
            self.op_since[name] = now
            log.info("operation %s started", name)
        for name in result.finished:
            self.op_since[name] = now
            log.info("operation %s finished", name)
        if result.started or result.finished:
            self._status_due = True
        self._persist()
        self._publish_changed()
        self._maybe_plan()

    def _persist(self) -> None:
        state = self.core.own_state()  # a forced value is not the variable's: a restart releases forces
        changes = {self.compiled.paths[i]: state[i] for i in self.persisted_indices
                   if self._last_persisted.get(i) != state[i]}
        if changes:
            self.store.save(changes)
            for path in changes:
                self._last_persisted[self.compiled.index[path]] = state[self.compiled.index[path]]

    def _publish_changed(self) -> None:
        # Against what was sent, not the tick's start: a force or a mirror taken between ticks is a change too.
        state, sent = self.core.state, self._sent
        for resource, indices in self.command_indices.items():
            if sent.get(resource) != tuple(state[i] for _, i in indices):
                self._send(resource)

    def _send(self, resource: str) -> None:
        # Sent to unhealthy resources too: the engine changes nothing for them, and re-sending
        # the same state lets a recovering hub catch up at once. Not to a held one: its command state is unknown.
        if resource in self.command_hold.held:
            return
        codec = self.commanded[resource]
        state = self.core.state
        values = {name: state[i] for name, i in self.command_indices[resource]}
        current, previous = tuple(values.values()), self._sent.get(resource)
        if previous is not None and previous != current:  # new values, new seq: the watchdog sees them applied
            self.command_seq[resource] += 1
        self._sent[resource] = current
        seq = self.command_seq[resource]
        if previous != current:
            self.recorder.command(resource, seq)
        message = codec.command(values, seq=seq, controller=self.controller_id, epoch=self.station_hold.epoch)
        self.bus.publish(self.keys.cmd(resource), codec.encode_command(message))
        self.watchdog.command_sent(resource, seq)

    async def _resend_commands(self, stop: asyncio.Event) -> None:
        period = 1.0 / self.config.controller.command_rate_hz
        while not stop.is_set():
            for resource in self.commanded:
                self._send(resource)
            await asyncio.sleep(period)

    # --- planning off the loop ------------------------------------------------------------
    def _maybe_plan(self) -> None:
        if self._planning is not None or not self._planner_usable:
            return
        request = self.core.plan_request()
        if request is None:
            return
        self.recorder.plan_request(request)
        first_answered = asyncio.Event()

        async def solve() -> None:
            try:
                if self.planner_process is not None:
                    async for answer in self.planner_process.answers(request):
                        if answer.note is not None:
                            self.core.events.log.append(answer.note)
                        if not first_answered.is_set():
                            self._adopt(request, answer.result, answer.note)
                            first_answered.set()
                        elif isinstance(answer.result, Plan) and self._improve(request, answer.result):
                            log.info("shorter plan taken: %d steps (%s)", len(answer.result.steps),
                                     answer.result.stats.method)
                            self._status_due = True
                            self._dirty.set()
                else:
                    self._adopt(request, await asyncio.to_thread(self.core.solve, request))
            except Exception as exc:  # a planner bug must not stop the station: report and retry
                log.exception("planner failed")
                if not first_answered.is_set():
                    self._adopt(request, NoPlan(f"planner failed: {type(exc).__name__}: {exc}",
                                                tuple(request.goals)))
            finally:
                first_answered.set()

        async def first() -> None:
            # A newer request may go out as soon as this one has its first answer; the worker then
            # drops the improvement of this one.
            await first_answered.wait()
            self._planning = None
            self._dirty.set()

        task = asyncio.create_task(solve(), name=f"plan-{request.generation}")
        self._solving.add(task)
        task.add_done_callback(self._solving.discard)
        self._planning = asyncio.create_task(first(), name="plan")

    def _improve(self, request: PlanRequest, better: Plan) -> bool:
        taken = self.core.improve(request, better)
        self.recorder.plan(request, better, taken=taken, improvement=True)
        return taken

    def _adopt(self, request: PlanRequest, result: Plan | NoPlan | None, note: PlannedAlone | None = None) -> None:
        said = len(self.core.events.log)
        self.recorder.plan(request, result, taken=self.core.adopt(request, result), note=note)
        for event in self.core.events.log[said:]:
            if isinstance(event, NoPlanFound):  # once per goal and reason, not at every retry
                log.warning("%s", event.text)
        if isinstance(result, Plan):
            stats = result.stats
            log.info("plan: %d steps for %d goals in %.1f ms (%s%s; %s)", len(result.steps), len(request.goals),
                     stats.seconds * 1000, stats.method, ", shortest" if stats.minimal else "", request.reason.text)
        self._status_due = True
        self._dirty.set()

    # --- status out -----------------------------------------------------------------------
    async def _publish_status_loop(self, stop: asyncio.Event) -> None:
        last_snapshot = 0.0
        self.status_diet.serve(self.bus, self.keys, self.plan_book)
        while not stop.is_set():
            now = time.monotonic()
            status = self.status_diet.next(self.status(), self.core.events.log, now)
            self.bus.publish(self.keys.ctl("status"), encode(status))
            if now - last_snapshot >= STATE_SNAPSHOT_PERIOD_S:
                snapshot = StateSnapshot(time=time.time(), values=self.compiled.unpack(self.core.state),
                                         forced=self.core.forced_paths())
                self.bus.publish(self.keys.ctl("state"), encode(snapshot))
                last_snapshot = now
            await asyncio.sleep(STATUS_PERIOD_S)

    def status(self) -> StatusMessage:
        """The whole picture (`status_diet` publishes what changed of it)."""
        core = self.core
        now = time.monotonic()
        operations = [
            OperationInfo(op.name, core.op_state(op.name), core.error_text(op.name),
                          self.op_since.get(op.name, self.started) - self.started)
            for op in self.model.operations
        ]
        health = []
        for resource in self.hubs_of:
            h = self.watchdog.health(resource)
            health.append(ResourceHealthInfo(resource, h.hub, h.healthy, h.reason, h.age, h.mirror_lag, h.note))
        events = core.events
        return StatusMessage(
            station=self.config.station.name, controller=self.controller_id, time=time.time(),
            uptime=now - self.started, operations=operations, health=health, plan=self.plan_book.info(),
            plans=events.plans, replans=events.replans, no_plans=events.no_plans,
            abilities=events.abilities_started, paused=core.paused, finished=core.all_finished(),
            events=events.log[-EVENT_WINDOW:], events_total=len(events.log),
            loop=self.meter.take(),
        )
