"""What every long-running statehub process shares: logging, stopping on signals, its network, its errors.

The processes are `python -m hubs` and `python -m controller` (also `hubctl hub` and
`hubctl controller`); each reports an expected error (a bad hubs.toml, an invalid model) as
one line naming the process and exits 2, as hubctl does, instead of a traceback.
"""

from __future__ import annotations

import argparse
import asyncio
import atexit
import faulthandler
import logging
import os
import random
import signal
import socket
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from common.config.hubs_toml import ConfigError, NetworkConfig, StationConfig
from common.config.security import SecurityError
from common.model import ModelError
from common.stations import ModelLoadError

# What a process reports as one line: the operator's input is wrong, not the program.
# A file that cannot be read (a --config, --db or --params-file path) is the operator's input too.
EXPECTED_ERRORS: tuple[type[BaseException], ...] = (
    ConfigError, ModelError, ModelLoadError, SecurityError, argparse.ArgumentTypeError,
    FileNotFoundError, IsADirectoryError, PermissionError,
)


def setup_logging(name: str, verbose: bool = False) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format=f"%(asctime)s {name} %(levelname)s %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger("zenoh").setLevel(logging.WARNING)


# A process asked to stop has this long to exit (its units give systemd's TimeoutStopSec=10s): then it
# prints every thread's stack and exits 1, where systemd would SIGKILL it with no word of what hung.
EXIT_GUARD_S = 8.0


def stop_on_signals(exit_within: float | None = EXIT_GUARD_S) -> asyncio.Event:
    """An event set on SIGINT or SIGTERM. From the first signal on, the process exits within
    `exit_within` seconds whatever happens: faulthandler's watchdog is a thread of its own in C, so a
    loop or a thread stuck in a call that never returns (a device, a lock, an executor joined at exit)
    cannot hold the exit up, and the stacks it prints say where it hung."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()

    def on_signal() -> None:
        if not stop.is_set() and exit_within is not None:
            faulthandler.dump_traceback_later(exit_within, exit=True, file=sys.stderr)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, on_signal)
    return stop


def network(config: StationConfig, process: str, loopback_port: int | None) -> NetworkConfig:
    """The process's network as hubs.toml gives it, or on loopback with the controller listening on the port."""
    return config.network_for(process) if loopback_port is None else config.loopback_network(process, loopback_port)


EPHEMERAL_RANGE_FILE = Path("/proc/sys/net/ipv4/ip_local_port_range")
LOWEST_CHOSEN_PORT = 10_000


def _ephemeral_ports() -> range:
    """The ports the kernel hands out by itself (bind to port 0, the local end of every outgoing connection)."""
    try:
        low, high = (int(v) for v in EPHEMERAL_RANGE_FILE.read_text().split())
    except (OSError, ValueError):
        low, high = 32768, 60999  # Linux's default
    return range(low, high + 1)


def free_port() -> int:
    """A TCP port on loopback that nothing listens on now: where a station run on loopback listens.

    Chosen at random *below* the kernel's ephemeral range: a port the kernel picked for a bind to port 0
    is free now, but until our process binds it (a second later, once it has started) any outgoing
    connection on this machine may take it as its local end ("Address already in use"). Below the range
    only another caller choosing the same port at random can."""
    ephemeral = _ephemeral_ports()
    candidates = range(LOWEST_CHOSEN_PORT, ephemeral.start)
    for _ in range(50 if candidates else 0):
        port = random.choice(candidates)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    with socket.socket() as s:  # nothing free below the range: the kernel's choice
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def positive(text: str) -> float:
    """An argparse type: a number above zero (a speed factor, a time)."""
    value = float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def run_main(prog: str, body: Callable[[], int],
             expected: tuple[type[BaseException], ...] = EXPECTED_ERRORS) -> int:
    """Run a process's `main` body: an expected error becomes `prog: message` and status 2,
    Ctrl-C status 130."""
    try:
        return int(body() or 0)
    except expected as exc:
        print(f"{prog}: {one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


def exit_process(code: int | None) -> NoReturn:
    """Leave a process that has used zenoh with `code`: exit handlers run and output is flushed, then the
    process ends without the interpreter's teardown. A thread of zenoh's runtime that calls into Python
    while the interpreter tears down is ended by a forced unwind its Rust frames catch, and glibc aborts
    the process ("FATAL: exception not rethrown", status -6) after it has said and done everything:
    `hubctl test` reported its failing hub and then died of SIGABRT instead of exiting 1."""
    code = int(code or 0)
    try:
        atexit._run_exitfuncs()
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
    except BrokenPipeError:  # the reader went away; the status still counts
        pass
    os._exit(code)


def one_line(exc: BaseException) -> str:
    """An expected error as the one line a process prints: a file that cannot be read is named."""
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"cannot read {exc.filename}: {exc.strerror}"
    return str(exc)
