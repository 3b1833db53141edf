"""What the live controller shows of itself: `{station}/ctl/status` (through the status diet,
controller/statusfeed.py) every STATUS_PERIOD_S, and the global state on `{station}/ctl/state` every
STATE_SNAPSHOT_PERIOD_S."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping

from common.bus.protocol import Bus
from common.wire.ctl import (
    EVENT_WINDOW,
    CycleInfo,
    OperationInfo,
    ResourceHealthInfo,
    ResourceIdleInfo,
    StateSnapshot,
    StatusMessage,
)
from common.wire.keys import Keys
from common.wire.messages import encode

from .control import ControlCore
from .cycle import CycleRecord, CycleReport
from .engine import TickResult
from .loopmeter import LoopMeter
from .production.flow import OrderFlow
from .statusfeed import PlanBook, StatusDiet
from .watchdog import Watchdog

STATUS_PERIOD_S = 0.25
STATE_SNAPSHOT_PERIOD_S = 1.0
WAITS_SHOWN = 3  # of what a resource waited for, the longest ones in a status


def cycle_info(report: CycleReport) -> CycleInfo:
    """A cycle report on the wire."""
    return CycleInfo(
        cycle_s=report.cycle, predicted_s=report.predicted, bound_s=report.bound,
        chain_s=report.chain, busiest=report.busiest,
        busiest_work_s=report.busiest_work,
        idle=[ResourceIdleInfo(r.resource, r.idle, list(r.waits[:WAITS_SHOWN])) for r in report.idle],
        apart_s=report.apart, apart=list(report.apart_resources))


class StatusPublisher:
    def __init__(self, station: str, controller_id: str, core: ControlCore, watchdog: Watchdog,
                 resources: Mapping[str, str], meter: LoopMeter, orders: OrderFlow | None = None,
                 cycle: CycleRecord | None = None) -> None:
        """`resources`: each supervised resource's hub, in the order the status lists them; `orders`: the
        station's orders (a station that has had one is finished when none runs or waits); `cycle`: the
        loop's plans' predictions and resources' busy spans, for the predicted finish and the bound."""
        self.station = station
        self.controller_id = controller_id
        self.core = core
        self.watchdog = watchdog
        self.resources = resources
        self.meter = meter
        self.orders = orders
        self.cycle = cycle
        self.finished_at: float | None = None  # the core's clock when every operation was last seen finished
        self.started = time.monotonic()
        self.op_since: dict[str, float] = {}  # when each operation last started or finished
        self.plan_book = PlanBook(core.compiled, core)
        self.diet = StatusDiet()

    def ticked(self, result: TickResult) -> None:
        now = time.monotonic()
        for name in (*result.started, *result.finished):
            self.op_since[name] = now
        if result.started:
            self.finished_at = None
        if result.finished and self.core.all_finished():
            self.finished_at = self.core.clock()  # the cycle ends here, not when a status is next made

    async def run(self, bus: Bus, keys: Keys, stop: asyncio.Event) -> None:
        last_snapshot = 0.0
        self.diet.serve(bus, keys, self.plan_book)
        core = self.core
        while not stop.is_set():
            now = time.monotonic()
            status = self.diet.next(self.status(), core.events.log, now)
            bus.publish(keys.ctl("status"), encode(status))
            if now - last_snapshot >= STATE_SNAPSHOT_PERIOD_S:
                snapshot = StateSnapshot(time=time.time(), values=core.compiled.unpack(core.state),
                                         forced=core.forced_paths())
                bus.publish(keys.ctl("state"), encode(snapshot))
                last_snapshot = now
            await asyncio.sleep(STATUS_PERIOD_S)

    def status(self) -> StatusMessage:
        """The whole picture (the status diet publishes what changed of it)."""
        core = self.core
        now = time.monotonic()
        operations = [
            OperationInfo(op.name, core.op_state(op.name), core.error_text(op.name),
                          self.op_since.get(op.name, self.started) - self.started)
            for op in core.model.operations
        ]
        health = []
        for resource in self.resources:
            h = self.watchdog.health(resource)
            health.append(ResourceHealthInfo(resource, h.hub, h.healthy, h.reason, h.age, h.mirror_lag, h.note))
        events = core.events
        orders = self.orders if self.orders is not None and not self.orders.book.empty() else None
        return StatusMessage(
            station=self.station, controller=self.controller_id, time=time.time(),
            uptime=now - self.started, operations=operations, health=health, plan=self.plan_book.info(),
            plans=events.plans, replans=events.replans, no_plans=events.no_plans,
            abilities=events.abilities_started, paused=core.paused,
            finished=core.all_finished() if orders is None else orders.idle(),
            events=events.log.recent(EVENT_WINDOW), events_total=events.log.total,
            loop=self.meter.take(), production=None if orders is None else orders.info(),
            cycle=self._cycle(),
        )

    def _cycle(self) -> CycleInfo | None:
        if self.cycle is None:
            return None
        end = self.finished_at if self.finished_at is not None else self.core.clock()
        # The bound from the specifications' exclusions takes a good part of a second on a long run: worked out
        # once the station is done, never between two orders, where it would hold up the loop the hubs wait on.
        done = self.finished_at is not None and (self.orders is None or self.orders.idle())
        return cycle_info(self.cycle.report(end, final=done))
