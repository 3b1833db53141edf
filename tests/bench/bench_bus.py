"""Bus benchmark: raw zenoh-python between two processes vs the same through our asyncio `Bus`.

    python tests/bench/bench_bus.py [--quick]

Two processes on loopback: this one listens, a peer (this file with --peer) connects
and echoes. Measured for small messages (64 bytes):

* round trip: publish on bench/ping, the peer republishes on bench/pong; median and p99;
* throughput: a flood of messages (congestion control BLOCK, so none is dropped), the
  peer reports when it has them all; messages per second.

"raw" is zenoh-python as its examples use it (no asyncio, the echo publishes from
inside the callback, the pinger blocks on a FIFO channel); "bus" is `common.bus.protocol.Bus`
on both sides. "express" sends each message at once; "batched" lets zenoh batch.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, ROOT)

import zenoh  # noqa: E402

from common.bus.zenoh_bus import ZenohBus  # noqa: E402
from common.bus.zenoh_config import zenoh_config  # noqa: E402
from common.plumbing.lifecycle import free_port  # noqa: E402

PAYLOAD = bytes(64)
BLOCK = zenoh.CongestionControl.BLOCK


@dataclass
class Result:
    name: str
    rtts_us: list[float]
    rate: float

    def row(self) -> str:
        rtts = sorted(self.rtts_us)
        p99 = rtts[min(len(rtts) - 1, int(len(rtts) * 0.99))]
        return f"{self.name:<22} {statistics.median(rtts):>10.0f} {p99:>10.0f} {self.rate:>12,.0f}"


# --- the echoing peer ---------------------------------------------------------------------

def raw_peer(endpoint: str, express: bool) -> None:
    session = zenoh.open(zenoh_config("peer", connect=[endpoint]))
    pong = session.declare_publisher("bench/pong", express=express, congestion_control=BLOCK)
    done = session.declare_publisher("bench/flooded", express=True, congestion_control=BLOCK)
    expected, count = [0], [0]

    def on_ping(sample: zenoh.Sample) -> None:
        pong.put(sample.payload)  # the raw baseline: zenoh called from inside the callback

    def on_start(sample: zenoh.Sample) -> None:
        expected[0], count[0] = int(sample.payload.to_bytes()), 0
        done.put(b"started")

    def on_flood(sample: zenoh.Sample) -> None:
        count[0] += 1
        if count[0] == expected[0]:
            done.put(b"flooded")

    subs = [session.declare_subscriber("bench/ping", on_ping), session.declare_subscriber("bench/start", on_start),
            session.declare_subscriber("bench/flood", on_flood)]
    ready = threading.Event()
    token = session.liveliness().declare_subscriber("bench/main", lambda s: ready.set(), history=True)
    ready.wait()
    print("ready", flush=True)
    sys.stdin.read()  # until the main process closes our stdin
    del subs, token
    session.close()


async def bus_peer(endpoint: str, express: bool) -> None:
    async with ZenohBus(zenoh_config("peer", connect=[endpoint]), express=express) as bus:
        pings = bus.subscribe("bench/ping", coalesce=False, maxlen=None)
        starts = bus.subscribe("bench/start", coalesce=False)
        floods = bus.subscribe("bench/flood", coalesce=False, maxlen=None)
        watch = bus.watch_liveliness("bench/main")
        await watch.get()

        async def echo() -> None:
            async for sample in pings:
                bus.publish("bench/pong", sample.payload, block=True)

        async def count() -> None:
            async for start in starts:
                expected = int(start.payload)
                bus.publish("bench/flooded", b"started", block=True)
                for _ in range(expected):
                    await floods.get()
                bus.publish("bench/flooded", b"flooded", block=True)

        tasks = [asyncio.create_task(echo()), asyncio.create_task(count())]
        print("ready", flush=True)
        await asyncio.to_thread(sys.stdin.read)
        for task in tasks:
            task.cancel()


def start_peer(kind: str, endpoint: str, express: bool) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, __file__, "--peer", kind, endpoint, "1" if express else "0"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if line.strip() != "ready":
        raise RuntimeError(f"peer did not start (said {line!r})")
    return proc


def stop_peer(proc: subprocess.Popen[str]) -> None:
    assert proc.stdin is not None
    proc.stdin.close()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


# --- the measuring side -----------------------------------------------------------------------

def bench_raw(express: bool, rounds: int, flood: int) -> Result:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(zenoh_config("peer", listen=[endpoint]))
    try:
        pongs = session.declare_subscriber("bench/pong")
        flooded = session.declare_subscriber("bench/flooded")
        ping = session.declare_publisher("bench/ping", express=express, congestion_control=BLOCK)
        start = session.declare_publisher("bench/start", express=True, congestion_control=BLOCK)
        floods = session.declare_publisher("bench/flood", express=express, congestion_control=BLOCK)
        token = session.liveliness().declare_token("bench/main")
        proc = start_peer("raw", endpoint, express)
        try:
            warm_up = time.monotonic() + 10
            while pongs.try_recv() is None and time.monotonic() < warm_up:
                ping.put(PAYLOAD)
                time.sleep(0.01)
            time.sleep(0.1)
            while pongs.try_recv() is not None:
                pass
            rtts = []
            for _ in range(rounds):
                t0 = time.perf_counter_ns()
                ping.put(PAYLOAD)
                pongs.recv()
                rtts.append((time.perf_counter_ns() - t0) / 1000)
            start.put(str(flood).encode())
            assert flooded.recv().payload.to_bytes() == b"started"
            flood_began = time.perf_counter()
            for _ in range(flood):
                floods.put(PAYLOAD)
            assert flooded.recv().payload.to_bytes() == b"flooded"
            rate = flood / (time.perf_counter() - flood_began)
        finally:
            stop_peer(proc)
        token.undeclare()
    finally:
        session.close()
    return Result(f"raw zenoh ({'express' if express else 'batched'})", rtts, rate)


async def bench_bus(express: bool, rounds: int, flood: int) -> Result:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    async with ZenohBus(zenoh_config("peer", listen=[endpoint]), express=express) as bus:
        pongs = bus.subscribe("bench/pong", coalesce=False, maxlen=None)
        flooded = bus.subscribe("bench/flooded", coalesce=False)
        bus.declare_liveliness("bench/main")
        proc = await asyncio.to_thread(start_peer, "bus", endpoint, express)
        try:
            while True:
                bus.publish("bench/ping", PAYLOAD)
                try:
                    await asyncio.wait_for(pongs.get(), 0.01)
                    break
                except TimeoutError:
                    pass
            await asyncio.sleep(0.1)
            pongs.take_all()
            rtts = []
            for _ in range(rounds):
                t0 = time.perf_counter_ns()
                bus.publish("bench/ping", PAYLOAD, block=True)
                await pongs.get()
                rtts.append((time.perf_counter_ns() - t0) / 1000)
            bus.publish("bench/start", str(flood).encode(), block=True)
            assert (await flooded.get()).payload == b"started"
            flood_began = time.perf_counter()
            for i in range(flood):
                bus.publish("bench/flood", PAYLOAD, block=True)
                if i % 1000 == 999:
                    await asyncio.sleep(0)  # a real process lets its other tasks run
            assert (await flooded.get()).payload == b"flooded"
            rate = flood / (time.perf_counter() - flood_began)
        finally:
            await asyncio.to_thread(stop_peer, proc)
    return Result(f"asyncio Bus ({'express' if express else 'batched'})", rtts, rate)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--peer", nargs=3, metavar=("KIND", "ENDPOINT", "EXPRESS"), help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="fewer rounds (a smoke run)")
    args = parser.parse_args()
    if args.peer:
        kind, endpoint, express = args.peer
        if kind == "raw":
            raw_peer(endpoint, express == "1")
        else:
            asyncio.run(bus_peer(endpoint, express == "1"))
        return
    rounds, flood = (500, 5_000) if args.quick else (5_000, 100_000)
    started = time.perf_counter()
    results = []
    for express in (True, False):
        results.append(bench_raw(express, rounds, flood))
        results.append(asyncio.run(bench_bus(express, rounds, flood // 2)))
    print(f"\n{len(PAYLOAD)}-byte messages, two processes on loopback, {rounds} round trips, "
          f"{flood:,} (raw) / {flood // 2:,} (Bus) flooded messages")
    print(f"{'':<22} {'RTT median':>10} {'RTT p99':>10} {'messages/s':>12}")
    print(f"{'':<22} {'(µs)':>10} {'(µs)':>10}")
    for result in results:
        print(result.row())
    print(f"(took {time.perf_counter() - started:.1f} s)")


if __name__ == "__main__":
    main()
