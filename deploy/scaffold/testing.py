"""pytest support for station projects made by `hubctl new-station` and `hubctl new-device`.

A generated project enables it in its tests/conftest.py::

    pytest_plugins = ["deploy.modeltest.pytest_plugin", "deploy.scaffold.testing"]

* `station_hub` (fixture): `with station_hub(config, resource) as hub:` runs `hubctl hub`
  for the hub of `config` that serves `resource`, as a process of its own on a free
  loopback port, in the modes hubs.toml gives its devices; `hub.target` is where
  `model_test` (deploy/modeltest/pytest_plugin.py) finds it. Leaving the block stops the
  hub. When the block failed, or the hub died, the test fails with the hub's own errors
  (a driver's NotImplementedError, a configuration error) above the end of its log.
* `hubctl(*args)`: the hubctl of this environment, its output captured.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

import pytest

from common.config.hubs_toml import load_config
from common.plumbing.lifecycle import free_port

from ..modeltest.pytest_plugin import ModelTest
from ..modeltest.runner import Target

__all__ = ["HubRun", "ModelTest", "StationHubs", "hubctl", "station_hub"]

STARTUP_S = 30.0  # a bound for a hub process to start on a loaded machine, not a timing claim
STOP_S = 10.0
LOG_TAIL = 25
# "NotImplementedError: ...", "hubctl: hubs.toml:12: ...": the lines of a log that say what went wrong.
PROBLEM = re.compile(r"^(?:[\w.]*(?:Error|Exception)\b.*|hubctl: .*)$")


@dataclass
class Hubctl:
    returncode: int
    output: str  # stdout and stderr, interleaved


def hubctl_command() -> list[str]:
    """hubctl of the running interpreter's environment (the venv statehub is installed in)."""
    script = Path(sys.executable).parent / "hubctl"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "deploy.cli"]


def hubctl(*args: str | Path, timeout: float = 600.0) -> Hubctl:
    result = subprocess.run([*hubctl_command(), *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, timeout=timeout, check=False)
    return Hubctl(result.returncode, result.stdout)


@dataclass
class HubRun:
    """One `hubctl hub` process serving a resource's hub on loopback."""

    config: Path
    hub: str
    port: int
    log: Path
    process: subprocess.Popen[bytes] | None = None
    _target: Target | None = field(default=None, repr=False)

    @property
    def target(self) -> Target:
        """Where model_test finds the hub (the station's model, on the hub's loopback port)."""
        if self._target is None:
            self._target = Target.from_config(self.config, loopback_port=self.port)
        return self._target

    def start(self) -> None:
        argv = [*hubctl_command(), "hub", self.hub, "--config", str(self.config), "--loopback-port", str(self.port)]
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(argv, cwd=self.config.parent, stdout=log, stderr=subprocess.STDOUT,
                                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        deadline = time.monotonic() + STARTUP_S
        while self.alive and f"hub {self.hub} serving" not in self.text() and time.monotonic() < deadline:
            time.sleep(0.1)

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self) -> int | None:
        """Stop the hub; its exit code (None if it never ran)."""
        process = self.process
        if process is None:
            return None
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=STOP_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=STOP_S)
        return process.returncode

    def text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def problems(self) -> list[str]:
        """The hub's errors, each once, in order."""
        found = [line.strip() for line in self.text().splitlines() if PROBLEM.match(line.strip())]
        return list(dict.fromkeys(found))

    def describe(self, died: bool) -> str:
        ended = f" exited with code {self.process.returncode}" if died and self.process is not None else ""
        lines = [f"hub {self.hub} ({self.config}){ended}:"]
        lines += [f"  {problem}" for problem in self.problems()] or ["  no error in its log"]
        tail = self.text().splitlines()[-LOG_TAIL:]
        lines += [f"the end of its log ({self.log}):", *(f"  {line}" for line in tail)]
        return "\n".join(lines)


StationHubs = Callable[[str | Path, str], contextlib.AbstractContextManager[HubRun]]


def _hub_serving(config: Path, resource: str) -> str:
    station = load_config(config)
    owner = station.resources.get(resource)
    if owner is None:
        raise pytest.UsageError(f"{config}: no hub serves resource {resource!r} (served: "
                                f"{', '.join(sorted(station.resources)) or 'nothing'})")
    return owner.name


def _fail(message: str) -> NoReturn:
    # from None: the failure is the whole story, not a consequence of the model test's exception
    raise pytest.fail.Exception(message, pytrace=False) from None


@pytest.fixture
def station_hub(tmp_path: Path) -> StationHubs:
    """`with station_hub(config, resource) as hub:` the hub serving `resource`, running for the block."""

    @contextlib.contextmanager
    def run(config: str | Path, resource: str) -> Iterator[HubRun]:
        path = Path(config).resolve()
        hub = HubRun(path, _hub_serving(path, resource), free_port(), tmp_path / f"hub-{resource}.log")
        hub.start()
        failure: Exception | None = None
        try:
            if hub.alive:
                try:
                    yield hub
                except Exception as exc:  # the model test's report: shown with what the hub said
                    failure = exc
            died = not hub.alive
            code = hub.stop()
        finally:
            hub.stop()
        if died and (code or failure is not None):  # the hub's own error first: it is the cause
            _fail(hub.describe(died=True) + (f"\n\n{failure}" if failure else ""))
        if failure is not None:
            _fail(f"{failure}\n\n{hub.describe(died=False)}")

    return run
