"""The Zenoh side of a model-based test: commands to one resource's hub, its states back.

It talks to the hub exactly as the controller does: it holds the station (a holder token,
epoch 0) and sends Codec commands with a sequence number and a controller id on
`{station}/res/{r}/cmd`, sent at once and re-sent at the command rate; it reads every
state sample on `{station}/res/{r}/state` (in order, none coalesced), and follows the
other resources the model's guards read (their states and commands, newest only).
Hypothesis runs test functions synchronously, so the `Bus` lives on its own event loop
in a background thread (`BusThread`) and `ResourceLink` offers a thread-safe, blocking API.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import logging
import queue
import threading
import time
import uuid
from collections.abc import Callable, Coroutine, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from common.bus.protocol import Bus, Subscription, Token
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import TlsSettings, ZenohConfig, zenoh_config
from common.config.modes import NetworkMode
from common.model import Kind, Model, Value
from common.wire.ctl import StatusMessage
from common.wire.holder_token import declare_holder
from common.wire.keys import Keys, station_keys
from common.wire.messages import Codec, CommandMessage, HubStatus, MessageError, ModelMismatch, StateMessage, decode

log = logging.getLogger("statehub.modeltest")
T = TypeVar("T")
_OWN_IDS: set[str] = set()  # controller ids of this process's links


class LinkError(RuntimeError):
    """The hub cannot be tested: unreachable, another model, another controller commanding it."""


class BusThread:
    """One `Bus` on an event loop of its own thread, for synchronous callers."""

    def __init__(self, config: ZenohConfig, *, description: str = "") -> None:
        self.config = config
        self.description = description
        self.loop: asyncio.AbstractEventLoop | None = None
        self._bus: Bus | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    def start(self, timeout: float = 10.0) -> BusThread:
        self._thread = threading.Thread(target=self._main, name="modeltest-bus", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise LinkError(f"the zenoh session {self.description} did not open within {timeout:g} s")
        if self._error is not None:
            raise LinkError(f"cannot open the zenoh session {self.description}: {self._error}") from self._error
        return self

    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        self.loop = loop
        try:
            loop.run_until_complete(self._run())
        finally:
            loop.close()

    async def _run(self) -> None:
        self._stop = asyncio.Event()
        try:
            async with ZenohBus(self.config) as bus:
                self._bus = bus
                self._ready.set()
                await self._stop.wait()
        except Exception as exc:  # reported by start()
            self._error = exc
        finally:
            self._bus = None
            self._ready.set()

    @property
    def bus(self) -> Bus:
        if self._bus is None:
            raise LinkError("the zenoh session is closed")
        return self._bus

    @property
    def running(self) -> bool:
        return self._bus is not None

    def call(self, coro: Coroutine[Any, Any, T], timeout: float = 10.0) -> T:
        """Run `coro` on the bus's loop and wait for its result."""
        assert self.loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call_soon(self, function: Any, *args: Any) -> None:
        assert self.loop is not None
        with contextlib.suppress(RuntimeError):  # the loop is closing
            self.loop.call_soon_threadsafe(function, *args)

    def close(self) -> None:
        if self.loop is not None and self._stop is not None and self._thread is not None:
            with contextlib.suppress(RuntimeError):
                self.loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(10.0)


# One per (mode, listen, connect, lease_ms, certificate).
_SHARED: dict[tuple[NetworkMode, tuple[str, ...], tuple[str, ...], int, Path | None], BusThread] = {}
_SHARED_LOCK = threading.Lock()


def shared_bus(*, listen: Iterable[str] = (), connect: Iterable[str] = (), mode: NetworkMode = NetworkMode.PEER,
               lease_ms: int = 2000, tls: TlsSettings | None = None) -> BusThread:
    """One BusThread per network setting for the whole process (pytest sessions): a listener
    bound once stays bound, however many tests use it. Closed at exit."""
    key = (mode, tuple(listen), tuple(connect), lease_ms, tls.certificate if tls else None)
    with _SHARED_LOCK:
        existing = _SHARED.get(key)
        if existing is not None and existing.running:
            return existing
        described = f"(listen {', '.join(key[1]) or 'nothing'}; connect {', '.join(key[2]) or 'nothing'})"
        thread = BusThread(zenoh_config(mode, listen=key[1], connect=key[2], lease_ms=lease_ms, tls=tls),
                           description=described).start()
        _SHARED[key] = thread
        return thread


@atexit.register
def _close_shared() -> None:
    for thread in list(_SHARED.values()):
        with contextlib.suppress(Exception):
            thread.close()
    _SHARED.clear()


