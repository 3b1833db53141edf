"""The other process of the bus tests: `python tests/bus_peer.py ROLE ENDPOINT ARGS...`.

It connects to ENDPOINT (the test process listens there), waits until it sees the
test's liveliness token `PREFIX/parent` (so the test's declarations have reached
it), performs its role and prints `ready` (and role-specific lines) on stdout.

Roles:
  alive PREFIX HUB        declare the token PREFIX/hub/HUB/alive and sleep
  echo PREFIX             republish every sample of PREFIX/ping/* on PREFIX/pong/*
  burst PREFIX N          publish 0..N-1 on PREFIX/data/a and PREFIX/data/b, then PREFIX/done
  queryable PREFIX        answer queries on PREFIX/q/** with "<key>|<parameters>|<payload>"
  flood PREFIX KEY N SIZE put N garbage payloads of SIZE bytes on KEY (a rogue peer), print `sent`;
                          PREFIX/parent is not waited for: the peer is linked once a hub's token shows
"""

from __future__ import annotations

import asyncio
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from common.bus.protocol import Request
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config


def say(line: str) -> None:
    print(line, flush=True)


async def wait_for_parent(bus: ZenohBus, prefix: str) -> None:
    async with bus.watch_liveliness(f"{prefix}/parent") as watch:
        async for event in watch:
            if event.alive:
                return


async def main(role: str, endpoint: str, prefix: str, *args: str) -> None:
    async with ZenohBus(zenoh_config("peer", listen=[], connect=[endpoint])) as bus:
        if role == "alive":
            bus.declare_liveliness(f"{prefix}/hub/{args[0]}/alive")
            await wait_for_parent(bus, prefix)
            say("ready")
            await asyncio.Event().wait()
        elif role == "echo":
            sub = bus.subscribe(f"{prefix}/ping/*", coalesce=False)
            await wait_for_parent(bus, prefix)
            say("ready")
            async for sample in sub:
                bus.publish(sample.key.replace("/ping/", "/pong/"), sample.payload, block=True)
        elif role == "burst":
            await wait_for_parent(bus, prefix)
            say("ready")
            # block=True: a burst this fast congests the link, and the test counts every sample.
            for i in range(int(args[0])):
                bus.publish(f"{prefix}/data/a", str(i).encode(), block=True)
                bus.publish(f"{prefix}/data/b", str(i).encode(), block=True)
            bus.publish(f"{prefix}/done", b"done", block=True)
            say("sent")
            await asyncio.Event().wait()
        elif role == "flood":
            key, count, size = args[0], int(args[1]), int(args[2])
            async with bus.watch_liveliness(f"{prefix}/hub/*/alive") as hubs:
                await hubs.get()
            say("ready")
            chunk = bytes(range(256)) * (size // 256 + 1)
            for i in range(count):
                # block=True: every payload reaches the hub (dropping them would test nothing).
                bus.publish(key, (i.to_bytes(4, "big") + chunk)[:size], block=True)
                if i % 100 == 0:
                    await asyncio.sleep(0)
            say("sent")
            await asyncio.Event().wait()
        elif role == "queryable":
            async def answer(request: Request) -> bytes:
                return f"{request.key}|{request.parameters}|{(request.payload or b'').decode()}".encode()

            bus.declare_queryable(f"{prefix}/q/**", answer)
            await wait_for_parent(bus, prefix)
            say("ready")
            await asyncio.Event().wait()
        else:
            raise SystemExit(f"unknown role {role!r}")


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:]))
