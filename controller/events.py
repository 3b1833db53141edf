"""The controller's event log: what it decided and noticed (replans, plans found, requests answered, hubs
gone, forbidden states), one `emit()` for every part of the controller.

It keeps the newest `bound` events: a controller that runs for weeks logs without end, and its readers
(the status feed, the run recording) follow it with cursors and only ever need what is new to them.
A cursor is the running count of events at the time of reading; `since(cursor)` answers the events
after it that are still held and says how many of them the bound had already dropped.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import islice

from common.wire.ctl import ConsoleEvent

EVENT_LOG_BOUND = 1000  # events held: a status shows the last 20, the recording reads after every step


@dataclass(frozen=True)
class EventsSince:
    """The events after a cursor, oldest first, and the cursor to read on from."""

    events: list[ConsoleEvent]
    cursor: int
    missed: int = 0  # events after the old cursor the bound dropped before they were read


class EventLog:
    def __init__(self, bound: int = EVENT_LOG_BOUND) -> None:
        if bound < 1:
            raise ValueError(f"an event log holds at least one event, not {bound}")
        self._held: deque[ConsoleEvent] = deque(maxlen=bound)
        self.total = 0  # events emitted since the start, dropped ones included: the newest cursor
        self.faults = 0  # of which faults (`Event.fault`), for the run's summary

    def emit(self, event: ConsoleEvent) -> None:
        self._held.append(event)
        self.total += 1
        if event.fault:
            self.faults += 1

    def since(self, cursor: int) -> EventsSince:
        """The events emitted after `cursor` (a `total` read earlier) that are still held."""
        new = max(0, self.total - cursor)
        held = min(new, len(self._held))
        return EventsSince(self._newest(held), self.total, new - held)

    def recent(self, count: int) -> list[ConsoleEvent]:
        """The newest `count` events held, oldest first."""
        return self._newest(min(max(0, count), len(self._held)))

    def _newest(self, count: int) -> list[ConsoleEvent]:
        # From the newest end: a reader that is up to date copies nothing of the whole log.
        newest = list(islice(reversed(self._held), count))
        newest.reverse()
        return newest

    def __iter__(self) -> Iterator[ConsoleEvent]:
        """The events held, oldest first."""
        return iter(self._held)
