"""The console's side of the bus: what the controller and the hubs publish, and the console's requests.

`ConsoleLink.run()` keeps the newest status (the controller's deltas on `{station}/ctl/status`
merged into a full picture, controller/console/statusview.py; on connecting it asks for the whole picture),
the details of the plan under way (`{station}/ctl/plan/{id}`, asked when the plan or its done steps
change), `{station}/ctl/state` and the self-test report of each hub (those subscriptions coalesce:
a console that draws slower than the controller publishes only ever sees the newest), and counts
each change in `version` so that the screen redraws only when something arrived. `request()` asks the
controller on `{station}/ctl/request` and returns its `ConsoleReply`; a controller that
does not answer is a refusal with that reason.

Peers do not route for each other: the console listens too, so that the hubs (told by
the controller's gossip) link to it and it receives their self-test reports.
"""

from __future__ import annotations

import asyncio
import contextlib
import getpass
import logging
import socket
from collections.abc import Callable, Sequence
from typing import Protocol

import msgspec

from common.bus.protocol import Bus, BusError, Sample, Subscription
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import ZenohConfig, zenoh_config
from common.config.modes import NetworkMode
from common.wire.ctl import ConsoleReply, ConsoleRequest, PlanDetails, StateSnapshot, StatusMessage
from common.wire.keys import station_keys
from common.wire.messages import Message, MessageError, decode
from common.wire.selftest_report import SelftestMessage
from controller.console.statusview import StatusFollower, fetch_plan
from controller.ctl_query import ask_controller

log = logging.getLogger("statehub.console")

REQUEST_TIMEOUT_S = 3.0
SELFTEST_QUERY_PERIOD_S = 2.0
PLAN_CHECK_S = 0.5  # how often the console looks whether the plan's details are to be asked again
PLAN_REFRESH_S = 5.0  # what pending steps wait for changes with the state: asked again at least this often


class Feed(Protocol):
    """What the console app reads: a live `ConsoleLink`, or a canned feed in benchmarks."""

    status: StatusMessage | None
    plan: PlanDetails | None  # the steps of the plan under way (of `status.plan.id`, or of an earlier one)
    snapshot: StateSnapshot | None
    selftests: dict[str, SelftestMessage]
    version: int

    @property
    def connected(self) -> bool: ...

    async def run(self) -> None: ...

    async def request(self, request: ConsoleRequest) -> ConsoleReply: ...


def refused(reason: str) -> ConsoleReply:
    return ConsoleReply(accepted=False, reason=reason)


def origin() -> str:
    """Who is asking, for the controller's event log."""
    with contextlib.suppress(Exception):
        return f"{getpass.getuser()}@{socket.gethostname()}"
    return "console"


