"""RFID badge reader on a serial port, EM4100 ASCII frames (pyserial).

Frame (16 bytes, 9600 8N1 by default)::

    STX 0x02 | 10 ASCII hex chars: tag (5 bytes) | 2 ASCII hex chars: XOR of the 5 tag bytes | CR LF | ETX 0x03

A frame with a bad length, non-hex characters or a wrong checksum is ignored and counted
(``stats["bad_frames"]``); bytes outside STX…ETX are dropped and counted as noise.

``verified_m`` (an operator is logged in at the station):

* a tag on the allow-list (``operators``) logs that operator in: ``verified_m = true``;
* the *same* tag presented again logs out (badge in, badge out); a different allowed
  tag switches the operator and stays verified;
* frames of one tag within ``repeat_window`` s of the previous one are one presentation
  (readers repeat the frame while the badge stays in the field);
* an unknown tag changes nothing (``stats["rejected"]``);
* the login expires ``session_timeout`` s (default 8 h, a shift) after it began (0 = never);
* a lost reader logs out: after it returns, the operator badges again.

The reader only talks when a badge is presented, so the link is judged by the port:
the reader is lost when the port fails (unplugged USB adapter: read error or EIO) or
disappears.  A silent but healthy reader is indistinguishable from an idle one; the
self-test says so.

Reads run in a dedicated thread (pyserial is blocking, read timeout 50 ms) that hands
bytes to the event loop; the shared ReconnectLogic reopens the port with backoff.
Safe state: none (no outputs).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Annotated

import msgspec
import serial

from common.model import Value
from hubs.drivers import badge_readers
from hubs.drivers.base import DeviceUnavailable, NoOutputs, SelftestReport
from hubs.drivers.params import DriverParams, NonNegative
from hubs.drivers.reconnect import Backoff, LinkedDriver, ReconnectLogic, describe
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.em4100 import BAUDRATE, ETX, FRAME_BODY, STX, TAG_CHARS, checksum

log = logging.getLogger(__name__)

MAX_BUFFER = 256


def parse_body(body: bytes) -> str | None:
    """The tag in a frame body (between STX and ETX), None when the frame is bad."""
    if len(body) != FRAME_BODY or body[-2:] != b"\r\n":
        return None
    try:
        text = body[:-2].decode("ascii")
        raw = bytes.fromhex(text[:TAG_CHARS])
        check = int(text[TAG_CHARS:], 16)
    except ValueError:
        return None
    return text[:TAG_CHARS].upper() if checksum(raw) == check else None


class RfidSerial(NoOutputs, LinkedDriver[ReconnectLogic]):
    def __init__(
        self,
        resource: str = "rfid",
        *,
        port: str,
        baudrate: int = BAUDRATE,
        operators: Iterable[str] | Mapping[str, str] = (),
        session_timeout: float = 8 * 3600.0,
        repeat_window: float = 1.0,
        backoff: Backoff | None = None,
        serial_factory: Callable[[], serial.Serial] | None = None,
    ) -> None:
        self.resource = resource
        self.port = port
        self.baudrate = baudrate
        self.operators: dict[str, str] = (
            {k.upper(): v for k, v in operators.items()}
            if isinstance(operators, Mapping)
            else {t.upper(): t.upper() for t in operators}
        )
        self.session_timeout = session_timeout
        self.repeat_window = repeat_window
        self._serial_factory = serial_factory or self._open_port
        self._serial: serial.Serial | None = None
        self._thread: threading.Thread | None = None
        self._stop_reader = threading.Event()
        self._buffer = bytearray()
        self._operator: str | None = None
        self._login_time = 0.0
        self._last_tag: tuple[str, float] | None = None
        self.stats = {"frames": 0, "bad_frames": 0, "noise_bytes": 0, "rejected": 0, "logins": 0, "logouts": 0}
        self._link = ReconnectLogic(
            f"{resource}@{port}", self._open, self._release, backoff=backoff, on_state=self._on_state
        )
        badge_readers.register(resource, self)  # the operator's page on this hub shows who it is

    # -- Driver API -------------------------------------------------------------------

    @property
    def operator(self) -> str | None:
        """The logged-in operator's name (from the allow-list), None when nobody is."""
        self._expire()
        return self.operators.get(self._operator) if self._operator else None

    async def read(self) -> Mapping[str, Value]:
        if not self.connected:
            raise DeviceUnavailable(f"{self.resource}: reader on {self.port} not connected ({self._link.last_error})")
        self._expire()
        return {"verified_m": self._operator is not None}

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self._link.wait_attempt():
            report.add("device answers", False, f"cannot open {self.port}: {self._link.last_error}")
            report.add("inputs read", False, "not checked: port not open")
            return report
        report.add("device answers", True, f"{self.port} open at {self.baudrate} Bd (the reader talks only on a scan)")
        try:
            ser = self._serial
            waiting = await asyncio.to_thread(lambda: ser.in_waiting) if ser is not None else 0
            stats = ", ".join(f"{k}={v}" for k, v in self.stats.items())
            report.add("inputs read", True, f"{waiting} bytes waiting; {stats}")
        except (OSError, serial.SerialException) as exc:
            report.add("inputs read", False, describe(exc))
        report.add("outputs read back", True, "not applicable: the reader has no outputs")
        return report

    # -- frames -----------------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Bytes from the port (event loop thread)."""
        self._buffer += data
        while True:
            start = self._buffer.find(STX)
            if start < 0:
                self.stats["noise_bytes"] += len(self._buffer)
                self._buffer.clear()
                return
            if start:
                self.stats["noise_bytes"] += start
                del self._buffer[:start]
            end = self._buffer.find(ETX, 1)
            if end < 0:
                if len(self._buffer) > MAX_BUFFER:
                    self.stats["bad_frames"] += 1
                    self._buffer.clear()
                return
            body = bytes(self._buffer[1:end])
            del self._buffer[: end + 1]
            if STX in body:  # a frame cut short and a new one started: keep the new one
                self.stats["bad_frames"] += 1
                self._buffer[:0] = body[body.rindex(STX) :] + bytes([ETX])
                continue
            tag = parse_body(body)
            if tag is None:
                self.stats["bad_frames"] += 1
                log.info("%s: bad frame ignored: %r", self.resource, body)
                continue
            self.stats["frames"] += 1
            self._presented(tag, time.monotonic())

    def _presented(self, tag: str, now: float) -> None:
        last, self._last_tag = self._last_tag, (tag, now)
        if last is not None and last[0] == tag and now - last[1] <= self.repeat_window:
            return  # the same presentation, repeated by the reader
        if tag not in self.operators:
            self.stats["rejected"] += 1
            log.info("%s: unknown tag %s rejected", self.resource, tag)
            return
        self._expire()
        if self._operator == tag:
            self._operator = None
            self.stats["logouts"] += 1
        else:
            self._operator, self._login_time = tag, now
            self.stats["logins"] += 1

    def _expire(self) -> None:
        if self._operator is None or self.session_timeout <= 0:
            return
        if time.monotonic() - self._login_time > self.session_timeout:
            log.info("%s: session of %s expired", self.resource, self._operator)
            self._operator = None
            self.stats["logouts"] += 1

    def _on_state(self, connected: bool, reason: str) -> None:
        if not connected:
            self._last_tag = None  # the next frame is a new presentation
        if not connected and self._operator is not None:
            self._operator = None
            self.stats["logouts"] += 1
            log.info("%s: reader lost, operator logged out", self.resource)

    # -- port -------------------------------------------------------------------------

    def _open_port(self) -> serial.Serial:
        return serial.Serial(self.port, self.baudrate, timeout=0.05)

    def _pump(self, ser: serial.Serial, loop: asyncio.AbstractEventLoop) -> None:
        while not self._stop_reader.is_set():
            try:
                data = ser.read(ser.in_waiting or 1)
            except (OSError, serial.SerialException, TypeError, AttributeError) as exc:
                if not self._stop_reader.is_set():
                    self._link.connection_lost_threadsafe(f"serial read failed: {describe(exc)}")
                return
            if data:
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(self.feed, data)

    async def _open(self) -> None:
        self._buffer.clear()
        ser = await asyncio.to_thread(self._serial_factory)
        self._serial = ser
        self._stop_reader.clear()
        self._thread = threading.Thread(
            target=self._pump, args=(ser, asyncio.get_running_loop()), name=f"serial-{self.resource}", daemon=True
        )
        self._thread.start()

    async def _release(self) -> None:
        self._stop_reader.set()
        thread, self._thread = self._thread, None
        ser, self._serial = self._serial, None

        def shutdown() -> None:  # one thread call: finishes even if this coroutine is cancelled
            if thread is not None:
                thread.join(1.0)
            if ser is not None:
                with contextlib.suppress(Exception):
                    ser.close()

        await asyncio.to_thread(shutdown)


class RfidParams(DriverParams, frozen=True, kw_only=True):
    serial_port: str
    baudrate: Annotated[int, msgspec.Meta(gt=0)] = BAUDRATE
    operators: list[str] | dict[str, str] = []  # allowed tags, or {tag: operator name}
    session_timeout: NonNegative = 8 * 3600.0  # 0: never
    repeat_window: NonNegative = 1.0


def build(resource: str, params: RfidParams) -> RfidSerial:
    return RfidSerial(resource, port=params.serial_port, baudrate=params.baudrate, operators=params.operators,
                      session_timeout=params.session_timeout, repeat_window=params.repeat_window,
                      backoff=params.backoff())


PLUGIN = DriverPlugin(RfidParams, build)
