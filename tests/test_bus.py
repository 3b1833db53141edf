"""The asyncio bus over real Zenoh on loopback, against a second OS process (tests/bus_peer.py).

The test process listens on a free loopback port; the peer connects to it. Timings
are never asserted, except the functional lease bound: a frozen peer's token is
gone within 5 s (lease 2 s).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from common.bus.inbox import Inbox
from common.bus.protocol import Bus, BusClosed, LivelinessEvent, Reply, Request, Sample
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.plumbing.lifecycle import free_port
from common.wire.keys import KeyExprError, Keys

PEER = Path(__file__).with_name("bus_peer.py")
STARTUP = 20.0  # generous bound for a peer to start and connect on a loaded machine


class Peers:
    """Starts bus_peer.py processes and always reaps them."""

    def __init__(self, endpoint: str, prefix: str) -> None:
        self.endpoint, self.prefix = endpoint, prefix
        self.procs: list[subprocess.Popen[str]] = []

    async def start(self, role: str, *args: str) -> subprocess.Popen[str]:
        proc = subprocess.Popen([sys.executable, str(PEER), role, self.endpoint, self.prefix, *args],
                                stdout=subprocess.PIPE, text=True)
        self.procs.append(proc)
        await self.expect(proc, "ready")
        return proc

    async def expect(self, proc: subprocess.Popen[str], line: str) -> None:
        assert proc.stdout is not None
        got = await asyncio.wait_for(asyncio.to_thread(proc.stdout.readline), STARTUP)
        assert got.strip() == line, f"peer said {got!r} (exit code {proc.poll()})"

    def reap(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
                proc.send_signal(signal.SIGCONT)
            proc.wait(timeout=10)
            if proc.stdout is not None:
                proc.stdout.close()


@pytest.fixture
def prefix() -> str:
    return f"t{uuid.uuid4().hex[:8]}"


@pytest.fixture
async def bus(prefix: str) -> AsyncIterator[tuple[Bus, Peers]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    async with ZenohBus(zenoh_config("peer", listen=[endpoint])) as bus:
        peers = Peers(endpoint, prefix)
        try:
            bus.declare_liveliness(f"{prefix}/parent")
            yield bus, peers
        finally:
            peers.reap()


async def next_event(watch: object, timeout: float) -> LivelinessEvent:
    return await asyncio.wait_for(watch.get(), timeout)  # type: ignore[attr-defined]  # a subscription or a liveliness watch


# --- keys ----------------------------------------------------------------------------------

def test_keys() -> None:
    keys = Keys("engine_assembly")
    assert keys.cmd("nr") == "engine_assembly/res/nr/cmd"
    assert keys.state("nr") == "engine_assembly/res/nr/state"
    assert keys.alive("pi-tool") == "engine_assembly/hub/pi-tool/alive"
    assert keys.selftest("pi-tool") == "engine_assembly/hub/pi-tool/selftest"
    assert keys.ctl("console", "request") == "engine_assembly/ctl/console/request"
    assert keys.all_state == "engine_assembly/res/*/state"
    assert keys.resource_of("engine_assembly/res/nr/state") == "nr"
    assert keys.resource_of("engine_assembly/hub/nr/alive") is None
    assert keys.hub_of("engine_assembly/hub/pi-tool/alive") == "pi-tool"
    for bad in ("", "a/b", "a*", "$x", "a b"):
        with pytest.raises(KeyExprError):
            keys.cmd(bad)


def test_config_refuses_nonsense() -> None:
    with pytest.raises(ValueError, match="cannot listen"):
        zenoh_config("client", listen=["tcp/127.0.0.1:7447"])
    with pytest.raises(ValueError, match="'peer' or 'client'"):
        zenoh_config("router")
    with pytest.raises(ValueError, match="lease_ms"):
        zenoh_config(lease_ms=10)


# --- publish / subscribe -----------------------------------------------------------------------

async def test_publish_subscribe_between_processes(bus: tuple[Bus, Peers], prefix: str) -> None:
    b, peers = bus
    pongs = b.subscribe(f"{prefix}/pong/*", coalesce=False)
    await peers.start("echo")
    # Declarations propagate asynchronously: ping until the first echo comes back.
    deadline = time.monotonic() + STARTUP
    first: Sample | None = None
    while first is None and time.monotonic() < deadline:
        b.publish(f"{prefix}/ping/x", b"hello")
        with contextlib.suppress(TimeoutError):
            first = await asyncio.wait_for(pongs.get(), 0.2)
    assert first == Sample(f"{prefix}/pong/x", b"hello")
    await asyncio.sleep(0.2)
    pongs.take_all()  # extra echoes of the warm-up pings

    for i in range(200):  # block: a burst congests the link, and every sample is counted
        b.publish(f"{prefix}/ping/{i % 3}", str(i).encode(), block=True)
    received = [await asyncio.wait_for(pongs.get(), STARTUP) for _ in range(200)]
    assert [int(s.payload) for s in received] == list(range(200))  # all of them, in order
    assert received[5].key == f"{prefix}/pong/2"


async def test_slow_consumer_sees_only_the_newest_sample_per_key(bus: tuple[Bus, Peers], prefix: str) -> None:
    b, peers = bus
    newest = b.subscribe(f"{prefix}/data/*")  # coalesced
    everything = b.subscribe(f"{prefix}/data/*", coalesce=False, maxlen=None)
    done = b.subscribe(f"{prefix}/done")
    proc = await peers.start("burst", "2000")
    await peers.expect(proc, "sent")
    await asyncio.wait_for(done.get(), STARTUP)
    await asyncio.sleep(0.5)  # let the last samples of the burst through the zenoh threads

    latest = newest.take_all()
    assert sorted((s.key, s.payload) for s in latest) == [(f"{prefix}/data/a", b"1999"), (f"{prefix}/data/b", b"1999")]
    assert newest.dropped == 2 * 2000 - 2
    all_samples = everything.take_all()
    assert [int(s.payload) for s in all_samples if s.key.endswith("/a")] == list(range(2000))
    assert [int(s.payload) for s in all_samples if s.key.endswith("/b")] == list(range(2000))


async def test_closing_ends_iteration() -> None:
    async with ZenohBus(zenoh_config("peer")) as b:
        sub = b.subscribe("nobody/*")

        async def consume() -> list[Sample]:
            return [s async for s in sub]

        task = asyncio.create_task(consume())
        await asyncio.sleep(0.05)
        sub.close()
        assert await asyncio.wait_for(task, 5) == []
        with pytest.raises(BusClosed):
            await sub.get()
    with pytest.raises(BusClosed):
        b.publish("a/b", b"")


async def test_local_publish_reaches_local_subscriber() -> None:
    async with ZenohBus(zenoh_config("peer")) as b:
        sub = b.subscribe("local/*")
        b.publish("local/x", b"1")
        assert await asyncio.wait_for(sub.get(), 5) == Sample("local/x", b"1")


# --- batches ------------------------------------------------------------------------------------

def sample(key: str, i: int) -> Sample:
    return Sample(key, str(i).encode())


async def test_a_batch_holds_the_newest_sample_per_key_and_counts_the_replaced_ones() -> None:
    inbox: Inbox[Sample] = Inbox(asyncio.get_running_loop(), coalesce=True, maxlen=None)
    for i in range(5):
        inbox.put("k/a", sample("k/a", i))
        inbox.put("k/b", sample("k/b", i))
    inbox.put("k/c", sample("k/c", 0))
    # Keys in the order they first arrived, each with its newest sample; the 8 replaced ones are dropped.
    assert await inbox.get_batch() == [sample("k/a", 4), sample("k/b", 4), sample("k/c", 0)]
    assert inbox.dropped == 8
    inbox.put("k/b", sample("k/b", 5))
    assert await inbox.get_batch() == [sample("k/b", 5)]
    assert inbox.dropped == 8


async def test_an_uncoalesced_batch_holds_every_sample_in_order() -> None:
    inbox: Inbox[Sample] = Inbox(asyncio.get_running_loop(), coalesce=False, maxlen=3)
    for i in range(5):
        inbox.put("k/a", sample("k/a", i))
    assert await inbox.get_batch() == [sample("k/a", i) for i in (2, 3, 4)]
    assert inbox.dropped == 2  # pushed out beyond maxlen


async def test_a_waiting_consumer_is_woken_by_another_thread_and_by_closing() -> None:
    inbox: Inbox[Sample] = Inbox(asyncio.get_running_loop(), coalesce=True, maxlen=None)
    consumer = asyncio.create_task(inbox.get_batch())
    await asyncio.sleep(0)
    await asyncio.to_thread(inbox.put, "k/a", sample("k/a", 1))
    assert await asyncio.wait_for(consumer, 5) == [sample("k/a", 1)]
    consumer = asyncio.create_task(inbox.get_batch())
    await asyncio.sleep(0)
    inbox.close()
    with pytest.raises(BusClosed):
        await asyncio.wait_for(consumer, 5)


async def test_batch_s_defers_the_next_wake_up_so_that_samples_join_one_batch() -> None:
    inbox: Inbox[Sample] = Inbox(asyncio.get_running_loop(), coalesce=False, maxlen=None, batch_s=60.0)
    inbox.put("k/a", sample("k/a", 0))
    assert await inbox.get_batch() == [sample("k/a", 0)]  # pending samples are handed out at once
    consumer = asyncio.create_task(inbox.get_batch())
    for i in range(1, 4):
        await asyncio.to_thread(inbox.put, "k/a", sample("k/a", i))
        for _ in range(5):
            await asyncio.sleep(0)
    assert not consumer.done()  # within batch_s of the last batch: not woken, the samples wait
    inbox.close()  # closing wakes it at once, with what is pending
    assert await asyncio.wait_for(consumer, 5) == [sample("k/a", i) for i in (1, 2, 3)]


async def test_batches_over_zenoh_keep_per_key_order_newest_wins() -> None:
    async with ZenohBus(zenoh_config("peer")) as b:
        sub = b.subscribe("batch/*", batch_s=0.5, expect=["batch/a", "batch/b"])
        everything = b.subscribe("batch/*", coalesce=False, maxlen=None)
        for i in range(1000):
            b.publish("batch/a", str(i).encode(), block=True)
            b.publish("batch/b", str(i).encode(), block=True)
        b.publish("batch/end", b"-1", block=True)  # one subscription delivers in order: the last one
        newest: dict[str, int] = {}
        delivered = 0
        while "batch/end" not in newest:
            batch = await asyncio.wait_for(sub.get_batch(), STARTUP)
            assert len({s.key for s in batch}) == len(batch)  # one sample per key in a batch
            for s in batch:
                assert int(s.payload) > newest.get(s.key, -2), "an older sample after a newer one"
                newest[s.key] = int(s.payload)
            delivered += len(batch)
        assert newest == {"batch/a": 999, "batch/b": 999, "batch/end": -1}
        assert delivered + sub.dropped == 2001 and sub.dropped > 0
        # Without coalescing a batch holds every sample, in order.
        got: list[Sample] = []
        async for batch in everything.batches():
            got += batch
            if got[-1].key == "batch/end":
                everything.close()
        assert [s.payload for s in got if s.key == "batch/a"] == [str(i).encode() for i in range(1000)]
        assert len(got) == 2001 and everything.dropped == 0
        sub.close()  # undeclares the expected keys too
        assert [b async for b in sub.batches()] == []


# --- liveliness --------------------------------------------------------------------------------

async def test_liveliness_appears_and_goes_when_the_peer_is_killed(bus: tuple[Bus, Peers], prefix: str) -> None:
    b, peers = bus
    watch = b.watch_liveliness(f"{prefix}/hub/*/alive")
    proc = await peers.start("alive", "h1")
    key = f"{prefix}/hub/h1/alive"
    assert await next_event(watch, STARTUP) == LivelinessEvent(key, True)
    assert await b.alive_tokens(f"{prefix}/hub/*/alive") == {key}

    proc.send_signal(signal.SIGKILL)
    assert await next_event(watch, 5.0) == LivelinessEvent(key, False)
    assert await b.alive_tokens(f"{prefix}/hub/*/alive") == set()


async def test_frozen_peer_is_gone_within_the_lease_and_back_when_it_resumes(
        bus: tuple[Bus, Peers], prefix: str) -> None:
    b, peers = bus
    watch = b.watch_liveliness(f"{prefix}/hub/*/alive")
    proc = await peers.start("alive", "h2")
    key = f"{prefix}/hub/h2/alive"
    assert await next_event(watch, STARTUP) == LivelinessEvent(key, True)

    os.kill(proc.pid, signal.SIGSTOP)  # the TCP link stays open: only the lease can tell
    try:
        assert await next_event(watch, 5.0) == LivelinessEvent(key, False)  # lease 2 s
    finally:
        os.kill(proc.pid, signal.SIGCONT)
    # The peer notices its link was closed and reconnects by itself.
    assert await next_event(watch, STARTUP) == LivelinessEvent(key, True)


async def test_history_reports_tokens_alive_before_watching(bus: tuple[Bus, Peers], prefix: str) -> None:
    b, peers = bus
    await peers.start("alive", "h3")  # "ready" once it saw our token, so it is connected
    key = f"{prefix}/hub/h3/alive"
    deadline = time.monotonic() + STARTUP
    while key not in await b.alive_tokens(f"{prefix}/**") and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    watch = b.watch_liveliness(f"{prefix}/hub/*/alive")
    assert await next_event(watch, STARTUP) == LivelinessEvent(key, True)


async def test_hub_started_first_connects_and_reconnects_after_a_controller_restart(prefix: str) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    peers = Peers(endpoint, prefix)
    try:
        proc = subprocess.Popen([sys.executable, str(PEER), "alive", endpoint, prefix, "h4"],
                                stdout=subprocess.PIPE, text=True)
        peers.procs.append(proc)
        await asyncio.sleep(0.5)  # nobody listens yet: the peer keeps retrying in the background
        key = f"{prefix}/hub/h4/alive"
        for _ in range(2):  # the controller comes up, then restarts
            async with ZenohBus(zenoh_config("peer", listen=[endpoint])) as b:
                b.declare_liveliness(f"{prefix}/parent")
                watch = b.watch_liveliness(f"{prefix}/hub/*/alive")
                assert await next_event(watch, STARTUP) == LivelinessEvent(key, True)
    finally:
        peers.reap()


async def test_open_failures_are_reported() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ConnectionError, match="Address already in use"):
            async with ZenohBus(zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"])):
                pass
    with pytest.raises(ConnectionError, match="Unable to connect"):
        async with ZenohBus(zenoh_config("client", connect=[f"tcp/127.0.0.1:{free_port()}"]), open_timeout=0.2):
            pass


# --- query / reply -----------------------------------------------------------------------------------

async def test_get_from_a_queryable_in_another_process(bus: tuple[Bus, Peers], prefix: str) -> None:
    b, peers = bus
    await peers.start("queryable")
    deadline = time.monotonic() + STARTUP
    replies: list[Reply] = []
    while not replies and time.monotonic() < deadline:
        replies = await b.get(f"{prefix}/q/abc?x=1", payload=b"hi", timeout=1.0)
    assert [(r.key, r.payload, r.ok) for r in replies] == [(f"{prefix}/q/abc", f"{prefix}/q/abc|x=1|hi".encode(), True)]


async def test_local_queryable_replies_errors_and_silence() -> None:
    async with ZenohBus(zenoh_config("peer")) as b:
        async def handler(request: Request) -> bytes | list[tuple[str, bytes]] | None:
            await asyncio.sleep(0)  # handlers run on the loop and may await
            if request.parameters == "fail=1":
                raise RuntimeError("no such thing")
            if request.parameters == "none=1":
                return None
            if request.parameters == "many=1":
                return [("svc/a", b"1"), ("svc/b", b"2")]
            return b"pong:" + (request.payload or b"")

        b.declare_queryable("svc/*", handler)
        [reply] = await b.get("svc/a", payload=b"x")
        assert (reply.key, reply.payload, reply.ok) == ("svc/a", b"pong:x", True)
        [error] = await b.get("svc/a?fail=1")
        assert not error.ok and b"no such thing" in error.payload
        assert await b.get("svc/a?none=1", timeout=0.5) == []
        many = await b.get("svc/*?many=1")
        assert sorted((r.key, r.payload) for r in many) == [("svc/a", b"1"), ("svc/b", b"2")]
        assert await b.get("nobody/here", timeout=0.2) == []

