"""What every long-running statehub process shares: logging, stopping on signals, its network, its errors.

The processes are `python -m hubs` and `python -m controller` (also `hubctl hub` and
`hubctl controller`); each reports an expected error (a bad hubs.toml, an invalid model) as
one line naming the process and exits 2, as hubctl does, instead of a traceback.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import socket
import sys
from collections.abc import Callable

from .config import ConfigError, NetworkConfig, StationConfig
from .model import ModelError
from .security import SecurityError
from .stations import ModelLoadError

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


def stop_on_signals() -> asyncio.Event:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    return stop


def network(config: StationConfig, process: str, loopback_port: int | None) -> NetworkConfig:
    """The process's network as hubs.toml gives it, or on loopback with the controller listening on the port."""
    return config.network_for(process) if loopback_port is None else config.loopback_network(process, loopback_port)


def free_port() -> int:
    """A TCP port on loopback that nothing listens on now: where a station run on loopback listens."""
    with socket.socket() as s:
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


def one_line(exc: BaseException) -> str:
    """An expected error as the one line a process prints: a file that cannot be read is named."""
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"cannot read {exc.filename}: {exc.strerror}"
    return str(exc)
