"""The Zenoh session, the station's key expressions, and one asyncio bridge over zenoh-python.

Key expressions (DESIGN.md §5), built by `Keys`:

    {station}/res/{resource}/cmd     controller -> hub   command (messages.Codec)
    {station}/res/{resource}/state   hub -> controller   measured state + mirror
    {station}/hub/{hub}/alive        liveliness token of a running hub
    {station}/hub/{hub}/selftest     self-test report
    {station}/ctl/...                controller: global state, plans, health, console

zenoh-python has no asyncio API: every callback runs on a zenoh thread. `Bus` hands
data to the event loop with `loop.call_soon_threadsafe`, at most one wake-up per
consumer wait, so a burst of samples costs one wake-up and a slow consumer only
ever sees the newest sample per key (`coalesce=True`, the default for state-based
traffic). Callbacks never call zenoh and never block.

High-rate streams (the controller ingests every hub's state) take whole batches:
`get_batch()` / `batches()` return everything pending in one list, and `batch_s`
spaces the batches so that samples arriving meanwhile join the next one instead of
waking the loop one by one. `expect` names the concrete keys a
wildcard subscription will see: zenoh then routes each sample through a declared
key instead of matching it against every key the session knows, a cost that
otherwise grows with the number of keys this session publishes (measured: the
receive threads of a controller publishing 300 command keys spent ~40 % of a core
matching 15,000 states/s; ~3 % with the state keys declared).

Publications are dropped (after ~1 ms) when the link is congested rather than
stalling the loop: right for state-based traffic, where the next one replaces a
lost one; `publish(..., block=True)` for the rare message that must arrive.

Liveness: a peer that dies closes its TCP link and its tokens vanish at once; a
peer that freezes (SIGSTOP, a hung Pi) keeps the link open, so it is noticed only
when its transport lease expires. `zenoh_config` sets the lease (default 2 s) and
the keep-alive rate so that a frozen hub is declared gone within about the lease
(the lease a process declares is the one its neighbours apply to it). A peer whose
link closes, or that starts before the process it connects to, keeps retrying in
the background and comes back by itself.

Usage:

    async with Bus(zenoh_config("peer", connect=["tcp/decs.local:7447"])) as bus:
        bus.declare_liveliness(keys.alive("pi-tool"))
        async for sample in bus.subscribe(keys.cmd("nr")):   # newest per key
            ...
        async for batch in bus.subscribe(keys.all_state, batch_s=0.002).batches():  # lists
            ...
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Literal, Protocol, TypeVar

import zenoh

log = logging.getLogger(__name__)

DEFAULT_LEASE_MS = 2000
# Keep-alives per lease period. 4 is zenoh's default; with a 2 s lease a keep-alive
# goes out every 500 ms, so one lost keep-alive never expires a healthy link.
KEEP_ALIVES_PER_LEASE = 4

Mode = Literal["peer", "client"]


# --- key expressions ------------------------------------------------------------------

_FORBIDDEN_IN_NAME = set("/*$?#@ ") | {"\t", "\n"}


class KeyExprError(ValueError):
    """A station, resource or hub name that cannot be one chunk of a key expression."""


def check_name(what: str, name: str) -> str:
    """A name used as one key chunk: non-empty, no '/', no wildcard or reserved character."""
    if not name or any(c in _FORBIDDEN_IN_NAME for c in name):
        raise KeyExprError(f"{what} name {name!r} cannot be used in a key expression "
                           f"(empty, or contains one of / * $ ? # @ or whitespace)")
    return name


@dataclass(frozen=True)
class Keys:
    """The key expressions of one station. Methods give concrete keys, `all_*` wildcard ones."""

    station: str

    def __post_init__(self) -> None:
        check_name("station", self.station)

    # resources
    def cmd(self, resource: str) -> str:
        return f"{self.station}/res/{check_name('resource', resource)}/cmd"

    def state(self, resource: str) -> str:
        return f"{self.station}/res/{check_name('resource', resource)}/state"

    @property
    def all_cmd(self) -> str:
        return f"{self.station}/res/*/cmd"

    @property
    def all_state(self) -> str:
        return f"{self.station}/res/*/state"

    # hubs
    def alive(self, hub: str) -> str:
        return f"{self.station}/hub/{check_name('hub', hub)}/alive"

    def selftest(self, hub: str) -> str:
        return f"{self.station}/hub/{check_name('hub', hub)}/selftest"

    @property
    def all_alive(self) -> str:
        return f"{self.station}/hub/*/alive"

    @property
    def all_selftest(self) -> str:
        return f"{self.station}/hub/*/selftest"

    # controller
    def ctl(self, *parts: str) -> str:
        """`{station}/ctl/a/b` for ctl("a", "b"); parts may hold '/' (e.g. "console/request")."""
        if not parts or any(not p or p.startswith("/") or p.endswith("/") for p in parts):
            raise KeyExprError(f"bad ctl key parts {parts!r}")
        return "/".join((self.station, "ctl", *parts))

    # parsing
    def resource_of(self, key: str) -> str | None:
        """`nr` for `station/res/nr/state` (or `/cmd`), else None."""
        parts = key.split("/")
        if len(parts) == 4 and parts[0] == self.station and parts[1] == "res" and parts[3] in ("cmd", "state"):
            return parts[2]
        return None

    def hub_of(self, key: str) -> str | None:
        """`pi-tool` for `station/hub/pi-tool/alive` (or `/selftest`), else None."""
        parts = key.split("/")
        if len(parts) == 4 and parts[0] == self.station and parts[1] == "hub":
            return parts[2]
        return None


# --- zenoh configuration ----------------------------------------------------------------

class NetworkSettings(Protocol):
    """What `zenoh_config_for` needs; `common.config.NetworkConfig` satisfies it."""

    mode: str
    listen: Sequence[str]
    connect: Sequence[str]
    lease_ms: int


def zenoh_config(mode: Mode | str = "peer", listen: Iterable[str] = (), connect: Iterable[str] = (),
                 lease_ms: int = DEFAULT_LEASE_MS, *, gossip: bool = True) -> zenoh.Config:
    """A zenoh config for a statehub process.

    * `mode`: "peer" (direct links on loopback or the station LAN; the controller
      listens, hubs connect to it) or "client" (through zenoh routers given in `connect`).
    * `listen` / `connect`: zenoh endpoints (`tcp/127.0.0.1:7447`); an empty `listen`
      means no listener at all (zenoh's default would be a random port on every interface).
    * multicast scouting is off: a station's peers are named, never discovered by
      multicast (which also leaks between test runs and between stations on one LAN).
      Gossip scouting stays on in peer mode so peers that share a listener learn of each other.
    * `lease_ms`: the transport lease this process declares to its neighbours; they
      close the link (and drop its liveliness tokens) when it is silent that long.
    """
    if mode not in ("peer", "client"):
        raise ValueError(f"zenoh mode must be 'peer' or 'client', not {mode!r}")
    if lease_ms < 100:
        raise ValueError(f"lease_ms={lease_ms} is too short to survive a scheduling hiccup (>= 100 ms)")
    listen, connect = list(listen), list(connect)
    if mode == "client" and listen:
        raise ValueError("a zenoh client cannot listen: remove `listen` or use mode 'peer'")
    config = zenoh.Config()
    settings: dict[str, Any] = {
        "mode": mode,
        "connect/endpoints": connect,
        "scouting/multicast/enabled": False,
        "scouting/gossip/enabled": gossip and mode == "peer",
        "transport/link/tx/lease": lease_ms,
        "transport/link/tx/keep_alive": KEEP_ALIVES_PER_LEASE,
        # Keep retrying a connect endpoint in the background (a hub may boot before the
        # controller); a client's open() still fails without a router, which Bus retries.
        "connect/exit_on_failure": False,
        "connect/retry": {"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2},
    }
    if mode == "peer":
        settings["listen/endpoints"] = listen
    # Leave connect/timeout_ms alone: a peer's open() then returns after ~0.5 s even when
    # nobody listens yet, and keeps retrying in the background (timeout 0 stops the retries).
    for key, value in settings.items():
        config.insert_json5(key, json.dumps(value))
    return config


def zenoh_config_for(network: NetworkSettings) -> zenoh.Config:
    return zenoh_config(network.mode, network.listen, network.connect, network.lease_ms)


# --- data handed to the loop --------------------------------------------------------------

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


T = TypeVar("T", Sample, LivelinessEvent)


class BusClosed(RuntimeError):
    """The bus (or one of its subscriptions) is closed."""


class _Inbox(Generic[T]):
    """A thread-safe buffer from zenoh threads to one asyncio consumer.

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
    over such lists. `take_all()` returns what is pending without waiting.
    """

    def __init__(self, bus: Bus, key: str, inbox: _Inbox[T]) -> None:
        self.key = key
        self._bus = bus
        self._inbox = inbox
        self._zenoh: Any = None
        self._keyexprs: list[zenoh.KeyExpr] = []  # `expect`ed keys, undeclared with the subscription

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
        if self._zenoh is not None:
            handle, self._zenoh = self._zenoh, None
            self._bus._forget(self)
            with contextlib.suppress(zenoh.ZError):  # the session is already closed
                handle.undeclare()
        keyexprs, self._keyexprs = self._keyexprs, []
        for keyexpr in keyexprs:
            with contextlib.suppress(zenoh.ZError, BusClosed):
                self._bus.session.undeclare(keyexpr)

    async def __aenter__(self) -> Subscription[T]:
        return self

    async def __aexit__(self, *_exc: object) -> None:
        self.close()


class Token:
    """A declared liveliness token; `undeclare()` (or closing the bus) withdraws it."""

    def __init__(self, bus: Bus, key: str, handle: zenoh.LivelinessToken) -> None:
        self.key = key
        self._bus = bus
        self._handle: zenoh.LivelinessToken | None = handle

    def undeclare(self) -> None:
        if self._handle is not None:
            handle, self._handle = self._handle, None
            self._bus._forget(self)
            with contextlib.suppress(zenoh.ZError):
                handle.undeclare()


QueryHandler = Callable[[Request], Awaitable[bytes | Iterable[tuple[str, bytes]] | None]]


class Queryable:
    """A declared queryable; `undeclare()` (or closing the bus) withdraws it."""

    def __init__(self, bus: Bus, key: str) -> None:
        self.key = key
        self._bus = bus
        self._zenoh: Any = None

    def undeclare(self) -> None:
        if self._zenoh is not None:
            handle, self._zenoh = self._zenoh, None
            self._bus._forget(self)
            with contextlib.suppress(zenoh.ZError):
                handle.undeclare()


def _first_line(exc: BaseException) -> str:
    # zenoh errors end with the Rust source location: not for an operator.
    return str(exc).split(" at /", 1)[0].strip()


def _is_concrete(key: str) -> bool:
    return "*" not in key and "$" not in key


# --- the bus -------------------------------------------------------------------------------

class Bus:
    """One zenoh session bridged to asyncio. Use as `async with Bus(config) as bus:`.

    All methods are called from the event loop's thread. Closing the bus undeclares
    everything it declared and closes the session (before the loop goes away).
    """

    def __init__(self, config: zenoh.Config | None = None, *, open_timeout: float | None = None,
                 express: bool = False) -> None:
        """`open_timeout`: a client without a reachable router keeps retrying to open for this
        many seconds (None: forever; a peer never waits). `express`: one network
        frame per publication. Measured on loopback (tests/bench/bench_bus.py) batching
        costs no latency when the link is idle and carries ~6x the messages per second
        under load, so it is the default."""
        self._config = config if config is not None else zenoh_config()
        self._open_timeout = open_timeout
        self._express = express
        self._session: zenoh.Session | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._publishers: dict[tuple[str, bool], zenoh.Publisher] = {}
        self._declared: set[Subscription[Any] | Token | Queryable] = set()
        self._tasks: set[asyncio.Task[None]] = set()

    # lifecycle
    async def open(self) -> Bus:
        """Open the session. A client retries until a router answers (or `open_timeout`);
        a peer opens at once and connects in the background, but a listener that cannot
        bind (address in use, not ours) fails at once: that is a configuration error."""
        self._loop = asyncio.get_running_loop()
        client = json.loads(self._config.get_json("mode")) == "client"
        delay, waited = 0.25, 0.0
        while True:
            try:
                # zenoh.open blocks (connecting, scouting): keep it off the loop.
                self._session = await asyncio.to_thread(zenoh.open, self._config)
                return self
            except zenoh.ZError as exc:
                if not client or (self._open_timeout is not None and waited >= self._open_timeout):
                    raise ConnectionError(f"cannot open the zenoh session: {_first_line(exc)}") from None
                log.warning("no zenoh router yet (%s); retrying in %.1f s", _first_line(exc), delay)
                await asyncio.sleep(delay)
                waited += delay
                delay = min(delay * 2, 2.0)

    async def close(self) -> None:
        session, self._session = self._session, None
        if session is None:
            return
        for task in list(self._tasks):
            task.cancel()
        for item in list(self._declared):
            if isinstance(item, Subscription):
                item.close()
            else:
                item.undeclare()
        for pub in self._publishers.values():
            with contextlib.suppress(zenoh.ZError):
                pub.undeclare()
        self._publishers.clear()
        await asyncio.to_thread(session.close)

    async def __aenter__(self) -> Bus:
        return await self.open()

    async def __aexit__(self, *_exc: object) -> None:
        await self.close()

    @property
    def session(self) -> zenoh.Session:
        """The raw zenoh session (escape hatch; its callbacks run on zenoh threads)."""
        if self._session is None:
            raise BusClosed("the bus is not open")
        return self._session

    @property
    def zid(self) -> str:
        return str(self.session.zid())

    def _forget(self, item: object) -> None:
        self._declared.discard(item)  # type: ignore[arg-type]

    def _running_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise BusClosed("the bus is not open")
        return self._loop

    # publish / subscribe
    def publish(self, key: str, payload: bytes, *, block: bool = False) -> None:
        """Put `payload` on the concrete key `key` (a publisher is declared once per key).

        When the link is congested a publication is dropped after about a millisecond:
        right for state-based traffic, where the next publication replaces it, and the
        loop never stalls. `block=True` waits for room instead (for rare messages that
        must arrive, e.g. a self-test report); it may stall the loop while congested."""
        pub = self._publishers.get((key, block))
        if pub is None:
            congestion = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
            pub = self.session.declare_publisher(key, express=self._express, congestion_control=congestion)
            self._publishers[(key, block)] = pub
        pub.put(payload)

    def subscribe(self, key: str, *, coalesce: bool = True, maxlen: int | None = 10_000, batch_s: float = 0.0,
                  expect: Iterable[str] = ()) -> Subscription[Sample]:
        """Samples on `key` (wildcards allowed). `coalesce`: a slow consumer gets only the newest
        sample per concrete key; otherwise every sample in order (the oldest dropped beyond `maxlen`).
        `batch_s`: the least time between two batches of `get_batch()`/`batches()` (what arrives
        meanwhile joins the next batch; 0: a batch as soon as anything is pending). `expect`: concrete keys
        this subscription will see (e.g. every resource's state key under `res/*/state`), declared
        to zenoh so that it routes them without matching each sample against every known key."""
        inbox: _Inbox[Sample] = _Inbox(self._running_loop(), coalesce, maxlen, batch_s)

        def on_sample(sample: zenoh.Sample) -> None:  # zenoh thread: no zenoh calls, no blocking
            try:
                if sample.kind == zenoh.SampleKind.PUT:
                    concrete = str(sample.key_expr)
                    inbox.put(concrete, Sample(concrete, sample.payload.to_bytes()))
            except Exception:  # an exception must never escape into zenoh's thread
                log.exception("dropping a sample on %s", key)

        sub: Subscription[Sample] = Subscription(self, key, inbox)
        sub._keyexprs = [self.session.declare_keyexpr(k) for k in dict.fromkeys(expect)]
        sub._zenoh = self.session.declare_subscriber(key, on_sample)
        self._declared.add(sub)
        return sub

    # liveliness
    def declare_liveliness(self, key: str) -> Token:
        token = Token(self, key, self.session.liveliness().declare_token(key))
        self._declared.add(token)
        return token

    def watch_liveliness(self, key: str, *, history: bool = True) -> Subscription[LivelinessEvent]:
        """Alive/gone events of tokens matching `key`. `history`: first report the tokens alive now.
        Every event is kept (a restart shows as gone then alive)."""
        inbox: _Inbox[LivelinessEvent] = _Inbox(self._running_loop(), False, 10_000)

        def on_sample(sample: zenoh.Sample) -> None:  # zenoh thread
            try:
                concrete = str(sample.key_expr)
                inbox.put(concrete, LivelinessEvent(concrete, sample.kind == zenoh.SampleKind.PUT))
            except Exception:
                log.exception("dropping a liveliness event on %s", key)

        sub: Subscription[LivelinessEvent] = Subscription(self, key, inbox)
        sub._zenoh = self.session.liveliness().declare_subscriber(key, on_sample, history=history)
        self._declared.add(sub)
        return sub

    async def alive_tokens(self, key: str, timeout: float = 1.0) -> set[str]:
        """The keys of the liveliness tokens matching `key` alive now."""
        replies = await self._collect(lambda handler: self.session.liveliness().get(key, handler, timeout=timeout))
        return {r.key for r in replies if r.ok}

    # query / reply
    async def get(self, selector: str, *, payload: bytes | None = None, timeout: float = 1.0) -> list[Reply]:
        """Ask the queryables matching `selector` (`key?a=1`); all replies that arrive within `timeout`."""
        return await self._collect(lambda handler: self.session.get(selector, handler, payload=payload,
                                                                    timeout=timeout))

    async def _collect(self, start: Callable[[zenoh.handlers.Callback[zenoh.Reply]], None]) -> list[Reply]:
        loop = self._running_loop()
        done: asyncio.Future[None] = loop.create_future()
        replies: list[Reply] = []  # appended on a zenoh thread, read after `done`

        def on_reply(reply: zenoh.Reply) -> None:  # zenoh thread
            try:
                ok = reply.ok
                if ok is not None:
                    replies.append(Reply(str(ok.key_expr), ok.payload.to_bytes()))
                else:
                    err = reply.err
                    replies.append(Reply("", err.payload.to_bytes() if err is not None else b"", ok=False))
            except Exception:
                log.exception("dropping a reply")

        def on_done() -> None:  # zenoh thread: all replies in, or timed out
            def resolve() -> None:
                if not done.done():
                    done.set_result(None)
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(resolve)

        start(zenoh.handlers.Callback(on_reply, on_done))
        await done
        return replies

    def declare_queryable(self, key: str, handler: QueryHandler) -> Queryable:
        """Serve queries on `key` with `async handler(request)`, run on the loop.

        The handler returns the payload (bytes) to reply on the query's key (or on `key`
        when the query holds wildcards), a list of `(key, payload)` for several replies,
        or None for no reply. An exception becomes an error reply and is logged.
        """
        loop = self._running_loop()
        queryable = Queryable(self, key)

        async def serve(query: zenoh.Query) -> None:
            with query:  # finalizes the query (the querier stops waiting) however we leave
                try:
                    request = Request(str(query.key_expr), str(query.parameters),
                                      query.payload.to_bytes() if query.payload is not None else None)
                    result = await handler(request)
                    if result is None:
                        return
                    if isinstance(result, bytes | bytearray | memoryview):
                        reply_key = request.key if _is_concrete(request.key) else key
                        query.reply(reply_key, bytes(result))
                    else:
                        for reply_key, payload in result:
                            query.reply(reply_key, payload)
                except asyncio.CancelledError:
                    raise
                except Exception as exc:
                    log.exception("queryable %s failed on %s", key, query.selector)
                    query.reply_err(f"{type(exc).__name__}: {exc}".encode())

        def start(query: zenoh.Query) -> None:  # loop thread
            task = loop.create_task(serve(query))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

        def on_query(query: zenoh.Query) -> None:  # zenoh thread
            try:
                loop.call_soon_threadsafe(start, query)
            except RuntimeError:
                query.drop()  # the loop is gone: finalize at once so the querier does not wait

        queryable._zenoh = self.session.declare_queryable(key, on_query)
        self._declared.add(queryable)
        return queryable