class ConsoleLink:
    def __init__(self, station: str, connect: Sequence[str], *, listen: Sequence[str] = ("tcp/0.0.0.0:0",),
                 lease_ms: int = 2000, zconfig: ZenohConfig | None = None) -> None:
        """`zconfig`: the session's config when the station is secured (common/bus/station_net.py)."""
        self.keys = station_keys(station)
        self.connect = list(connect)
        self.config = zconfig or zenoh_config(NetworkMode.PEER, listen=listen, connect=connect, lease_ms=lease_ms)
        self.status: StatusMessage | None = None
        self.plan: PlanDetails | None = None
        self.snapshot: StateSnapshot | None = None
        self.selftests: dict[str, SelftestMessage] = {}
        self.version = 0
        self.undecodable = 0
        self.origin = origin()
        self._bus: Bus | None = None
        self._opened = asyncio.Event()

    @property
    def connected(self) -> bool:
        return self._bus is not None

    async def run(self) -> None:
        async with ZenohBus(self.config) as bus:
            self._bus = bus
            self._opened.set()
            subscriptions = [
                (bus.subscribe(self.keys.ctl("state")), self._on_snapshot),
                (bus.subscribe(self.keys.all_selftest), self._on_selftest),
            ]
            tasks = [asyncio.create_task(self._consume(s, handler)) for s, handler in subscriptions]
            tasks.append(asyncio.create_task(self._follow_status(bus)))
            tasks.append(asyncio.create_task(self._follow_plan(bus)))
            tasks.append(asyncio.create_task(self._ask_selftests(bus)))
            try:
                await asyncio.gather(*tasks)
            finally:
                self._bus = None
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)

    async def request(self, request: ConsoleRequest) -> ConsoleReply:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(REQUEST_TIMEOUT_S):
                await self._opened.wait()
        bus = self._bus
        if bus is None:
            return refused("not connected to the station's bus")
        if not request.origin:
            request = msgspec.structs.replace(request, origin=self.origin)
        try:
            return await ask_controller(
                bus, self.keys.ctl("request"), request, ConsoleReply, timeout=REQUEST_TIMEOUT_S, refuse=refused,
                unanswered=f"no controller answered within {REQUEST_TIMEOUT_S:.0f} s "
                           f"(connecting to {', '.join(self.connect) or 'nobody'})")
        except BusError as exc:  # the session closing under us: an answer, not a crash
            return refused(f"the request could not be sent: {exc}")

    # --- what arrives ------------------------------------------------------------------------
    @staticmethod
    async def _consume(subscription: Subscription[Sample], handler: Callable[[Sample], None]) -> None:
        async for sample in subscription:
            handler(sample)

    def _decode(self, sample: Sample, type_: type[Message]) -> Message | None:
        try:
            return decode(sample.payload, type_)
        except MessageError as exc:
            self._undecodable(sample, exc)
            return None

    def _undecodable(self, sample: Sample, exc: MessageError) -> None:
        if not self.undecodable:
            log.warning("dropped %s: %s", sample.key, exc)
        self.undecodable += 1

    async def _follow_status(self, bus: Bus) -> None:
        # Every sample: a delta applies only to the picture before it (a gap is mended by asking).
        follower = StatusFollower(bus, self.keys)
        async for sample in bus.subscribe(self.keys.ctl("status"), coalesce=False):
            try:
                status = await follower.take(sample.payload)
            except MessageError as exc:
                self._undecodable(sample, exc)
                continue
            if status is not None:
                self.status = status
                self.version += 1

    async def _follow_plan(self, bus: Bus) -> None:
        """Ask the plan's details when another plan is under way or its done steps changed (at most every
        PLAN_CHECK_S), and every PLAN_REFRESH_S while it has steps pending (what they wait for moves on)."""
        asked: tuple[int, bytes] | None = None
        asked_at = 0.0
        while True:
            await asyncio.sleep(PLAN_CHECK_S)
            status = self.status
            plan = status.plan if status is not None else None
            if plan is None or not plan.id:
                continue
            now = asyncio.get_running_loop().time()
            pending = plan.done_count < plan.steps
            if asked != (plan.id, plan.done) or (pending and now - asked_at >= PLAN_REFRESH_S):
                details = await fetch_plan(bus, self.keys, plan.id)
                asked, asked_at = (plan.id, plan.done), now
                if details is not None:
                    self.plan = details
                    self.version += 1

    def _on_snapshot(self, sample: Sample) -> None:
        snapshot = self._decode(sample, StateSnapshot)
        if isinstance(snapshot, StateSnapshot):
            self.snapshot = snapshot
            self.version += 1

    def _on_selftest(self, sample: Sample) -> None:
        report = self._decode(sample, SelftestMessage)
        if isinstance(report, SelftestMessage):
            self.selftests[report.hub] = report
            self.version += 1

    async def _ask_selftests(self, bus: Bus) -> None:
        """A hub publishes its report once, at boot: ask for those published before the console started,
        until every hub the controller knows has answered."""
        while True:
            status = self.status
            hubs = {h.hub for h in status.health} if status is not None else set()
            if not hubs or hubs - set(self.selftests):
                for reply in await bus.get(self.keys.all_selftest, timeout=1.0):
                    if reply.ok:
                        self._on_selftest(Sample(reply.key, reply.payload))
            await asyncio.sleep(SELFTEST_QUERY_PERIOD_S)