@dataclass(frozen=True)
class StateSample:
    """One state message of the tested resource, decoded, with the context when it arrived."""

    time: float  # local monotonic clock at receipt
    measured: dict[str, Value | None]  # by path
    mirror_seq: int | None
    mirror_controller: str | None
    mirror: dict[str, Value] | None  # the applied command, by path
    status: HubStatus
    detail: str
    hub: str
    context: dict[str, Value]  # other resources' variables, last known, by path


class ResourceLink:
    """Commands to one resource's hub and its states back, as the controller exchanges them."""

    def __init__(self, bus: BusThread, station: str, model: Model, resource: str, *,
                 context: Iterable[str] = (), command_rate_hz: float = 10.0, controller_id: str | None = None) -> None:
        self.bus = bus
        self.keys = station_keys(station)
        self.model = model
        self.resource = model.resource_by_name[resource]
        self.codec = Codec(self.resource)
        self.controller_id = controller_id or f"modeltest-{uuid.uuid4().hex[:8]}"
        self.period = 1.0 / command_rate_hz
        self.context_paths = tuple(context)
        self.samples: queue.Queue[StateSample] = queue.Queue()
        self.foreign: dict[str, float] = {}  # other controllers commanding this resource -> last seen
        self.controller_status: dict[str, float] = {}  # controllers publishing {station}/ctl/status
        self.error: str | None = None  # a reason the hub cannot be tested (another model)
        self.last_sample_at: float | None = None
        self._context: dict[str, Value] = {}
        self._seq = 0
        self._current: tuple[int, dict[str, Value]] | None = None  # (seq, values): replaced, never mutated
        _OWN_IDS.add(self.controller_id)
        self._subscriptions: list[Subscription[Any]] = []
        self._tasks: list[asyncio.Task[None]] = []
        self._holder: Token | None = None

    # --- lifecycle ----------------------------------------------------------------------------
    def open(self) -> ResourceLink:
        self.bus.call(self._open())
        return self

    async def _open(self) -> None:
        bus = self.bus.bus
        name = self.resource.name
        self._holder = declare_holder(bus, self.keys, self.controller_id)  # hubs apply the holder's commands only
        self._watch(bus.subscribe(self.keys.state(name), coalesce=False), self._on_state)
        self._watch(bus.subscribe(self.keys.cmd(name), coalesce=False), self._on_own_command)
        self._watch(bus.subscribe(self.keys.ctl("status")), self._on_status)
        by_resource: dict[str, set[Kind]] = {}
        for path in self.context_paths:
            var = self.model.var(path)
            if var.kind in (Kind.MEASURED, Kind.COMMAND) and var.resource != name:
                by_resource.setdefault(var.resource, set()).add(var.kind)
        for other, kinds in by_resource.items():
            codec = Codec(self.model.resource_by_name[other])
            if Kind.MEASURED in kinds:
                self._watch(bus.subscribe(self.keys.state(other)), self._context_handler(codec, codec.decode_state))
            if Kind.COMMAND in kinds:
                self._watch(bus.subscribe(self.keys.cmd(other)), self._context_handler(codec, codec.decode_command))
        self._tasks.append(asyncio.create_task(self._resend(), name=f"modeltest resend {name}"))

    def _watch(self, subscription: Subscription[Any], handler: Callable[[bytes], None]) -> None:
        self._subscriptions.append(subscription)

        async def consume() -> None:
            async for sample in subscription:
                try:
                    handler(sample.payload)
                except Exception:  # one bad sample never stops the link
                    log.exception("modeltest: dropped a sample on %s", sample.key)

        self._tasks.append(asyncio.create_task(consume(), name=f"modeltest {subscription.key}"))

    def close(self) -> None:
        if not self.bus.running:
            return

        async def stop() -> None:
            for task in self._tasks:
                task.cancel()
            for subscription in self._subscriptions:
                subscription.close()
            if self._holder is not None:
                self._holder.undeclare()

        with contextlib.suppress(Exception):
            self.bus.call(stop(), timeout=5.0)

    # --- incoming -----------------------------------------------------------------------------
    def _on_state(self, payload: bytes) -> None:
        try:
            state = self.codec.decode_state(payload)
        except ModelMismatch as exc:
            self.error = str(exc)
            return
        except MessageError as exc:
            log.warning("modeltest: ignored a state of %s: %s", self.resource.name, exc)
            return
        mirror = state.mirror
        now = time.monotonic()
        self.last_sample_at = now
        self.samples.put(StateSample(
            time=now,
            measured=self.codec.values(state, paths=True),
            mirror_seq=None if mirror is None else mirror.seq,
            mirror_controller=None if mirror is None else mirror.controller,
            mirror=None if mirror is None else self.codec.values(mirror, paths=True),
            status=state.status, detail=state.detail, hub=state.hub, context=dict(self._context)))

    def _on_own_command(self, payload: bytes) -> None:
        try:
            command = self.codec.decode_command(payload)
        except MessageError as exc:
            self.foreign[f"(unreadable command: {exc})"] = time.monotonic()
            return
        if command.controller not in _OWN_IDS:  # a link of this process that closed may still be in flight
            self.foreign[command.controller] = time.monotonic()

    def _on_status(self, payload: bytes) -> None:
        with contextlib.suppress(MessageError):
            status = decode(payload, StatusMessage)
            self.controller_status[status.controller] = time.monotonic()

    def _context_handler(self, codec: Codec, decode_message: Callable[[bytes], CommandMessage | StateMessage]
                         ) -> Callable[[bytes], None]:
        """Another resource's states or commands (read by `decode_message`): their values the guards read."""
        wanted = set(self.context_paths)

        def handle(payload: bytes) -> None:
            try:
                message = decode_message(payload)
            except MessageError:
                return
            for path, value in codec.values(message, paths=True).items():
                if path in wanted and value is not None:
                    self._context[path] = value

        return handle

    # --- commands -----------------------------------------------------------------------------
    def send(self, values: Mapping[str, Value]) -> int:
        """Command these values (every command variable, by short name) now and at the command rate
        from now on; returns the command's sequence number."""
        self._seq += 1
        values = dict(values)
        self.codec.command(values, seq=self._seq, controller=self.controller_id)  # domain check, here
        self._current = (self._seq, values)  # one assignment: the bus thread never sees a half-made command
        self.bus.call_soon(self._publish)
        return self._seq

    @property
    def seq(self) -> int:
        return self._seq

    def _publish(self) -> None:
        current = self._current
        if current is None or not self.bus.running:
            return
        seq, values = current
        message = self.codec.command(values, seq=seq, controller=self.controller_id)
        self.bus.bus.publish(self.keys.cmd(self.resource.name), self.codec.encode_command(message))

    async def _resend(self) -> None:
        while True:
            self._publish()
            await asyncio.sleep(self.period)

    # --- reading ------------------------------------------------------------------------------
    def next_sample(self, timeout: float) -> StateSample | None:
        try:
            return self.samples.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None

    def drain(self) -> list[StateSample]:
        items = []
        while True:
            try:
                items.append(self.samples.get_nowait())
            except queue.Empty:
                return items

    def listen_for_controllers(self, seconds: float) -> dict[str, float]:
        """Watch for `seconds`: other controllers commanding this resource (id -> last seen)."""
        time.sleep(seconds)
        return dict(self.foreign)


