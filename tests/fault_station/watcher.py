"""The fault station's watcher: a `Bus` in a background thread that records the station's traffic.

With the receive time it records every `{station}/ctl/status` (StatusMessage, the controller's deltas
merged into full statuses by controller/console/statusview.py) and
`{station}/ctl/state` (StateSnapshot), every state of every resource (`{station}/res/*/state`,
decoded with the resource's Codec) and every command (`{station}/res/*/cmd`), and counts
what it could not decode (the garbage a test publishes itself). Nothing is coalesced: a
test counts edges in these streams (`rising_edges`, `value_at`). The processes it watches
are in harness.py.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from typing import Any, TypeVar

from common.bus.protocol import Sample
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import StationConfig
from common.model import Model
from common.wire.ctl import StateSnapshot, StatusMessage
from common.wire.messages import Codec, MessageError, decode
from controller.console.statusview import StatusFollower

T = TypeVar("T")


# --- what the watcher records -------------------------------------------------------------

@dataclass(frozen=True)
class Seen:
    at: float  # time.monotonic() when the watcher received it
    message: Any


@dataclass
class Record:
    statuses: list[Seen] = field(default_factory=list)
    snapshots: list[Seen] = field(default_factory=list)
    states: dict[str, list[Seen]] = field(default_factory=dict)
    commands: dict[str, list[Seen]] = field(default_factory=dict)
    undecodable: dict[str, int] = field(default_factory=dict)


class Watcher:
    """A Bus in a background thread: records the station's traffic, publishes for the test."""

    def __init__(self, config: StationConfig, model: Model, port: int) -> None:
        self.keys = config.keys
        self.codecs = {r.name: Codec(r) for r in model.resources}
        self.lock = threading.Lock()
        self.record = Record(states={r: [] for r in self.codecs}, commands={r: [] for r in self.codecs})
        self._endpoint = f"tcp/127.0.0.1:{port}"
        self._lease = config.network.lease_ms
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self.bus: ZenohBus | None = None
        self._thread = threading.Thread(target=self._main, name="watcher", daemon=True)
        self._thread.start()
        if not self._ready.wait(20) or self._error is not None:
            raise RuntimeError(f"the watcher bus did not open: {self._error!r}")

    # the background thread
    def _main(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported by __init__ or close
            self._error = exc
            self._ready.set()
        finally:
            self._loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        config = zenoh_config("peer", listen=["tcp/127.0.0.1:0"], connect=[self._endpoint], lease_ms=self._lease)
        # Reconnect to a (re)started controller within 0.1 s (a process's default backs off to 2 s), so that
        # the watcher sees its first messages; listening lets the hubs link to it as soon as gossip tells them.
        config.insert_json5("connect/retry", json.dumps({"period_init_ms": 50, "period_max_ms": 100,
                                                         "period_increase_factor": 1}))
        async with ZenohBus(config) as bus:
            self.bus = bus
            subscriptions = [
                (bus.subscribe(self.keys.ctl("state"), coalesce=False, maxlen=None), self._on_snapshot),
                (bus.subscribe(self.keys.all_state, coalesce=False, maxlen=None), self._on_state),
                (bus.subscribe(self.keys.all_cmd, coalesce=False, maxlen=None), self._on_command),
            ]
            tasks = [asyncio.create_task(self._consume(sub, handler)) for sub, handler in subscriptions]
            tasks.append(asyncio.create_task(self._follow_status(bus)))
            self._ready.set()
            await self._stop.wait()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    @staticmethod
    async def _consume(subscription: Any, handler: Callable[[Sample, float], None]) -> None:
        async for sample in subscription:
            handler(sample, time.monotonic())

    def _bad(self, key: str) -> None:
        with self.lock:
            self.record.undecodable[key] = self.record.undecodable.get(key, 0) + 1

    async def _follow_status(self, bus: ZenohBus) -> None:
        follower = StatusFollower(bus, self.keys)
        async for sample in bus.subscribe(self.keys.ctl("status"), coalesce=False, maxlen=None):
            at = time.monotonic()
            try:
                status = await follower.take(sample.payload)
            except MessageError:
                self._bad(sample.key)
                continue
            if status is not None:
                with self.lock:
                    self.record.statuses.append(Seen(at, status))

    def _on_snapshot(self, sample: Sample, at: float) -> None:
        try:
            snapshot = decode(sample.payload, StateSnapshot)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.snapshots.append(Seen(at, snapshot))

    def _on_state(self, sample: Sample, at: float) -> None:
        resource = self.keys.resource_of(sample.key)
        codec = self.codecs.get(resource or "")
        try:
            if codec is None:
                raise MessageError("unknown resource")
            state = codec.decode_state(sample.payload)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.states[codec.resource].append(Seen(at, state))

    def _on_command(self, sample: Sample, at: float) -> None:
        resource = self.keys.resource_of(sample.key)
        codec = self.codecs.get(resource or "")
        try:
            if codec is None:
                raise MessageError("unknown resource")
            command = codec.decode_command(sample.payload)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.commands[codec.resource].append(Seen(at, command))

    # the test's thread
    def call(self, coroutine: Coroutine[Any, Any, T], timeout: float = 10.0) -> T:
        return asyncio.run_coroutine_threadsafe(coroutine, self._loop).result(timeout)

    def publish(self, key: str, payload: bytes) -> None:
        async def put() -> None:
            assert self.bus is not None
            self.bus.publish(key, payload, block=True)

        self.call(put())

    def alive_hubs(self) -> set[str]:
        async def query() -> set[str]:
            assert self.bus is not None
            return await self.bus.alive_tokens(self.keys.all_alive, timeout=1.0)

        return {self.keys.hub_of(k) or k for k in self.call(query())}

    def peers(self) -> int:
        """How many zenoh peers this watcher is linked to."""
        async def count() -> int:
            assert self.bus is not None
            return self.bus.peer_count()

        return self.call(count())

    def close(self) -> None:
        if self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(15)

    def forget(self) -> None:
        """Drop everything recorded so far (the station is started again from nothing)."""
        with self.lock:
            self.record = Record(states={r: [] for r in self.codecs}, commands={r: [] for r in self.codecs})

    # views (copies, taken under the lock)
    def statuses(self) -> list[Seen]:
        with self.lock:
            return list(self.record.statuses)

    def snapshots(self) -> list[Seen]:
        with self.lock:
            return list(self.record.snapshots)

    def states(self, resource: str) -> list[Seen]:
        with self.lock:
            return list(self.record.states[resource])

    def commands(self, resource: str) -> list[Seen]:
        with self.lock:
            return list(self.record.commands[resource])

    def undecodable(self) -> dict[str, int]:
        with self.lock:
            return dict(self.record.undecodable)

    def status(self) -> StatusMessage | None:
        with self.lock:
            return self.record.statuses[-1].message if self.record.statuses else None

    def current_status(self) -> StatusMessage:
        """The latest status, where the test has seen one already."""
        status = self.status()
        assert status is not None, "no status from the controller yet"
        return status

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            return dict(self.record.snapshots[-1].message.values) if self.record.snapshots else {}

    def state(self, resource: str) -> Any:
        with self.lock:
            seen = self.record.states[resource]
            return seen[-1].message if seen else None

    def finished(self) -> bool:
        status = self.status()
        return status is not None and status.finished

    def health(self, resource: str) -> Any:
        status = self.status()
        if status is None:
            return None
        return next((h for h in status.health if h.resource == resource), None)


# --- reading the recorded streams ------------------------------------------------------------

def rising_edges(states: list[Seen], variable: str) -> list[Seen]:
    """The states in which `variable` became true (from false or unknown), per hub run: a hub restarted
    (its seq starts again) begins from false."""
    edges, previous, last_seq = [], False, None
    for seen in states:
        message = seen.message
        if last_seq is not None and message.seq < last_seq:
            previous = False
        last_seq = message.seq
        value = bool(getattr(message, variable))
        if value and not previous:
            edges.append(seen)
        previous = value
    return edges


def value_published_before(states: list[Seen], variable: str, time: float) -> Any:
    """The value of `variable` in the newest state its hub published at or before `time` (the hubs' own
    wall-clock stamps: the hubs of a station run share this machine's clock). Unlike `value_at`, it does
    not depend on the order in which two hubs' states reached the watcher over their own links."""
    value, newest = None, float("-inf")
    for seen in states:
        stamp = seen.message.time
        if newest <= stamp <= time:
            value, newest = getattr(seen.message, variable), stamp
    return value


def value_at(states: list[Seen], variable: str, at: float) -> Any:
    """The value of `variable` in the newest state received before `at` (monotonic)."""
    value = None
    for seen in states:
        if seen.at > at:
            break
        value = getattr(seen.message, variable)
    return value

