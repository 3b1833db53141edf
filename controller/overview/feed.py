"""What the overview knows of the running station, kept current from the bus and the run's recording.

`OverviewFeed.run(reader)` follows the controller's status (deltas merged into full statuses, the
whole picture asked when one is missed, controller/console/statusview.py), asks the details of the
plan under way when it or its done steps change (and now and then while steps wait: what they wait
for moves on), and reads the run's Gantt data from the recording every `GANTT_S`. Each change makes
a new `picture()` / `gantt` and wakes the page's streams (`changed`).
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque

from common.wire.ctl import Event, PlanDetails, StatusMessage
from common.wire.messages import MessageError, decode
from controller.console.station import StationInfo
from controller.console.statusview import StatusView
from controller.console.view import EventFeed, OperationClock

from .picture import EVENTS_SHOWN, SILENT_AFTER_S, Gantt, Picture, no_gantt, picture
from .reader import StationReader
from .runfile import RunGantt

log = logging.getLogger("statehub.overview")

PLAN_CHECK_S = 0.5
PLAN_REFRESH_S = 3.0
GANTT_S = 2.0
SILENCE_CHECK_S = 1.0  # a silent controller is noticed (and said) within about this long


class OverviewFeed:
    def __init__(self, info: StationInfo, run_gantt: RunGantt | None) -> None:
        self.info = info
        self.run_gantt = run_gantt
        self.status: StatusMessage | None = None
        self.plan: PlanDetails | None = None
        self.gantt: Gantt = no_gantt("reading the run's recording ...")
        self.version = 0  # counts every change of the picture or the Gantt data
        self._view = StatusView()
        self._clock = OperationClock()
        self._event_feed = EventFeed()
        self._events: deque[Event] = deque(maxlen=EVENTS_SHOWN)
        self._heard_at: float | None = None
        self._changed = asyncio.Condition()

    def picture(self) -> Picture:
        silent = None if self._heard_at is None else asyncio.get_running_loop().time() - self._heard_at
        return picture(self.info.station, self.status, self.plan, self.info, self._clock, self._events, silent)

    async def changed(self, seen: int) -> int:
        """Wait until `version` differs from `seen`; returns it."""
        async with self._changed:
            await self._changed.wait_for(lambda: self.version != seen)
            return self.version

    async def _bump(self) -> None:
        async with self._changed:
            self.version += 1
            self._changed.notify_all()

    async def run(self, reader: StationReader) -> None:
        tasks = [asyncio.create_task(self._follow_status(reader)), asyncio.create_task(self._follow_plan(reader)),
                 asyncio.create_task(self._watch_silence()), asyncio.create_task(self._follow_gantt())]
        try:
            await asyncio.gather(*tasks)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def take(self, status: StatusMessage) -> None:
        """A status (full or delta) as it came from the controller."""
        merged = self._view.apply(status)
        await self._merged(merged)

    async def _merged(self, merged: StatusMessage | None) -> None:
        if merged is None:
            return
        self.status = merged
        self._heard_at = asyncio.get_running_loop().time()
        self._events.extend(self._event_feed.new(merged))
        await self._bump()

    async def _follow_status(self, reader: StationReader) -> None:
        await self._merged(self._view.apply(full) if (full := await reader.full_status()) else None)
        async for sample in reader.statuses():
            try:
                merged = self._view.apply(decode(sample.payload, StatusMessage))
            except MessageError as exc:
                log.warning("dropped %s: %s", sample.key, exc)
                continue
            if merged is None and self._view.needs_full:
                full = await reader.full_status()
                merged = self._view.apply(full) if full is not None else None
            await self._merged(merged)

    async def _follow_plan(self, reader: StationReader) -> None:
        asked: tuple[int, bytes] | None = None
        asked_at = 0.0
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(PLAN_CHECK_S)
            plan = self.status.plan if self.status is not None else None
            if plan is None or not plan.id:
                continue
            pending = plan.done_count < plan.steps
            if asked != (plan.id, plan.done) or (pending and loop.time() - asked_at >= PLAN_REFRESH_S):
                details = await reader.plan(plan.id)
                asked, asked_at = (plan.id, plan.done), loop.time()
                if details is not None and details != self.plan:
                    self.plan = details
                    await self._bump()

    async def _watch_silence(self) -> None:
        """A controller that stops publishing changes nothing by itself: the page must still say so."""
        said = False
        while True:
            await asyncio.sleep(SILENCE_CHECK_S)
            heard = self._heard_at
            silent = heard is not None and asyncio.get_running_loop().time() - heard > SILENT_AFTER_S
            if silent or said:
                await self._bump()  # the silence's length is shown, so it changes every check
            said = silent

    async def _follow_gantt(self) -> None:
        if self.run_gantt is None:
            self.gantt = no_gantt("no recording directory given")
            await self._bump()
            return
        while True:
            try:
                drawn = await asyncio.to_thread(self.run_gantt.read)
            except Exception as exc:  # a recording mid-write, a model that changed: the rest of the page goes on
                log.warning("the run's Gantt data: %s: %s", type(exc).__name__, exc)
                drawn = no_gantt(f"the run's recording could not be read: {type(exc).__name__}: {exc}")
            if drawn != self.gantt:
                self.gantt = drawn
                await self._bump()
            await asyncio.sleep(GANTT_S)
