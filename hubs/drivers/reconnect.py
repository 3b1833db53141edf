"""Reconnection with backoff: the one retry loop every driver shares.

After aioesphomeapi's ``ReconnectLogic``: a driver hands this object a ``connect``
coroutine (open the device, configure it, start any receive task; raise on failure)
and a ``disconnect`` coroutine (release whatever ``connect`` opened; must not raise).
The object keeps the device connected in the background:

* ``start()`` returns at once; a background task calls ``connect`` until it succeeds,
  waiting between attempts with exponential backoff (``Backoff``: factor, cap, jitter).
* The driver reports a lost device with ``connection_lost(reason)`` from any of its
  coroutines (a failed read, a missed heartbeat, a stale timestamp).  ``connected``
  turns false *at once*, so the very next ``read`` raises ``DeviceUnavailable``;
  then ``disconnect`` runs and reconnection starts after the next backoff delay.
  Threads report with ``connection_lost_threadsafe``.
* The backoff resets only after a connection stayed up ``stable_after`` seconds, so a
  device that accepts and drops at once is retried with growing delays, not hammered.
* ``on_state(connected, reason)`` is called on every change (for logs and hub status).
* ``stop()`` cancels everything and runs ``disconnect`` if needed.
* ``wait_connected(t)`` waits for a connection; ``wait_attempt()`` waits only for the
  verdict of the first connect attempt (what a self-test wants).

No driver writes its own retry loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

from .base import Driver

log = logging.getLogger(__name__)

ConnectFn = Callable[[], Awaitable[None]]
StateCallback = Callable[[bool, str], None]


@dataclass
class Backoff:
    """Exponential backoff: ``initial * factor**n``, capped at ``maximum``, times (1 ± ``jitter``)."""

    initial: float = 0.2
    maximum: float = 5.0
    factor: float = 2.0
    jitter: float = 0.2
    rng: random.Random = field(default_factory=random.Random)
    attempt: int = 0

    def next_delay(self) -> float:
        base = min(self.maximum, self.initial * self.factor**self.attempt)
        self.attempt += 1
        spread = base * self.jitter
        return max(0.0, base + self.rng.uniform(-spread, spread))

    def reset(self) -> None:
        self.attempt = 0



def describe(exc: BaseException) -> str:
    """A one-line reason for logs and reports."""
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class ReconnectLogic:
    """Keeps one device connected: connect, report loss, back off, reconnect, stop."""

    def __init__(
        self,
        name: str,
        connect: ConnectFn,
        disconnect: ConnectFn | None = None,
        *,
        on_state: StateCallback | None = None,
        backoff: Backoff | None = None,
        connect_timeout: float = 5.0,
        stable_after: float = 2.0,
    ) -> None:
        self.name = name
        self._connect = connect
        self._disconnect = disconnect
        self._on_state = on_state
        self.backoff = backoff or Backoff()
        self.connect_timeout = connect_timeout
        self.stable_after = stable_after
        self._connected = False
        self._task: asyncio.Task[None] | None = None
        self._lost = asyncio.Event()
        self._stopping = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._since = 0.0
        self.last_error = "not connected yet"
        self.attempts = 0  # connect attempts since start (for reports and tests)
        self.connects = 0  # successful connects since start
        self._up = asyncio.Event()
        self._attempted = asyncio.Event()  # set once the first connect attempt has finished

    # -- public API -----------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    async def start(self) -> None:
        """Start (re)connecting in the background; returns at once."""
        if self.running:
            return
        self._stopping = False
        self._loop = asyncio.get_running_loop()
        self._task = asyncio.create_task(self._run(), name=f"reconnect:{self.name}")

    async def stop(self) -> None:
        """Stop reconnecting and release the device."""
        self._stopping = True
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        was = self._connected
        self._connected = False
        self._up.clear()
        await self._safe_disconnect()
        if was:
            self._notify(False, "stopped")

    def connection_lost(self, reason: str) -> None:
        """The driver saw its device go: report it now, reconnect in the background."""
        if not self._connected:
            self.last_error = reason
            self._lost.set()  # also aborts a connect in progress that already saw the failure
            return
        self._connected = False
        self._up.clear()
        self.last_error = reason
        log.warning("%s: device lost: %s", self.name, reason)
        self._notify(False, reason)
        self._lost.set()

    def connection_lost_threadsafe(self, reason: str) -> None:
        """`connection_lost` from a thread other than the event loop's."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):  # loop closing
            loop.call_soon_threadsafe(self.connection_lost, reason)

    async def wait_connected(self, timeout: float) -> bool:
        """Wait until connected (True) or the timeout passes (False)."""
        if self._connected:
            return True
        try:
            async with asyncio.timeout(timeout):
                await self._up.wait()
        except TimeoutError:
            return self._connected
        return self._connected

    async def wait_attempt(self, timeout: float | None = None) -> bool:
        """Wait until connected or until a connect attempt has failed; True when connected.

        What a self-test wants: the verdict of the first attempt, not a wait for a device that
        has already refused."""
        if self._connected:
            return True
        if timeout is None:
            timeout = self.connect_timeout + 0.5
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout):
                await self._attempted.wait()
        return self._connected

    # -- the loop -------------------------------------------------------------------

    async def _run(self) -> None:
        while not self._stopping:
            self._lost.clear()
            self.attempts += 1
            try:
                async with asyncio.timeout(self.connect_timeout):
                    await self._connect()
                if self._lost.is_set():
                    raise ConnectionError(self.last_error)
            except asyncio.CancelledError:
                raise  # stop() releases the device
            except Exception as exc:
                self.last_error = describe(exc)
                log.info("%s: connect failed: %s", self.name, self.last_error)
                self._attempted.set()
                await self._safe_disconnect()
                await asyncio.sleep(self.backoff.next_delay())
                continue
            self.connects += 1
            self._since = time.monotonic()
            self._connected = True
            self._up.set()
            self._attempted.set()
            self.last_error = ""
            log.info("%s: connected", self.name)
            self._notify(True, "connected")
            await self._lost.wait()
            # connection_lost already flipped `connected` and notified.
            if time.monotonic() - self._since >= self.stable_after:
                self.backoff.reset()
            await self._safe_disconnect()
            await asyncio.sleep(self.backoff.next_delay())

    async def _safe_disconnect(self) -> None:
        if self._disconnect is None:
            return
        try:
            async with asyncio.timeout(self.connect_timeout):
                await self._disconnect()
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # releasing a dead device may fail; it must not stop the loop
            log.debug("%s: disconnect failed: %s", self.name, describe(exc))

    def _notify(self, connected: bool, reason: str) -> None:
        if self._on_state is None:
            return
        try:
            self._on_state(connected, reason)
        except Exception:
            log.exception("%s: on_state callback failed", self.name)


class Link(Protocol):
    """What a driver's device connection offers: `ReconnectLogic`, or a protocol link built on it."""

    @property
    def connected(self) -> bool: ...

    async def start(self) -> None: ...

    async def stop(self) -> None: ...


L = TypeVar("L", bound=Link)


class LinkedDriver(Driver, Generic[L]):
    """A driver whose device connection is one link: connecting, closing and `connected` are
    the link's. Subclasses set `self._link` in their constructor."""

    _link: L

    @property
    def connected(self) -> bool:
        return self._link.connected

    @property
    def link(self) -> L:
        return self._link

    async def connect(self) -> None:
        await self._link.start()

    async def close(self) -> None:
        await self._link.stop()
