"""`MemoryBus`: the `Bus` in memory, so that hubs, a controller and consoles run in one test process.

    hub = MemoryHub()
    async with MemoryBus(hub) as controller_bus, MemoryBus(hub) as hub_bus:
        ...  # as if each were a process on the station's Zenoh network

Buses made on one `MemoryHub` see each other as Zenoh peers on one network do
(common/bus/protocol.py lists the semantics):

* key expressions with `*` (one chunk) and `**` (any number of chunks), matched (and
  for queries intersected) as Zenoh does; `$*` and the other Zenoh extras are refused,
  and so is publishing on a wildcard key (which Zenoh allows, and statehub never does);
* every delivery (samples, liveliness events, the start of a query handler) happens on
  the event loop after the call that caused it returns, never inside it: `publish`
  schedules the delivery with `loop.call_soon`, and the subscription's `Inbox` wakes its
  consumer through the same path as Zenoh's threads do, with the same coalescing;
* who receives is decided when the sample is published: a subscription declared later
  does not see it, one closed meanwhile drops it;
* a liveliness token goes when it is undeclared or its bus closes (a process that dies);
  a key with several tokens is alive until the last goes;
* `get` replies are consolidated as Zenoh's default does: the last reply per key.

A hub serves the buses of one event loop (a second loop is refused).
"""

from __future__ import annotations

import asyncio
import functools
import itertools
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from common.bus.inbox import Inbox
from common.bus.protocol import (
    BusClosed,
    LivelinessEvent,
    Queryable,
    QueryHandler,
    Reply,
    Request,
    Sample,
    Subscription,
    Token,
    serve_query,
)
from common.wire.keys import KeyExprError

T = TypeVar("T")
_WILD = ("*", "**")


def key_chunks(key: str, *, concrete: bool = False) -> tuple[str, ...]:
    """The chunks of a key expression; KeyExprError for one Zenoh would refuse (or a wildcard where
    a concrete key is needed)."""
    chunks = tuple(key.split("/"))
    if not key or any(not c for c in chunks):
        raise KeyExprError(f"invalid key expression {key!r}: empty, or an empty chunk ('//', or '/' at an end)")
    for chunk in chunks:
        if chunk not in _WILD and any(c in chunk for c in "*$?#"):
            raise KeyExprError(f"invalid key expression {key!r}: chunk {chunk!r} (a wildcard is a whole chunk, "
                               f"'*' or '**'; '?' and '#' are not allowed)")
    if any(a == b == "**" for a, b in itertools.pairwise(chunks)):
        raise KeyExprError(f"invalid key expression {key!r}: '**/**' (write '**')")
    if concrete and any(c in _WILD for c in chunks):
        raise KeyExprError(f"{key!r} holds a wildcard where a concrete key is needed")
    return chunks


