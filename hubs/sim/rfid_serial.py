"""A simulated EM4100 RFID reader on a pseudo-terminal pair.

The simulator holds the pty master; the driver opens the slave side with pyserial like
the reader's ``/dev/ttyUSB0``.  Because a new pty gets a new ``/dev/pts/N`` each time,
the simulator maintains a stable symlink (``link``, like udev's
``/dev/serial/by-id/...``) that always points at the current slave.

Frame format (16 bytes, what common 125 kHz EM4100 readers send per scan)::

    STX (0x02) | 10 hex chars: the 5 tag bytes | 2 hex chars: XOR of the 5 bytes | CR LF | ETX (0x03)

``scan(tag)`` sends a badge presentation (``repeats`` frames, as a reader repeats while
the badge stays in the field), ``send_corrupted(tag)`` a frame with a wrong checksum,
``send_raw`` anything.  ``stop()`` closes the master: the driver's next read fails
with EIO, like an unplugged USB reader; ``start()`` creates a fresh pty and moves the
symlink to it.  Runnable as a process too (``python -m hubs.sim.rfid_serial --link PATH``):
it prints the slave path and then scans every tag read from stdin, one per line.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import threading
import time
import tty
from pathlib import Path

from hubs.protocols.em4100 import ETX, STX, TAG_CHARS, checksum
from hubs.sim.registry import SimServer, SimulatedDevice, SimulatorPlugin, python_module


def frame(tag: str, *, corrupt: bool = False) -> bytes:
    tag = tag.upper()
    if len(tag) != TAG_CHARS:
        raise ValueError(f"an EM4100 tag is {TAG_CHARS} hex characters")
    check = checksum(bytes.fromhex(tag)) ^ (0x5A if corrupt else 0)
    return bytes([STX]) + f"{tag}{check:02X}".encode("ascii") + b"\r\n" + bytes([ETX])


class RfidReaderSim:
    def __init__(self, link: str | os.PathLike[str] | None = None) -> None:
        self.link = Path(link) if link is not None else None
        self._master: int | None = None
        self._slave: int | None = None
        self.slave_path = ""
        self.frames_sent = 0
        self._lock = threading.Lock()

    @property
    def path(self) -> str:
        """The path the driver opens: the stable symlink if there is one, else the slave pty."""
        return str(self.link) if self.link is not None else self.slave_path

    @property
    def running(self) -> bool:
        return self._master is not None

    def start(self) -> str:
        if self._master is not None:
            return self.path
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing before the driver configures the port
        self._master, self._slave = master, slave
        self.slave_path = os.ttyname(slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.slave_path)
            tmp.replace(self.link)  # atomic: the driver never sees a missing link while we restart
        return self.path

    def stop(self, *, remove_link: bool = False) -> None:
        """The reader vanishes (unplugged)."""
        with self._lock:
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
        if remove_link and self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()

    def send_raw(self, data: bytes) -> None:
        with self._lock:
            if self._master is None:
                raise OSError("reader not running")
            os.write(self._master, data)

    def scan(self, tag: str, repeats: int = 1, interval: float = 0.0) -> None:
        """A badge held to the reader: ``repeats`` identical frames."""
        for i in range(repeats):
            self.send_raw(frame(tag))
            self.frames_sent += 1
            if interval and i + 1 < repeats:
                time.sleep(interval)

    def send_corrupted(self, tag: str) -> None:
        self.send_raw(frame(tag, corrupt=True))
        self.frames_sent += 1

    def __enter__(self) -> RfidReaderSim:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop(remove_link=True)


# --- as a simulator plugin (device type rfid) --------------------------------------------------

OPERATOR_TAG = "5A0017C3E1"  # the simulated operator's badge, the one the sim world presents


def _server(device: SimulatedDevice) -> SimServer:
    link = device.run_dir.resolve() / f"{device.resource}.tty"
    return SimServer(python_module("hubs.sim.rfid_serial", "--link", str(link)), ready=r"^(\S+)$",
                     driver_params=lambda _path: {"serial_port": str(link),
                                                  "operators": {OPERATOR_TAG: "simulated operator"}},
                     control=True, files=(link,))


PLUGIN = SimulatorPlugin("RFID reader", server=_server)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Simulated EM4100 RFID reader on a pty")
    parser.add_argument("--link", help="stable symlink to the slave pty (e.g. /tmp/rfid0)")
    args = parser.parse_args(argv)
    sim = RfidReaderSim(args.link)
    print(sim.start(), flush=True)
    try:
        for line in sys.stdin:
            tag = line.strip()
            if tag:
                sim.scan(tag)
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop(remove_link=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
