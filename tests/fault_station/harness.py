"""A whole station as real OS processes over Zenoh on loopback, and a watcher that records it.

    with Station(tmp_path) as station:
        station.start()                         # controller, then every hub of hubs.toml
        station.wait_for(lambda: station.watch.finished(), 30, "the station finishes")
        station.kill("pi-tool"); station.start_hub("pi-tool")
        station.freeze("ur10"); station.thaw("ur10")

Each process is `python -m controller` or `python -m hubs HUB ...` (what `hubctl up` and the
systemd units run) with `--loopback-port`, in its own session, logging to a file in
the test's temporary directory. `Station` is synchronous: its `Watcher` (watcher.py) runs
its `Bus` on an event loop in a background thread and records every status, state snapshot,
resource state and command, with the receive time.

`close()` (or leaving the `with`) always stops every process (SIGCONT first if frozen,
then SIGTERM, then SIGKILL) and prints the tail of each log, which pytest shows for a
failing test.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from common.config.hubs_toml import load_station
from common.plumbing.lifecycle import free_port
from tests.fault_station.watcher import Watcher

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = Path(__file__).with_name("hubs.toml")
LAZY_HUB = Path(__file__).with_name("lazy_hub.py")
STOP_GRACE_S = 5.0
START_ATTEMPTS = 3  # starts of the whole station before a record that misses a device's boot fails the test
LOG_TAIL_CHARS = 4000

T = TypeVar("T")


def write_config(directory: Path, template: Path = TEMPLATE, *, prefix: str = "fault",
                 replace: Iterable[tuple[str, str]] = ()) -> Path:
    """A copy of `template` (a hubs.toml) with a station name unique to this run, so that runs on one
    machine never hear each other, and text replacements."""
    text, count = re.subn(r'(?m)^name = "[^"]*"', f'name = "{prefix}_{os.getpid()}_{uuid.uuid4().hex[:6]}"',
                          template.read_text(), count=1)
    if count != 1:
        raise ValueError(f"{template}: no station name")
    for old, new in replace:
        if old not in text:
            raise ValueError(f"{template}: no {old!r} to replace")
        text = text.replace(old, new)
    path = directory / "hubs.toml"
    path.write_text(text)
    return path


# --- the processes -------------------------------------------------------------------------

@dataclass
class Process:
    name: str
    argv: list[str]
    log: Path
    popen: subprocess.Popen[bytes] | None = None
    frozen: bool = False
    runs: int = 0
    stopped: bool = False  # stopped (or killed) by the test: its exit is no failure

    @property
    def pid(self) -> int:
        assert self.popen is not None, f"{self.name} was never started"
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def tail(self, chars: int = LOG_TAIL_CHARS) -> str:
        if not self.log.exists():
            return "(no log)"
        text = self.log.read_text(errors="replace")
        return text[-chars:]


class Station:
    """The controller and the hubs of a hubs.toml as processes, plus a `Watcher`. `hold`: the controller
    runs with `--hold` (nothing starts by itself: the operator starts the operations)."""

    def __init__(self, directory: Path, *, config: Path | None = None, speed: float = 1.0,
                 replace: Iterable[tuple[str, str]] = (), hold: bool = False) -> None:
        self.dir = directory
        self.config_path = config or write_config(directory, replace=replace)
        self.hold = hold
        self.config, self.model = load_station(self.config_path)
        self.keys = self.config.keys
        self.port = free_port()
        self.db = directory / "controller.sqlite"
        self.speed = speed
        self.processes: dict[str, Process] = {}
        self.watch = Watcher(self.config, self.model, self.port)
        self._env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT),
                                                                              os.environ.get("PYTHONPATH")]))}

    def __enter__(self) -> Station:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # starting and stopping
    def _spawn(self, name: str, argv: list[str]) -> Process:
        old = self.processes.get(name)
        if old is not None and old.alive():
            raise RuntimeError(f"{name} is already running (pid {old.pid})")
        runs = old.runs + 1 if old is not None else 1
        log = self.dir / f"{name}.{runs}.log"
        process = Process(name, argv, log, runs=runs)
        with log.open("wb") as handle:
            process.popen = subprocess.Popen(argv, cwd=ROOT, env=self._env, stdout=handle,
                                             stderr=subprocess.STDOUT, start_new_session=True)
        self.processes[name] = process
        return process

    def start_controller(self, *, fresh: bool = True, mirror_wait: float = 5.0) -> Process:
        argv = [sys.executable, "-m", "controller", "--config", str(self.config_path),
                "--loopback-port", str(self.port), "--db", str(self.db), "--mirror-wait", str(mirror_wait)]
        if fresh:
            argv.append("--fresh")
        if self.hold:
            argv.append("--hold")
        return self._spawn("controller", argv)

    def start_hub(self, hub: str, *, lazy: int | None = None) -> Process:
        """A hub of hubs.toml; `lazy=N`: tests/fault_station/lazy_hub.py instead (applies N commands, no more)."""
        if lazy is not None:
            argv = [sys.executable, str(LAZY_HUB), hub, "--config", str(self.config_path),
                    "--loopback-port", str(self.port), "--speed", str(self.speed), "--apply", str(lazy)]
        else:
            argv = [sys.executable, "-m", "hubs", hub, "--config", str(self.config_path),
                    "--loopback-port", str(self.port), "--speed", str(self.speed)]
        return self._spawn(hub, argv)

    def start(self, *, lazy: dict[str, int] | None = None, timeout: float = 20.0) -> None:
        """The controller, then (once the watcher is linked to it) every hub; returns once the controller
        reports every resource healthy (unless a hub is `lazy`: {hub: commands it applies}) and the watcher
        has recorded every resource from before the controller changed any command (so that the recorded
        streams are complete). A hub links to the watcher once gossip tells it where the watcher is; a device
        that acts on its own at boot (the badge reader) can act before that on a loaded machine, and its start
        is not in the record: the station is then started again from nothing, at most `START_ATTEMPTS` times."""
        for attempt in range(1, START_ATTEMPTS + 1):
            missed = self._start_once(lazy or {}, timeout)
            if not missed:
                return
            if attempt == START_ATTEMPTS:
                raise AssertionError(f"the watcher missed the start of {missed} {START_ATTEMPTS} times")
            print(f"\nthe watcher missed the start of {missed}: the station starts again (attempt {attempt + 1})")
            for process in self.processes.values():
                if process.alive():
                    self.kill(process.name)
            self.processes.clear()
            self.wait_for(lambda: self.watch.peers() == 0, timeout, "the watcher's links to the killed processes close")
            self.watch.forget()

    def _start_once(self, lazy: dict[str, int], timeout: float) -> str:
        """One start (see `start`); what the watcher missed the start of, if anything."""
        self.start_controller()
        self.wait_for(self.watch.peers, timeout, "the watcher links to the controller", poll=0.02)
        for hub in self.config.hubs:
            self.start_hub(hub, lazy=lazy.get(hub))
        self.wait_for(lambda: all(self.watch.states(r) for r in self.config.resources), timeout,
                      "the watcher receives every resource's state")
        if not lazy:
            self.wait_for(self.all_healthy, timeout, "the controller reports every resource healthy")
        for resource in self.config.resources:
            # The first state recorded must still show the device as it boots (the model's initial
            # measured values): then every change it made since is in the record.
            first = self.watch.states(resource)[0].message
            initial = {v.name: v.initial for v in self.model.resource_by_name[resource].measured}
            recorded = self.watch.codecs[resource].values(first)
            if recorded != initial:
                return f"{resource}: its first state (seq {first.seq}) is {recorded}, not the initial {initial}"
        return ""

    def all_healthy(self) -> bool:
        status = self.watch.status()
        return status is not None and bool(status.health) and all(h.healthy for h in status.health)

    def signal(self, name: str, sig: signal.Signals) -> float:
        """Send `sig` to the process (never to anything else); returns time.monotonic() just before it
        was sent: all the watcher records from the process's answer on is later (taken after the
        signal, this thread could be descheduled while the thawed hub published and the watcher
        recorded it: seen as 'no state after the thaw')."""
        process = self.processes[name]
        if not process.alive():
            raise RuntimeError(f"{name} is not running:\n{process.tail()}")
        sent = time.monotonic()
        os.kill(process.pid, sig)
        return sent

    def kill(self, name: str) -> float:
        """kill -9; returns when it is gone (time.monotonic() of the signal)."""
        sent = self.signal(name, signal.SIGKILL)
        process = self.processes[name]
        assert process.popen is not None
        process.stopped = True
        process.popen.wait(10)
        process.frozen = False
        return sent

    def freeze(self, name: str) -> float:
        sent = self.signal(name, signal.SIGSTOP)
        self.processes[name].frozen = True
        return sent

    def thaw(self, name: str) -> float:
        sent = self.signal(name, signal.SIGCONT)
        self.processes[name].frozen = False
        return sent

    def restart(self, name: str, **options: Any) -> Process:
        if self.processes[name].alive():
            self.kill(name)
        if name == "controller":
            return self.start_controller(**options)
        return self.start_hub(name, **options)

    def stop(self, name: str) -> int | None:
        process = self.processes.get(name)
        if process is None or process.popen is None:
            return None
        popen = process.popen
        process.stopped = True
        if popen.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                if process.frozen:
                    os.kill(popen.pid, signal.SIGCONT)
                popen.send_signal(signal.SIGTERM)
            try:
                popen.wait(STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                popen.kill()
                popen.wait(10)
        return popen.returncode

    def close(self) -> None:
        for name in list(self.processes):
            with contextlib.suppress(Exception):
                self.stop(name)
        self.watch.close()
        with contextlib.suppress(Exception):
            self.dump(self.dir / "watcher.jsonl")
        self.print_logs()

    def dump(self, path: Path) -> None:
        """Everything the watcher recorded, one JSON object a line, in the order received (for post-mortems)."""
        watch = self.watch
        rows = [("status", s) for s in watch.statuses()] + [("snapshot", s) for s in watch.snapshots()]
        for resource in watch.codecs:
            rows += [(f"state {resource}", s) for s in watch.states(resource)]
            rows += [(f"cmd {resource}", s) for s in watch.commands(resource)]
        rows.sort(key=lambda row: row[1].at)
        with path.open("wb") as handle:
            for what, seen in rows:
                handle.write(msgspec.json.encode({"at": seen.at, "what": what, "message": seen.message}) + b"\n")

    def print_logs(self) -> None:
        for process in self.processes.values():
            print(f"\n----- {process.name} (run {process.runs}, {process.log}) -----\n{process.tail()}")
        print(f"\n----- watcher (all it recorded: {self.dir / 'watcher.jsonl'}): {self.describe()}")

    def dead(self) -> list[str]:
        """Processes that exited although nobody stopped them."""
        return [p.name for p in self.processes.values()
                if p.popen is not None and not p.stopped and p.popen.poll() is not None]

    # waiting
    def wait_for(self, predicate: Callable[[], T | None], timeout: float, what: str, *, poll: float = 0.01,
                 allow_dead: bool = False) -> T:
        """Poll `predicate` until it returns something truthy (returned); fail after `timeout` s with
        what the station was doing, or at once when a process died."""
        deadline = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            dead = [] if allow_dead else self.dead()
            if dead:
                raise AssertionError(f"waiting for {what}: {', '.join(dead)} exited; {self.describe()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout} s; {self.describe()}")
            time.sleep(poll)

    def describe(self) -> str:
        status = self.watch.status()
        if status is None:
            return "no status from the controller"
        ops = ", ".join(f"{o.name}={o.state}" + (f" ({o.error})" if o.error else "") for o in status.operations)
        health = "; ".join(f"{h.resource}: {'ok' if h.healthy else h.reason}" for h in status.health)
        return (f"controller {status.controller} at {status.uptime:.1f} s: {ops}; health: {health}; "
                f"plans {status.plans}, replans {status.replans}, no plans {status.no_plans}; "
                f"events: {[event.text for event in status.events[-6:]]}")

    # the persisted state
    def persisted(self) -> dict[str, Any]:
        """The controller's SQLite: every stored variable by path (read-only, safe while it runs)."""
        db = sqlite3.connect(f"file:{self.db}?mode=ro", uri=True, timeout=5)
        try:
            return {path: json.loads(value) for path, value in db.execute("SELECT path, value FROM variables")}
        finally:
            db.close()