@functools.lru_cache(maxsize=65536)
def intersects(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    """Whether some concrete key matches both key expressions (for a concrete `b`: whether `a` matches it)."""
    if not a or not b:
        return all(c == "**" for c in a + b)
    if a[0] == "**":
        return intersects(a[1:], b) or intersects(a, b[1:])
    if b[0] == "**":
        return intersects(a, b[1:]) or intersects(a[1:], b)
    return (a[0] == b[0] or "*" in (a[0], b[0])) and intersects(a[1:], b[1:])


@dataclass(eq=False)
class _Route(Generic[T]):
    """A subscription (or liveliness watch) of one bus, as the hub routes to it."""

    chunks: tuple[str, ...]
    inbox: Inbox[T]


@dataclass(eq=False)
class _Served:
    """A queryable of one bus."""

    chunks: tuple[str, ...]
    key: str
    handler: QueryHandler
    bus: MemoryBus


class MemoryHub:
    """The network that the `MemoryBus`es made on it share (one event loop)."""

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self.subscribers: set[_Route[Sample]] = set()
        self.watchers: set[_Route[LivelinessEvent]] = set()
        self.queryables: set[_Served] = set()
        self.tokens: Counter[str] = Counter()  # alive tokens per key (several buses may declare one key)

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        if self._loop is not None and self._loop is not loop and not self._loop.is_closed():
            raise RuntimeError("a MemoryHub serves the buses of one event loop; this bus opened on another")
        self._loop = loop

    def _later(self, deliveries: list[tuple[Inbox[Any], str, Any]]) -> None:
        """Hand items to inboxes once the caller has returned to the loop (as Zenoh's threads would)."""
        if deliveries and self._loop is not None:
            self._loop.call_soon(_deliver, deliveries)

    def publish(self, key: str, payload: bytes) -> None:
        chunks = key_chunks(key, concrete=True)
        sample = Sample(key, payload)
        self._later([(r.inbox, key, sample) for r in self.subscribers if intersects(r.chunks, chunks)])

    def token_changed(self, key: str, alive: bool) -> None:
        self.tokens[key] += 1 if alive else -1
        if self.tokens[key] == (1 if alive else 0):  # the first token of the key came, or the last went
            chunks = key_chunks(key)
            event = LivelinessEvent(key, alive)
            self._later([(w.inbox, key, event) for w in self.watchers if intersects(w.chunks, chunks)])
        if not self.tokens[key]:
            del self.tokens[key]

    def alive(self, chunks: tuple[str, ...]) -> list[str]:
        return [key for key in self.tokens if intersects(chunks, key_chunks(key))]

    def watch(self, route: _Route[LivelinessEvent], history: bool) -> None:
        self.watchers.add(route)
        if history:
            self._later([(route.inbox, key, LivelinessEvent(key, True)) for key in self.alive(route.chunks)])


def _deliver(deliveries: list[tuple[Inbox[Any], str, Any]]) -> None:
    for inbox, key, item in deliveries:
        inbox.put(key, item)


class _Query:
    """One `get` under way: the replies its queryables give until the querier stops waiting."""

    def __init__(self, request: Request) -> None:
        self.request = request
        self.chunks = key_chunks(request.key)
        self.replies: dict[str, Reply] = {}  # the last per key (Zenoh's default consolidation)
        self.errors: list[Reply] = []

    def reply(self, key: str, payload: bytes) -> None:
        if not intersects(key_chunks(key), self.chunks):
            raise KeyExprError(f"reply key {key!r} does not match the query {self.request.key!r}")
        self.replies[key] = Reply(key, bytes(payload))

    def reply_err(self, message: bytes) -> None:
        self.errors.append(Reply("", message, ok=False))

    def answers(self) -> list[Reply]:
        return [*self.replies.values(), *self.errors]


class MemoryBus:
    """A `Bus` on a `MemoryHub`: use as `async with MemoryBus(hub) as bus:`."""

    def __init__(self, hub: MemoryHub) -> None:
        self.hub = hub
        self._loop: asyncio.AbstractEventLoop | None = None
        self._open = False
        self._declared: set[Subscription[Any] | Token | Queryable] = set()
        self._tasks: set[asyncio.Task[None]] = set()

    # lifecycle
    async def open(self) -> MemoryBus:
        self._loop = asyncio.get_running_loop()
        self.hub.attach(self._loop)
        self._open = True
        return self

    async def close(self) -> None:
        if not self._open:
            return
        self._open = False
        for task in list(self._tasks):
            task.cancel()
        for item in list(self._declared):
            if isinstance(item, Subscription):
                item.close()
            else:
                item.undeclare()
        await asyncio.sleep(0)  # the handlers see their cancellation before the bus is gone

    async def __aenter__(self) -> MemoryBus:
        return await self.open()

    async def __aexit__(self, *_exc: object) -> None:
        await self.close()

    def _running_loop(self) -> asyncio.AbstractEventLoop:
        if not self._open or self._loop is None:
            raise BusClosed("the bus is not open")
        return self._loop

    def _withdraw(self, item: Subscription[Any] | Token | Queryable, routes: set[Any], route: object) -> None:
        self._declared.discard(item)
        routes.discard(route)

    # publish / subscribe
    def publish(self, key: str, payload: bytes, *, block: bool = False) -> None:
        """See `Bus.publish`; nothing is ever congested here, so `block` changes nothing."""
        self._running_loop()
        self.hub.publish(key, bytes(payload))

    def subscribe(self, key: str, *, coalesce: bool = True, maxlen: int | None = 10_000, batch_s: float = 0.0,
                  expect: Iterable[str] = ()) -> Subscription[Sample]:
        """See `Bus.subscribe`; `expect` is a Zenoh routing hint, unused here."""
        route: _Route[Sample] = _Route(key_chunks(key), Inbox(self._running_loop(), coalesce, maxlen, batch_s))
        sub = Subscription(key, route.inbox, lambda: self._withdraw(sub, self.hub.subscribers, route))
        self.hub.subscribers.add(route)
        self._declared.add(sub)
        return sub

    # liveliness
    def declare_liveliness(self, key: str) -> Token:
        self._running_loop()
        key_chunks(key, concrete=True)

        def withdraw() -> None:
            self._declared.discard(token)
            self.hub.token_changed(key, False)

        token = Token(key, withdraw)
        self.hub.token_changed(key, True)
        self._declared.add(token)
        return token

    def watch_liveliness(self, key: str, *, history: bool = True) -> Subscription[LivelinessEvent]:
        """See `Bus.watch_liveliness`."""
        route: _Route[LivelinessEvent] = _Route(key_chunks(key), Inbox(self._running_loop(), False, 10_000))
        sub = Subscription(key, route.inbox, lambda: self._withdraw(sub, self.hub.watchers, route))
        self.hub.watch(route, history)
        self._declared.add(sub)
        return sub

    async def alive_tokens(self, key: str, timeout: float = 1.0) -> set[str]:
        """The keys of the liveliness tokens matching `key` alive now."""
        self._running_loop()
        chunks = key_chunks(key)
        await asyncio.sleep(0)  # an answer comes back over the network, never at once
        return set(self.hub.alive(chunks))

    # query / reply
    async def get(self, selector: str, *, payload: bytes | None = None, timeout: float = 1.0) -> list[Reply]:
        """See `Bus.get`: every matching queryable (this bus's own too) is asked; a handler still
        running after `timeout` goes on, but its replies are not waited for."""
        self._running_loop()
        key, _, parameters = selector.partition("?")
        query = _Query(Request(key, parameters, payload))
        serving = [q.bus._serve(q, query) for q in self.hub.queryables if intersects(q.chunks, query.chunks)]
        if serving:
            await asyncio.wait(serving, timeout=timeout)
        else:
            await asyncio.sleep(0)
        return query.answers()

    def _serve(self, served: _Served, query: _Query) -> asyncio.Task[None]:
        task = self._running_loop().create_task(  # starts on a later turn of the loop, not inside `get`
            serve_query(served.handler, query.request, served.key, query.reply, query.reply_err))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    def declare_queryable(self, key: str, handler: QueryHandler) -> Queryable:
        """See `Bus.declare_queryable`."""
        self._running_loop()
        served = _Served(key_chunks(key), key, handler, self)
        queryable = Queryable(key, lambda: self._withdraw(queryable, self.hub.queryables, served))
        self.hub.queryables.add(served)
        self._declared.add(queryable)
        return queryable
