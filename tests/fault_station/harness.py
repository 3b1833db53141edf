"""A whole station as real OS processes over Zenoh on loopback, and a watcher that records it.

    with Station(tmp_path) as station:
        station.start()                         # controller, then every hub of hubs.toml
        station.wait_for(lambda: station.watch.finished(), 30, "the station finishes")
        station.kill("pi-tool"); station.start_hub("pi-tool")
        station.freeze("ur10"); station.thaw("ur10")

Each process is `python -m controller` or `python -m hubs HUB ...` (what `hubctl up` and the
systemd units run) with `--loopback-port`, in its own session, logging to a file in
the test's temporary directory. `Station` is synchronous: the watcher runs its `Bus`
on an event loop in a background thread and records, with the receive time:

* every `{station}/ctl/status` (StatusMessage) and `{station}/ctl/state` (StateSnapshot),
* every state of every resource (`{station}/res/*/state`, decoded with the resource's Codec),
* every command (`{station}/res/*/cmd`),

and counts what it could not decode (the garbage a test publishes itself). Nothing is
coalesced: a test counts edges in these streams.

`close()` (or leaving the `with`) always stops every process (SIGCONT first if frozen,
then SIGTERM, then SIGKILL) and prints the tail of each log, which pytest shows for a
failing test.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Coroutine, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from common.bus import Bus, Keys, Sample, zenoh_config
from common.config import StationConfig, load_station
from common.ctl import StateSnapshot, StatusMessage
from common.messages import Codec, MessageError, decode
from common.model import Model

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = Path(__file__).with_name("hubs.toml")
LAZY_HUB = Path(__file__).with_name("lazy_hub.py")
STOP_GRACE_S = 5.0
LOG_TAIL_CHARS = 4000

T = TypeVar("T")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def write_config(directory: Path, *, station: str | None = None, replace: Iterable[tuple[str, str]] = ()) -> Path:
    """A copy of the template hubs.toml with a station name unique to this run (and text replacements)."""
    text = TEMPLATE.read_text()
    name = station or f"fault_{os.getpid()}_{uuid.uuid4().hex[:6]}"
    text = text.replace('name = "fault_station"', f'name = "{name}"', 1)
    for old, new in replace:
        if old not in text:
            raise ValueError(f"{TEMPLATE}: no {old!r} to replace")
        text = text.replace(old, new)
    path = directory / "hubs.toml"
    path.write_text(text)
    return path


# --- what the watcher records -------------------------------------------------------------

@dataclass(frozen=True)
class Seen:
    at: float  # time.monotonic() when the watcher received it
    message: Any


@dataclass
class Record:
    statuses: list[Seen] = field(default_factory=list)
    snapshots: list[Seen] = field(default_factory=list)
    states: dict[str, list[Seen]] = field(default_factory=dict)
    commands: dict[str, list[Seen]] = field(default_factory=dict)
    undecodable: dict[str, int] = field(default_factory=dict)


class Watcher:
    """A Bus in a background thread: records the station's traffic, publishes for the test."""

    def __init__(self, config: StationConfig, model: Model, port: int) -> None:
        self.keys = Keys(config.station.name)
        self.codecs = {r.name: Codec(r) for r in model.resources}
        self.lock = threading.Lock()
        self.record = Record(states={r: [] for r in self.codecs}, commands={r: [] for r in self.codecs})
        self._endpoint = f"tcp/127.0.0.1:{port}"
        self._lease = config.network.lease_ms
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self.bus: Bus | None = None
        self._thread = threading.Thread(target=self._main, name="watcher", daemon=True)
        self._thread.start()
        if not self._ready.wait(20) or self._error is not None:
            raise RuntimeError(f"the watcher bus did not open: {self._error!r}")

    # the background thread
    def _main(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported by __init__ or close
            self._error = exc
            self._ready.set()
        finally:
            self._loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        config = zenoh_config("peer", listen=["tcp/127.0.0.1:0"], connect=[self._endpoint], lease_ms=self._lease)
        # Reconnect to a (re)started controller within 0.1 s (a process's default backs off to 2 s), so that
        # the watcher sees its first messages; listening lets the hubs link to it as soon as gossip tells them.
        config.insert_json5("connect/retry", json.dumps({"period_init_ms": 50, "period_max_ms": 100,
                                                         "period_increase_factor": 1}))
        async with Bus(config) as bus:
            self.bus = bus
            subscriptions = [
                (bus.subscribe(self.keys.ctl("status"), coalesce=False, maxlen=None), self._on_status),
                (bus.subscribe(self.keys.ctl("state"), coalesce=False, maxlen=None), self._on_snapshot),
                (bus.subscribe(self.keys.all_state, coalesce=False, maxlen=None), self._on_state),
                (bus.subscribe(self.keys.all_cmd, coalesce=False, maxlen=None), self._on_command),
            ]
            tasks = [asyncio.create_task(self._consume(sub, handler)) for sub, handler in subscriptions]
            self._ready.set()
            await self._stop.wait()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    @staticmethod
    async def _consume(subscription: Any, handler: Callable[[Sample, float], None]) -> None:
        async for sample in subscription:
            handler(sample, time.monotonic())

    def _bad(self, key: str) -> None:
        with self.lock:
            self.record.undecodable[key] = self.record.undecodable.get(key, 0) + 1

    def _on_status(self, sample: Sample, at: float) -> None:
        try:
            status = decode(sample.payload, StatusMessage)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.statuses.append(Seen(at, status))

    def _on_snapshot(self, sample: Sample, at: float) -> None:
        try:
            snapshot = decode(sample.payload, StateSnapshot)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.snapshots.append(Seen(at, snapshot))

    def _on_state(self, sample: Sample, at: float) -> None:
        resource = self.keys.resource_of(sample.key)
        codec = self.codecs.get(resource or "")
        try:
            if codec is None:
                raise MessageError("unknown resource")
            state = codec.decode_state(sample.payload)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.states[codec.resource].append(Seen(at, state))

    def _on_command(self, sample: Sample, at: float) -> None:
        resource = self.keys.resource_of(sample.key)
        codec = self.codecs.get(resource or "")
        try:
            if codec is None:
                raise MessageError("unknown resource")
            command = codec.decode_command(sample.payload)
        except MessageError:
            return self._bad(sample.key)
        with self.lock:
            self.record.commands[codec.resource].append(Seen(at, command))

    # the test's thread
    def call(self, coroutine: Coroutine[Any, Any, T], timeout: float = 10.0) -> T:
        return asyncio.run_coroutine_threadsafe(coroutine, self._loop).result(timeout)

    def publish(self, key: str, payload: bytes) -> None:
        async def put() -> None:
            assert self.bus is not None
            self.bus.publish(key, payload, block=True)

        self.call(put())

    def alive_hubs(self) -> set[str]:
        async def query() -> set[str]:
            assert self.bus is not None
            return await self.bus.alive_tokens(self.keys.all_alive, timeout=1.0)

        return {self.keys.hub_of(k) or k for k in self.call(query())}

    def peers(self) -> int:
        """How many zenoh peers this watcher is linked to."""
        async def count() -> int:
            assert self.bus is not None
            return len(list(self.bus.session.info.peers_zid()))

        return self.call(count())

    def close(self) -> None:
        if self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(15)

    # views (copies, taken under the lock)
    def statuses(self) -> list[Seen]:
        with self.lock:
            return list(self.record.statuses)

    def snapshots(self) -> list[Seen]:
        with self.lock:
            return list(self.record.snapshots)

    def states(self, resource: str) -> list[Seen]:
        with self.lock:
            return list(self.record.states[resource])

    def commands(self, resource: str) -> list[Seen]:
        with self.lock:
            return list(self.record.commands[resource])

    def undecodable(self) -> dict[str, int]:
        with self.lock:
            return dict(self.record.undecodable)

    def status(self) -> StatusMessage | None:
        with self.lock:
            return self.record.statuses[-1].message if self.record.statuses else None

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            return dict(self.record.snapshots[-1].message.values) if self.record.snapshots else {}

    def state(self, resource: str) -> Any:
        with self.lock:
            seen = self.record.states[resource]
            return seen[-1].message if seen else None

    def finished(self) -> bool:
        status = self.status()
        return status is not None and status.finished

    def health(self, resource: str) -> Any:
        status = self.status()
        if status is None:
            return None
        return next((h for h in status.health if h.resource == resource), None)


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
    """The controller and the hubs of a hubs.toml as processes, plus a `Watcher`."""

    def __init__(self, directory: Path, *, config: Path | None = None, speed: float = 1.0,
                 replace: Iterable[tuple[str, str]] = ()) -> None:
        self.dir = directory
        self.config_path = config or write_config(directory, replace=replace)
        self.config, self.model = load_station(self.config_path)
        self.keys = Keys(self.config.station.name)
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
        streams are complete)."""
        self.start_controller()
        self.wait_for(self.watch.peers, timeout, "the watcher links to the controller", poll=0.02)
        lazy = lazy or {}
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
            if self.watch.codecs[resource].values(first) != initial:
                raise AssertionError(f"the watcher missed the start of {resource}: its first state (seq {first.seq}) "
                                     f"is {self.watch.codecs[resource].values(first)}, not the initial {initial}")

    def all_healthy(self) -> bool:
        status = self.watch.status()
        return status is not None and bool(status.health) and all(h.healthy for h in status.health)

    def signal(self, name: str, sig: signal.Signals) -> float:
        """Send `sig` to the process (never to anything else); returns time.monotonic() when sent."""
        process = self.processes[name]
        if not process.alive():
            raise RuntimeError(f"{name} is not running:\n{process.tail()}")
        os.kill(process.pid, sig)
        return time.monotonic()

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
    def wait_for(self, predicate: Callable[[], T], timeout: float, what: str, *, poll: float = 0.01,
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
                f"events: {status.events[-6:]}")

    # the persisted state
    def persisted(self) -> dict[str, Any]:
        """The controller's SQLite: every stored variable by path (read-only, safe while it runs)."""
        db = sqlite3.connect(f"file:{self.db}?mode=ro", uri=True, timeout=5)
        try:
            return {path: json.loads(value) for path, value in db.execute("SELECT path, value FROM variables")}
        finally:
            db.close()


# --- reading the recorded streams ------------------------------------------------------------

def rising_edges(states: list[Seen], variable: str) -> list[Seen]:
    """The states in which `variable` became true (from false or unknown), per hub run: a hub restarted
    (its seq starts again) begins from false."""
    edges, previous, last_seq = [], False, None
    for seen in states:
        message = seen.message
        if last_seq is not None and message.seq < last_seq:
            previous = False
        last_seq = message.seq
        value = bool(getattr(message, variable))
        if value and not previous:
            edges.append(seen)
        previous = value
    return edges


def value_at(states: list[Seen], variable: str, at: float) -> Any:
    """The value of `variable` in the newest state received before `at` (monotonic)."""
    value = None
    for seen in states:
        if seen.at > at:
            break
        value = getattr(seen.message, variable)
    return value


def command_values(codec: Codec, command: msgspec.Struct) -> dict[str, Any]:
    return codec.values(command)
