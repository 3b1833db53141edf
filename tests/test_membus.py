"""One behaviour suite for both buses, and what only the in-memory bus promises.

Each shared test runs over `ZenohBus` (two sessions in this process on a loopback port:
the first listens, the second connects) and over `MemoryBus` (two buses on one
`MemoryHub`). Zenoh propagates declarations asynchronously, so a test first waits until
the peer has learnt what it declared (`linked`); the in-memory bus passes that at once.
The real-process Zenoh tests stay in tests/test_bus.py.
"""

from __future__ import annotations

import asyncio
import inspect
import time
import uuid
from collections.abc import AsyncIterator

import pytest

from common.bus.memory_bus import MemoryBus, MemoryHub, intersects, key_chunks
from common.bus.protocol import Bus, BusClosed, LivelinessEvent, Reply, Request, Sample, Subscription
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import loopback_endpoint, zenoh_config
from common.plumbing.lifecycle import free_port
from common.wire.keys import KeyExprError

STARTUP = 20.0  # generous bound for zenoh peers to link on a loaded machine


class Network:
    """Buses that see each other: Zenoh sessions on one loopback port, or MemoryBuses on one hub."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.endpoint = loopback_endpoint(free_port())
        self.memory = MemoryHub()
        self.buses: list[ZenohBus | MemoryBus] = []

    async def bus(self) -> Bus:
        bus: ZenohBus | MemoryBus
        if self.kind == "memory":
            bus = MemoryBus(self.memory)
        elif not self.buses:
            bus = ZenohBus(zenoh_config("peer", listen=[self.endpoint]))
        else:
            bus = ZenohBus(zenoh_config("peer", connect=[self.endpoint]))
        self.buses.append(bus)
        return await bus.open()

    async def close(self) -> None:
        for bus in reversed(self.buses):
            await bus.close()


@pytest.fixture(params=["zenoh", "memory"])
async def net(request: pytest.FixtureRequest) -> AsyncIterator[Network]:
    network = Network(request.param)
    try:
        yield network
    finally:
        await network.close()


@pytest.fixture
def prefix() -> str:
    return f"t{uuid.uuid4().hex[:8]}"


async def linked(declarer: Bus, other: Bus, prefix: str) -> None:
    """Return once `other` knows what `declarer` declared so far: a probe subscription declared
    last receives what `other` publishes (declarations propagate in order)."""
    probe = declarer.subscribe(f"{prefix}-probe/x")
    deadline = time.monotonic() + STARTUP
    try:
        while time.monotonic() < deadline:
            other.publish(f"{prefix}-probe/x", b"")
            try:
                await asyncio.wait_for(probe.get(), 0.1)
                return
            except TimeoutError:
                continue
        raise AssertionError(f"the peers did not link within {STARTUP:.0f} s")
    finally:
        probe.close()


async def received(subscription: Subscription[Sample], count: int) -> list[Sample]:
    return [await asyncio.wait_for(subscription.get(), STARTUP) for _ in range(count)]


async def nothing_more(*subscriptions: Subscription[Sample]) -> None:
    await asyncio.sleep(0.2)  # what was on its way has arrived
    for subscription in subscriptions:
        assert subscription.take_all() == [], subscription.key


async def next_event(watch: Subscription[LivelinessEvent]) -> LivelinessEvent:
    return await asyncio.wait_for(watch.get(), STARTUP)


@pytest.mark.parametrize("implementation", [ZenohBus, MemoryBus])
def test_each_bus_offers_the_protocol_s_methods_with_their_signatures(implementation: type) -> None:
    methods = [name for name, member in vars(Bus).items() if callable(member) and not name.startswith("_")]
    assert len(methods) == 8
    for name in methods:
        assert inspect.signature(getattr(implementation, name)) == inspect.signature(getattr(Bus, name)), name


# --- publish / subscribe ------------------------------------------------------------------------

async def test_a_publication_reaches_every_subscription_whose_key_expression_matches(
        net: Network, prefix: str) -> None:
    a, b = await net.bus(), await net.bus()
    one_chunk = a.subscribe(f"{prefix}/*/state", coalesce=False)
    any_chunks = a.subscribe(f"{prefix}/**", coalesce=False)
    exact = a.subscribe(f"{prefix}/x/state", coalesce=False)
    own = b.subscribe(f"{prefix}/x/*", coalesce=False)  # the publisher's own subscription gets it too
    await linked(a, b, prefix)
    for key in ("x/state", "y/state", "x/cmd", "x/y/state", "x"):
        b.publish(f"{prefix}/{key}", key.encode(), block=True)
    b.publish(f"{prefix}-other/x/state", b"elsewhere", block=True)

    def keys(samples: list[Sample]) -> list[str]:
        assert all(s.payload == s.key.removeprefix(f"{prefix}/").encode() for s in samples)
        return [s.key.removeprefix(f"{prefix}/") for s in samples]

    assert keys(await received(any_chunks, 5)) == ["x/state", "y/state", "x/cmd", "x/y/state", "x"]
    assert keys(await received(one_chunk, 2)) == ["x/state", "y/state"]
    assert keys(await received(exact, 1)) == ["x/state"]
    assert keys(await received(own, 2)) == ["x/state", "x/cmd"]
    await nothing_more(one_chunk, any_chunks, exact, own)


async def test_a_slow_consumer_gets_the_newest_sample_per_key(net: Network, prefix: str) -> None:
    a, b = await net.bus(), await net.bus()
    newest = a.subscribe(f"{prefix}/data/*")
    everything = a.subscribe(f"{prefix}/data/*", coalesce=False, maxlen=None)
    await linked(a, b, prefix)
    for i in range(100):
        b.publish(f"{prefix}/data/a", str(i).encode(), block=True)
        b.publish(f"{prefix}/data/b", str(i).encode(), block=True)
    b.publish(f"{prefix}/data/end", b"-1", block=True)

    every = await received(everything, 201)
    assert [int(s.payload) for s in every if s.key.endswith("/a")] == list(range(100))
    assert every[-1].key == f"{prefix}/data/end"
    latest: dict[str, int] = {}
    taken = 0
    while "end" not in latest:  # nobody waited on it: its samples coalesced meanwhile
        batch = await asyncio.wait_for(newest.get_batch(), STARTUP)
        taken += len(batch)
        latest.update((s.key.rsplit("/", 1)[1], int(s.payload)) for s in batch)
    assert latest == {"a": 99, "b": 99, "end": -1}
    assert taken + newest.dropped == 201 and newest.dropped > 0


# --- query / reply -------------------------------------------------------------------------------

async def answer(request: Request) -> bytes | list[tuple[str, bytes]] | None:
    await asyncio.sleep(0)  # handlers run on the loop and may await
    if request.parameters == "fail=1":
        raise RuntimeError("no such thing")
    if request.parameters == "none=1":
        return None
    if request.parameters == "many=1":
        return [(request.key.replace("*", "a"), b"1"), (request.key.replace("*", "b"), b"2")]
    if request.parameters == "stray=1":
        return [("somewhere/else", b"?")]
    return b"pong:" + (request.payload or b"")


async def test_a_queryable_answers_gets_with_replies_errors_and_silence(net: Network, prefix: str) -> None:
    a, b = await net.bus(), await net.bus()
    queryable = b.declare_queryable(f"{prefix}/svc/*", answer)
    await linked(b, a, prefix)
    assert await a.get(f"{prefix}/svc/x", payload=b"hi") == [Reply(f"{prefix}/svc/x", b"pong:hi")]
    [error] = await a.get(f"{prefix}/svc/x?fail=1")
    assert not error.ok and b"RuntimeError: no such thing" in error.payload
    [stray] = await a.get(f"{prefix}/svc/x?stray=1")  # a reply must match the query
    assert not stray.ok
    assert await a.get(f"{prefix}/svc/x?none=1", timeout=0.5) == []
    many = await a.get(f"{prefix}/svc/*?many=1")
    assert sorted((r.key, r.payload) for r in many) == [(f"{prefix}/svc/a", b"1"), (f"{prefix}/svc/b", b"2")]
    # A wildcard query answered with bytes: the reply carries the queryable's key.
    assert await a.get(f"{prefix}/**") == [Reply(f"{prefix}/svc/*", b"pong:")]
    assert await a.get(f"{prefix}/nobody", timeout=0.2) == []
    # A bus answers its own queries too.
    a.declare_queryable(f"{prefix}/own", answer)
    assert await a.get(f"{prefix}/own", payload=b"me") == [Reply(f"{prefix}/own", b"pong:me")]

    queryable.undeclare()
    deadline = time.monotonic() + STARTUP
    while await a.get(f"{prefix}/svc/x", timeout=0.2) and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    assert await a.get(f"{prefix}/svc/x", timeout=0.2) == []


# --- liveliness ----------------------------------------------------------------------------------

async def test_liveliness_tokens_appear_and_go_with_their_bus(net: Network, prefix: str) -> None:
    a, b = await net.bus(), await net.bus()
    watch = a.watch_liveliness(f"{prefix}/hub/*/alive")
    key = f"{prefix}/hub/h1/alive"
    token = b.declare_liveliness(key)
    assert await next_event(watch) == LivelinessEvent(key, True)
    assert await a.alive_tokens(f"{prefix}/hub/*/alive") == {key}
    late = a.watch_liveliness(f"{prefix}/**")  # history: the tokens alive before it was declared
    assert await next_event(late) == LivelinessEvent(key, True)
    no_history = a.watch_liveliness(f"{prefix}/**", history=False)

    token.undeclare()
    assert await next_event(watch) == LivelinessEvent(key, False)
    assert await next_event(no_history) == LivelinessEvent(key, False)
    assert await a.alive_tokens(f"{prefix}/**") == set()
    b.declare_liveliness(key)  # a restart: gone, then alive again
    assert await next_event(watch) == LivelinessEvent(key, True)
    await b.close()  # a process that ends takes its tokens with it
    assert await next_event(watch) == LivelinessEvent(key, False)


async def test_a_key_with_two_tokens_is_alive_until_the_last_goes(net: Network, prefix: str) -> None:
    a, b = await net.bus(), await net.bus()
    key = f"{prefix}/hub/twice/alive"
    watch = a.watch_liveliness(f"{prefix}/hub/*/alive")
    first = a.declare_liveliness(key)
    assert await next_event(watch) == LivelinessEvent(key, True)
    second = b.declare_liveliness(key)
    await linked(b, a, prefix)  # the second token has reached a
    first.undeclare()
    await asyncio.sleep(0.2)  # a "gone" would be on its way by now
    assert watch.take_all() == []
    second.undeclare()
    assert await next_event(watch) == LivelinessEvent(key, False)


# --- closing -------------------------------------------------------------------------------------

async def test_closing_ends_iteration_and_every_later_call_raises_bus_closed(net: Network, prefix: str) -> None:
    a = await net.bus()
    sub = a.subscribe(f"{prefix}/*")
    watch = a.watch_liveliness(f"{prefix}/*")

    async def consume() -> list[Sample]:
        return [s async for s in sub]

    task = asyncio.create_task(consume())
    await asyncio.sleep(0.05)
    sub.close()
    assert await asyncio.wait_for(task, 5) == []
    with pytest.raises(BusClosed):
        await sub.get()
    await a.close()
    assert [e async for e in watch] == []  # closing the bus closes its subscriptions
    with pytest.raises(BusClosed):
        a.publish(f"{prefix}/x", b"")
    with pytest.raises(BusClosed):
        a.subscribe(f"{prefix}/*")
    with pytest.raises(BusClosed):
        a.declare_liveliness(f"{prefix}/x")
    with pytest.raises(BusClosed):
        await a.get(f"{prefix}/x")
    with pytest.raises(BusClosed):
        await a.alive_tokens(f"{prefix}/*")
    await a.close()  # twice: nothing happens


# --- only the in-memory bus ----------------------------------------------------------------------

async def test_memory_delivery_happens_on_the_loop_after_the_call_never_inside_it() -> None:
    hub = MemoryHub()
    async with MemoryBus(hub) as a, MemoryBus(hub) as b:
        samples = a.subscribe("k/*", coalesce=False)
        watch = a.watch_liveliness("t/*")
        b.publish("k/x", b"1")
        b.declare_liveliness("t/x")
        assert samples.take_all() == [] and watch.take_all() == []
        late = a.subscribe("k/*")  # declared after the publication: does not get it
        await asyncio.sleep(0)
        assert samples.take_all() == [Sample("k/x", b"1")]
        assert watch.take_all() == [LivelinessEvent("t/x", True)]
        assert late.take_all() == []

        order: list[str] = []

        async def handler(_request: Request) -> bytes:
            order.append("handler")
            return b"x"

        b.declare_queryable("q/x", handler)
        query = asyncio.ensure_future(a.get("q/x"))
        await asyncio.sleep(0)  # `get` has asked; the handler has not run inside it
        order.append("asked")
        assert await query == [Reply("q/x", b"x")]
        assert order == ["asked", "handler"]


async def test_memory_get_does_not_wait_past_its_timeout_for_a_slow_handler() -> None:
    release = asyncio.Event()

    async def slow(_request: Request) -> bytes:
        await release.wait()
        return b"late"

    async with MemoryBus(MemoryHub()) as bus:
        bus.declare_queryable("slow", slow)
        assert await bus.get("slow", timeout=0.05) == []
        release.set()


async def test_a_memory_hub_serves_one_event_loop() -> None:
    hub = MemoryHub()
    async with MemoryBus(hub):
        def elsewhere() -> None:
            async def open_bus() -> None:
                await MemoryBus(hub).open()
            asyncio.run(open_bus())

        with pytest.raises(RuntimeError, match="one event loop"):
            await asyncio.to_thread(elsewhere)


def test_key_expressions_match_as_zenoh_matches_them() -> None:
    def meet(a: str, b: str) -> bool:
        return intersects(key_chunks(a), key_chunks(b))

    assert meet("a/*/c", "a/b/c") and not meet("a/*", "a/b/c") and not meet("a/*/c", "a/c")
    assert meet("a/**", "a") and meet("a/**", "a/b/c") and meet("**", "x/y")
    assert meet("a/**/c", "a/c") and meet("a/**/c", "a/b/d/c") and not meet("a/**/c", "a/b/d")
    assert meet("a/*/c", "a/**") and meet("*/b", "a/*") and not meet("a/*/c", "b/**")
    for bad in ("", "a//b", "/a", "a/", "a*", "a/$*", "a/**/**", "a?b", "a#"):
        with pytest.raises(KeyExprError):
            key_chunks(bad)
    with pytest.raises(KeyExprError, match="concrete"):
        key_chunks("a/*", concrete=True)
