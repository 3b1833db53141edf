"""The station bus as the processes see it: the `Bus` protocol and what travels over it.

Hubs, the controller, consoles and tools are written against `Bus`; two implementations
keep its semantics:

* `ZenohBus` (common/bus/zenoh_bus.py): one Zenoh session, its callbacks handed from zenoh's
  threads to the event loop (common/bus/inbox.py). What every process runs.
* `MemoryBus` (common/bus/memory_bus.py): buses sharing one in-memory `MemoryHub` in one event
  loop, so that hubs, a controller and a console run together in one test process.

Semantics both keep:

* `publish` puts a payload on a concrete key; every subscription whose key expression
  (`*` one chunk, `**` any number) matches receives it, the publisher's own included.
  Delivery is asynchronous, on the subscriber's event loop: never inside `publish`.
* A subscription is an async iterator (`Subscription`); by default it coalesces: a slow
  consumer sees only the newest sample per key. `batch_s` / `batches()` for streams.
* `declare_queryable` serves `get`s with an async handler run on the loop; an exception
  in the handler is an error `Reply`. `get` returns the replies that came within `timeout`.
* `declare_liveliness` declares a token that lives until it is undeclared or its bus
  closes (or, over Zenoh, its process dies or freezes past the lease);
  `watch_liveliness` reports each token matching a key expression appearing and going.
* `close` undeclares everything the bus declared; then every call raises `BusClosed`.

Usage:

    async with ZenohBus(zenoh_config("peer", connect=["tcp/decs.local:7447"])) as bus:
        bus.declare_liveliness(keys.alive("pi-tool"))
        async for sample in bus.subscribe(keys.cmd("nr")):   # newest per key
            ...
        async for batch in bus.subscribe(keys.all_state, batch_s=0.002).batches():  # lists
            ...
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass
from typing import Protocol

from common.bus.inbox import BusClosed, BusError, Subscription

log = logging.getLogger("common.bus.protocol")

__all__ = ["Bus", "BusClosed", "BusError", "LivelinessEvent", "QueryHandler", "Queryable", "Reply", "Request",
           "Sample", "Subscription", "Token", "serve_query"]


# --- what is handed to the loop ------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Sample:
    key: str
    payload: bytes


@dataclass(frozen=True, slots=True)
class LivelinessEvent:
    key: str
    alive: bool  # False: the token was undeclared, or its session died or froze (lease)


@dataclass(frozen=True, slots=True)
class Reply:
    key: str  # the replier's key; "" for an error reply
    payload: bytes
    ok: bool = True  # False: the queryable answered with an error (payload is its message)


@dataclass(frozen=True, slots=True)
class Request:
    """A query as a queryable handler sees it."""

    key: str  # the query's key expression (may hold wildcards)
    parameters: str  # the selector's parameters, `a=1;b=2`
    payload: bytes | None


QueryHandler = Callable[[Request], Awaitable[bytes | Iterable[tuple[str, bytes]] | None]]


# --- what a bus declares ---------------------------------------------------------------------

class _Declared:
    """A declaration withdrawn once, by `undeclare()` or by closing its bus."""

    def __init__(self, key: str, release: Callable[[], None]) -> None:
        self.key = key
        self._release: Callable[[], None] | None = release

    def undeclare(self) -> None:
        release, self._release = self._release, None
        if release is not None:
            release()


class Token(_Declared):
    """A declared liveliness token; `undeclare()` (or closing the bus) withdraws it."""


class Queryable(_Declared):
    """A declared queryable; `undeclare()` (or closing the bus) withdraws it."""


def is_concrete(key: str) -> bool:
    return "*" not in key and "$" not in key


async def serve_query(handler: QueryHandler, request: Request, key: str, reply: Callable[[str, bytes], None],
                      reply_err: Callable[[bytes], None]) -> None:
    """Run `handler` on `request` (a query to the queryable declared on `key`) and answer through `reply`.

    The handler returns the payload (bytes) to reply on the query's key (or on `key` when
    the query holds wildcards), a list of `(key, payload)` for several replies, or None
    for no reply. An exception becomes an error reply and is logged."""
    try:
        result = await handler(request)
        if result is None:
            return
        if isinstance(result, bytes | bytearray | memoryview):
            reply(request.key if is_concrete(request.key) else key, bytes(result))
        else:
            for reply_key, payload in result:
                reply(reply_key, payload)
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        selector = f"{request.key}?{request.parameters}" if request.parameters else request.key
        log.exception("queryable %s failed on %s", key, selector)
        reply_err(f"{type(exc).__name__}: {exc}".encode())


# --- the protocol --------------------------------------------------------------------------------

class Bus(Protocol):
    """What hubs, the controller, consoles and tools use of the station bus.

    Every method is called from the event loop's thread; every callback and handler runs there."""

    def publish(self, key: str, payload: bytes, *, block: bool = False) -> None:
        """Put `payload` on the concrete key `key`. A congested link drops the publication
        (the next one replaces it) unless `block`: then the loop waits for room."""

    def subscribe(self, key: str, *, coalesce: bool = True, maxlen: int | None = 10_000, batch_s: float = 0.0,
                  expect: Iterable[str] = ()) -> Subscription[Sample]:
        """Samples on `key` (wildcards allowed). `coalesce`: a slow consumer gets only the newest
        sample per concrete key; otherwise every sample in order (the oldest dropped beyond `maxlen`).
        `batch_s`: the least time between two batches of `get_batch()`/`batches()`. `expect`: the
        concrete keys this subscription will see (a routing hint; it changes nothing delivered)."""
        ...

    def declare_liveliness(self, key: str) -> Token:
        """A liveliness token on `key`, alive until undeclared or the bus closes."""
        ...

    def watch_liveliness(self, key: str, *, history: bool = True) -> Subscription[LivelinessEvent]:
        """Alive/gone events of tokens matching `key`. `history`: first report the tokens alive now.
        Every event is kept (a restart shows as gone then alive)."""
        ...

    async def alive_tokens(self, key: str, timeout: float = 1.0) -> set[str]:
        """The keys of the liveliness tokens matching `key` alive now."""
        ...

    async def get(self, selector: str, *, payload: bytes | None = None, timeout: float = 1.0) -> list[Reply]:
        """Ask the queryables matching `selector` (`key?a=1`); all replies that arrive within `timeout`."""
        ...

    def declare_queryable(self, key: str, handler: QueryHandler) -> Queryable:
        """Serve queries on `key` with `async handler(request)`, run on the loop (see `serve_query`)."""
        ...

    async def close(self) -> None:
        """Undeclare everything this bus declared; later calls raise BusClosed."""
