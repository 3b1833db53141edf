"""A hub as a separate OS process (`python -m hubs NAME --config C --loopback-port P ...`), as its unit runs it.

`HubProcess.restart()` is a power cycle. The `hub_process` fixture (conftest.py) starts them for
one test; `running_hub` for a longer scope (a module's fixture).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STOP_GRACE_S = 10.0


class HubProcess:
    """One hub of `config`, on loopback with the controller (or a test playing it) listening on `port`."""

    def __init__(self, config: Path, hub: str, port: int, log: Path, *options: str) -> None:
        self.config, self.hub, self.port, self.log, self.options = config, hub, port, log, options
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> HubProcess:
        argv = [sys.executable, "-m", "hubs", self.hub, "--config", str(self.config),
                "--loopback-port", str(self.port), *self.options]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
        return self

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self) -> None:
        """SIGTERM, as systemd stops it; SIGKILL if it does not exit in time."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=STOP_GRACE_S)
        self.process = None

    def kill(self) -> None:
        """kill -9: a crash, with no goodbye on the bus."""
        assert self.process is not None, f"{self.hub} is not running"
        self.process.kill()
        self.process.wait()

    def restart(self) -> None:
        self.stop()
        self.start()


@contextlib.contextmanager
def running_hub(config: Path, hub: str, port: int, log: Path, *options: str) -> Iterator[HubProcess]:
    process = HubProcess(config, hub, port, log, *options).start()
    try:
        yield process
    finally:
        process.stop()