async def _watch_controllers(bus: Bus, keys: Keys, model: Model, resources: Iterable[str], seconds: float,
                             own: str | None) -> dict[str, set[str]]:
    seen: dict[str, set[str]] = {}
    subscriptions: list[tuple[str, Codec | None, Subscription[Any]]] = []
    for name in resources:
        subscriptions.append((name, Codec(model.resource_by_name[name]), bus.subscribe(keys.cmd(name),
                                                                                        coalesce=False)))
    subscriptions.append(("", None, bus.subscribe(keys.ctl("status"))))
    try:
        await asyncio.sleep(seconds)
        for name, codec, subscription in subscriptions:
            for sample in subscription.take_all():
                if codec is None:
                    with contextlib.suppress(MessageError):
                        status = decode(sample.payload, StatusMessage)
                        seen.setdefault(f"{status.controller} (publishes {keys.ctl('status')})", set())
                    continue
                try:
                    controller = codec.decode_command(sample.payload).controller
                except MessageError as exc:
                    controller = f"(unreadable command: {exc})"
                if controller != own and controller not in _OWN_IDS:
                    seen.setdefault(controller, set()).add(name)
    finally:
        for _, _, subscription in subscriptions:
            subscription.close()
    return seen


def watch_controllers(bus: BusThread, station: str, model: Model, resources: Iterable[str], seconds: float,
                      own: str | None = None) -> dict[str, set[str]]:
    """Listen `seconds` for controllers other than `own`: each id, with the resources it commands
    (empty for a controller seen only by its status)."""
    return bus.call(_watch_controllers(bus.bus, station_keys(station), model, tuple(resources), seconds, own),
                    timeout=seconds + 10.0)


def alive_hubs(bus: BusThread, station: str, timeout: float = 1.0) -> set[str]:
    """The hubs of the station whose liveliness token is alive now."""
    keys = station_keys(station)
    tokens = bus.call(bus.bus.alive_tokens(keys.all_alive, timeout=timeout), timeout + 5.0)
    return {hub for key in tokens if (hub := keys.hub_of(key)) is not None}
