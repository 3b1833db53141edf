"""`ZenohBus`: the `Bus` over one Zenoh session, bridged to asyncio.

zenoh-python has no asyncio API: every callback runs on a zenoh thread. The callbacks
here only hand data to an `Inbox` (common/bus/inbox.py), which wakes the loop at most once
per consumer wait; they never call zenoh and never block. Queries are served by
handlers run as tasks on the loop.

`expect` (on `subscribe`) names the concrete keys a wildcard subscription will see:
zenoh then routes each sample through a declared key instead of matching it against
every key the session knows, a cost that otherwise grows with the number of keys this
session publishes (measured: the receive threads of a controller publishing 300
command keys spent ~40 % of a core matching 15,000 states/s; ~3 % with the state keys
declared).

Publications are dropped (after ~1 ms) when the link is congested rather than
stalling the loop: right for state-based traffic, where the next one replaces a lost
one; `publish(..., block=True)` for the rare message that must arrive.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from common.bus.inbox import Inbox
from common.bus.protocol import (
    BusClosed,
    BusError,
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
from common.bus.zenoh_config import ZenohConfig, is_client, zenoh_config

log = logging.getLogger("common.bus.protocol")

_Declaration = Subscription[Any] | Token | Queryable


def _first_line(exc: BaseException) -> str:
    # zenoh errors end with the Rust source location: not for an operator.
    return str(exc).split(" at /", 1)[0].strip()


class ZenohBus:
    """One zenoh session bridged to asyncio. Use as `async with ZenohBus(config) as bus:`.

    All methods are called from the event loop's thread. Closing the bus undeclares
    everything it declared and closes the session (before the loop goes away).
    """

    def __init__(self, config: ZenohConfig | None = None, *, open_timeout: float | None = None,
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
        self._declared: set[_Declaration] = set()
        self._tasks: set[asyncio.Task[None]] = set()

    # lifecycle
    async def open(self) -> ZenohBus:
        """Open the session. A client retries until a router answers (or `open_timeout`);
        a peer opens at once and connects in the background, but a listener that cannot
        bind (address in use, not ours) fails at once: that is a configuration error."""
        self._loop = asyncio.get_running_loop()
        client = is_client(self._config)
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

    async def __aenter__(self) -> ZenohBus:
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

    def peer_count(self) -> int:
        """How many zenoh peers this session is linked to."""
        return len(list(self.session.info.peers_zid()))

    def _running_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise BusClosed("the bus is not open")
        return self._loop

    def _release(self, item: _Declaration, undeclares: list[Callable[[], object]]) -> None:
        """Withdraw a declaration: forget it, then undeclare its zenoh handles (those of a
        closed session are gone already)."""
        self._declared.discard(item)
        for undeclare in undeclares:
            with contextlib.suppress(zenoh.ZError, BusClosed):
                undeclare()

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
        """See `Bus.subscribe`. `expect`ed keys are declared to zenoh, so that it routes them
        without matching each sample against every key this session knows."""
        inbox: Inbox[Sample] = Inbox(self._running_loop(), coalesce, maxlen, batch_s)

        def on_sample(sample: zenoh.Sample) -> None:  # zenoh thread: no zenoh calls, no blocking
            try:
                if sample.kind == zenoh.SampleKind.PUT:
                    concrete = str(sample.key_expr)
                    inbox.put(concrete, Sample(concrete, sample.payload.to_bytes()))
            except Exception:  # an exception must never escape into zenoh's thread
                log.exception("dropping a sample on %s", key)

        session = self.session
        undeclares: list[Callable[[], object]] = []
        sub: Subscription[Sample] = Subscription(key, inbox, lambda: self._release(sub, undeclares))
        keyexprs = [session.declare_keyexpr(k) for k in dict.fromkeys(expect)]
        undeclares.append(session.declare_subscriber(key, on_sample).undeclare)
        undeclares += [functools.partial(session.undeclare, keyexpr) for keyexpr in keyexprs]
        self._declared.add(sub)
        return sub

    # liveliness
    def declare_liveliness(self, key: str) -> Token:
        handle = self.session.liveliness().declare_token(key)
        token = Token(key, lambda: self._release(token, [handle.undeclare]))
        self._declared.add(token)
        return token

    def watch_liveliness(self, key: str, *, history: bool = True) -> Subscription[LivelinessEvent]:
        """See `Bus.watch_liveliness`."""
        inbox: Inbox[LivelinessEvent] = Inbox(self._running_loop(), False, 10_000)

        def on_sample(sample: zenoh.Sample) -> None:  # zenoh thread
            try:
                concrete = str(sample.key_expr)
                inbox.put(concrete, LivelinessEvent(concrete, sample.kind == zenoh.SampleKind.PUT))
            except Exception:
                log.exception("dropping a liveliness event on %s", key)

        handle = self.session.liveliness().declare_subscriber(key, on_sample, history=history)
        sub: Subscription[LivelinessEvent] = Subscription(key, inbox, lambda: self._release(sub, [handle.undeclare]))
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

        try:
            start(zenoh.handlers.Callback(on_reply, on_done))
        except zenoh.ZError as exc:  # e.g. the session closed under us
            raise BusError(f"zenoh refused the query: {_first_line(exc)}") from None
        await done
        return replies

    def declare_queryable(self, key: str, handler: QueryHandler) -> Queryable:
        """See `Bus.declare_queryable`; a query is finalized (its querier stops waiting) when the handler ends."""
        loop = self._running_loop()

        async def serve(query: zenoh.Query) -> None:
            with query:  # finalizes the query (the querier stops waiting) however we leave
                request = Request(str(query.key_expr), str(query.parameters),
                                  query.payload.to_bytes() if query.payload is not None else None)
                await serve_query(handler, request, key, query.reply, query.reply_err)

        def start(query: zenoh.Query) -> None:  # loop thread
            task = loop.create_task(serve(query))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

        def on_query(query: zenoh.Query) -> None:  # zenoh thread
            try:
                loop.call_soon_threadsafe(start, query)
            except RuntimeError:
                query.drop()  # the loop is gone: finalize at once so the querier does not wait

        handle = self.session.declare_queryable(key, on_query)
        queryable = Queryable(key, lambda: self._release(queryable, [handle.undeclare]))
        self._declared.add(queryable)
        return queryable
