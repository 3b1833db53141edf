"""The thread-safe hand-over from a bus's delivery side to one asyncio consumer, and `Subscription`.

zenoh-python has no asyncio API: every callback runs on a zenoh thread. An `Inbox`
hands data to the event loop with `loop.call_soon_threadsafe`, at most one wake-up per
consumer wait, so a burst of samples costs one wake-up and a slow consumer only ever
sees the newest sample per key (`coalesce=True`, the default for state-based traffic).
The in-memory bus (common/bus/memory_bus.py) fills its inboxes from the loop itself, through
the same wake-up path, so both buses deliver with the same semantics.

High-rate streams (the controller ingests every hub's state) take whole batches:
`get_batch()` / `batches()` return everything pending in one list, and `batch_s`
spaces the batches so that samples arriving meanwhile join the next one instead of
waking the loop one by one.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections import deque
from collections.abc import AsyncIterator, Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class BusError(RuntimeError):
    """The bus could not do what was asked (e.g. its session closed under a query)."""


class BusClosed(BusError):
    """The bus (or one of its subscriptions) is closed."""


class Inbox(Generic[T]):
    """A thread-safe buffer from the bus's delivery threads (or the loop itself) to one asyncio consumer.

    `coalesce`: keep only the newest item per key (state-based traffic: an older state
    is worthless once a newer one arrived). Otherwise keep every item, oldest dropped
    beyond `maxlen`. The producer wakes the loop only when the consumer is waiting and
    no wake-up is already scheduled, so bursts cost one cross-thread call. `batch_s`:
    `get_batch()` hands out at most one batch per `batch_s` (closing ends the wait at
    once), so a steady stream arrives in batches rather than as one wake-up per sample,
    and a consumer that cannot keep up still yields to the loop between batches.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, coalesce: bool, maxlen: int | None,
                 batch_s: float = 0.0) -> None:
        self._loop = loop
        self._coalesce = coalesce
        self._batch_s = batch_s
        self._lock = threading.Lock()
        self._latest: dict[str, T] = {}
        self._queue: deque[T] = deque(maxlen=maxlen)
        self._waiter: asyncio.Future[None] | None = None
        self._wake_scheduled = False
        self._not_before = 0.0  # loop time before which get_batch() hands out no batch (batch_s)
        self._closed = False
        self.dropped = 0  # samples replaced (coalesced) or pushed out (maxlen) before being read

    # producer side: any thread
    def put(self, key: str, item: T) -> None:
        with self._lock:
            if self._closed:
                return
            if self._coalesce:
                if key in self._latest:
                    self.dropped += 1
                self._latest[key] = item
            else:
                if self._queue.maxlen is not None and len(self._queue) == self._queue.maxlen:
                    self.dropped += 1
                self._queue.append(item)
            wake = self._waiter is not None and not self._wake_scheduled
            if wake:
                self._wake_scheduled = True
        if wake:
            self._call_soon(self._wake)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            wake = self._waiter is not None
        if wake:  # at once, even if a wake-up is already scheduled for the end of `batch_s`
            self._call_soon(self._wake_now)

    def _call_soon(self, callback: Callable[[], None]) -> None:
        # RuntimeError: the loop is closed, the process is shutting down, nobody waits any more.
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(callback)

    # consumer side: the loop thread
    def _wake(self) -> None:
        # Too soon after the last batch: wake later, and let what arrives meanwhile join the batch.
        # `_wake_scheduled` stays set until then, so producers make no further cross-thread calls.
        if not self._closed and self._loop.time() < self._not_before:
            self._loop.call_at(self._not_before, self._wake_now)
        else:
            self._wake_now()

    def _wake_now(self) -> None:
        with self._lock:
            self._wake_scheduled = False
            waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _pop_locked(self) -> T | None:
        if self._latest:
            key = next(iter(self._latest))
            return self._latest.pop(key)
        if self._queue:
            return self._queue.popleft()
        return None

    def _take_locked(self) -> list[T]:
        # One mode is in use per inbox, so at most one of the two holds anything.
        if self._latest:
            items = list(self._latest.values())
            self._latest.clear()
            return items
        items = list(self._queue)
        self._queue.clear()
        return items

    def take_all(self) -> list[T]:
        with self._lock:
            return self._take_locked()

    async def _await_wake(self, waiter: asyncio.Future[None]) -> None:
        try:
            await waiter
        finally:
            with self._lock:
                self._waiter = None

    async def get(self) -> T:
        while True:
            with self._lock:
                item = self._pop_locked()
                if item is not None:
                    return item
                if self._closed:
                    raise BusClosed("subscription closed")
                waiter = self._waiter = self._loop.create_future()
            await self._await_wake(waiter)

    async def get_batch(self) -> list[T]:
        while True:
            with self._lock:
                due = self._closed or self._loop.time() >= self._not_before
                items = self._take_locked() if due else []
                if items:
                    break
                if self._closed:
                    raise BusClosed("subscription closed")
                waiter = self._waiter = self._loop.create_future()
                if not due and (self._latest or self._queue) and not self._wake_scheduled:
                    self._wake_scheduled = True  # pending, but too soon after the last batch
                    self._loop.call_at(self._not_before, self._wake_now)
            await self._await_wake(waiter)
        if self._batch_s > 0:
            self._not_before = self._loop.time() + self._batch_s
        return items


class Subscription(Generic[T]):
    """An async iterator over samples (or liveliness events) of one key expression.

    `async for s in sub` ends when the subscription or the bus is closed.
    `get_batch()` waits for what is pending and returns all of it; `batches()` iterates
    over such lists. `take_all()` returns what is pending without waiting. `release`
    withdraws the subscription from its bus; `close()` calls it once.
    """

    def __init__(self, key: str, inbox: Inbox[T], release: Callable[[], None]) -> None:
        self.key = key
        self._inbox = inbox
        self._release: Callable[[], None] | None = release

    @property
    def dropped(self) -> int:
        return self._inbox.dropped

    async def get(self) -> T:
        """The next item; raises BusClosed once closed."""
        return await self._inbox.get()

    async def get_batch(self) -> list[T]:
        """Everything pending (at least one item), oldest first; raises BusClosed once closed."""
        return await self._inbox.get_batch()

    async def batches(self) -> AsyncIterator[list[T]]:
        """`get_batch()` until the subscription or the bus is closed."""
        while True:
            try:
                batch = await self._inbox.get_batch()
            except BusClosed:
                return
            yield batch

    def take_all(self) -> list[T]:
        return self._inbox.take_all()

    def __aiter__(self) -> AsyncIterator[T]:
        return self

    async def __anext__(self) -> T:
        try:
            return await self._inbox.get()
        except BusClosed:
            raise StopAsyncIteration from None

    def close(self) -> None:
        self._inbox.close()
        release, self._release = self._release, None
        if release is not None:
            release()

    async def __aenter__(self) -> Subscription[T]:
        return self

    async def __aexit__(self, *_exc: object) -> None:
        self.close()
