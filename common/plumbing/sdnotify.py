"""systemd's notify protocol from the processes' loops: READY=1 once serving, WATCHDOG=1 while the loop runs.

The units (deploy/remote/units.py) are `Type=notify` with `WatchdogSec=`: systemd restarts a hub or the
controller whose loop stops turning, not only one whose process exits. A datagram to `$NOTIFY_SOCKET`
(a path, or an abstract socket when it starts with `@`); nothing at all without it (tests, `hubctl up`).
The watchdog is fed at half its period (`$WATCHDOG_USEC`), however often the loop calls `alive()`.
"""

from __future__ import annotations

import logging
import os
import socket
import time

log = logging.getLogger("statehub.sdnotify")


class Notifier:
    def __init__(self, environ: os._Environ[str] | dict[str, str] = os.environ) -> None:
        address = environ.get("NOTIFY_SOCKET", "")
        self._address = "\0" + address[1:] if address.startswith("@") else address
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) if address else None
        usec = environ.get("WATCHDOG_USEC", "")
        for_us = environ.get("WATCHDOG_PID", str(os.getpid())) == str(os.getpid())
        self.period = int(usec) / 2e6 if usec.isdigit() and for_us else None
        self._fed = 0.0

    def ready(self) -> None:
        self._send(b"READY=1")

    def alive(self) -> None:
        """From the loop, every round: feeds the watchdog when half its period has passed."""
        if self.period is None:
            return
        now = time.monotonic()
        if now - self._fed >= self.period:
            self._fed = now
            self._send(b"WATCHDOG=1")

    def _send(self, message: bytes) -> None:
        if self._socket is None:
            return
        try:
            self._socket.sendto(message, self._address)
        except OSError as exc:  # systemd gone (shutdown): nothing to tell
            log.debug("sd_notify %s: %s", message.decode(), exc)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None
