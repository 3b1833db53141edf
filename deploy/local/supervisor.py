"""`hubctl up`'s processes, kept running as their systemd units keep them running on the cell.

A process that exits, whatever its status, is started again after the delay of the units' restart
policy (deploy/remote/restart_policy.py: RestartSec, growing with each restart); a process started
more often than the start limit allows within its interval is not started again, and the run is
over: `gave_up` says which process, how it last exited and the end of its log. Hubs are stateless
and the controller resumes from its SQLite file (DESIGN.md §7), so a restart is harmless; a
restarted controller is started without its first start's `--fresh`.

Each process writes to its own log file; a restart appends to it after a line saying so.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from deploy.remote.restart_policy import RestartPolicy, StartLimit

STOP_GRACE_S = 5.0
LOG_TAIL_LINES = 15

Say = Callable[[str], object]


def describe_exit(returncode: int) -> str:
    """'status 3' or 'killed by SIGKILL' (asyncio reports a death by signal N as -N)."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"status {returncode}"


def run_line(elapsed: float, text: str) -> str:
    """A progress line timed from the run's start: the controller's uptime, which times the other lines, begins
    again when the controller is restarted."""
    return f"     run {elapsed:6.1f}s  {text}"


def log_tail(path: Path, lines: int = LOG_TAIL_LINES) -> str:
    if not path.exists():
        return "(no log)"
    with path.open("rb") as handle:
        handle.seek(0, 2)
        handle.seek(max(0, handle.tell() - 16_384))
        text = handle.read().decode(errors="replace")
    return "\n".join(text.splitlines()[-lines:])


@dataclass
class Child:
    """One process of the station: `argv` at every start, `first_start_args` only at the first one."""

    name: str
    argv: list[str]
    log: Path
    first_start_args: list[str] = field(default_factory=list)
    process: asyncio.subprocess.Process | None = None
    starts: int = 0
    last_exit: int | None = None


class StartWindow:
    """systemd's start rate limit: a window begins with a start; within `interval_s` of that beginning at most
    `burst` starts are allowed, and the window begins again at the first start after it."""

    def __init__(self, limit: StartLimit | None) -> None:
        self.limit = limit
        self.began: float | None = None
        self.count = 0

    def allow(self, now: float) -> bool:
        limit = self.limit
        if limit is None:
            return True
        if self.began is None or now - self.began > limit.interval_s:
            self.began, self.count = now, 1
            return True
        if self.count < limit.burst:
            self.count += 1
            return True
        return False


@dataclass(frozen=True)
class GaveUp:
    """A process hit its start limit: the run cannot go on without it."""

    name: str
    last_exit: int
    starts: int
    limit: StartLimit
    log: Path

    def message(self) -> str:
        tail = "\n".join(f"    | {line}" for line in log_tail(self.log).splitlines())
        return (f"{self.name} keeps dying: it hit its start limit ({self.starts} starts within "
                f"{self.limit.interval_s:g} s; StartLimitBurst={self.limit.burst}, "
                f"StartLimitIntervalSec={self.limit.interval_s:g}s) and is not started again; it last exited with "
                f"{describe_exit(self.last_exit)}. The end of its log, {self.log}:\n{tail}")


class Supervisor:
    """Starts the children, restarts each that exits as `policy` says, and stops them all on `stop()`."""

    def __init__(self, children: list[Child], policy: RestartPolicy, say: Say,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.children = {child.name: child for child in children}
        self.policy = policy
        self.say = say
        self.clock = clock
        self.began = clock()
        self.restarts = dict.fromkeys(self.children, 0)
        self.gave_up: GaveUp | None = None
        self.failed = asyncio.Event()  # set with gave_up
        self._windows = {name: StartWindow(policy.start_limit) for name in self.children}
        self._tasks: list[asyncio.Task[None]] = []
        self._stopping = False

    def _line(self, text: str) -> None:
        self.say(run_line(self.clock() - self.began, text))

    async def start(self) -> None:
        """Every child, in order; then each is watched."""
        for child in self.children.values():
            self._windows[child.name].allow(self.clock())
            await self._spawn(child)
        self._tasks = [asyncio.create_task(self._supervise(child), name=f"supervise {child.name}")
                       for child in self.children.values()]

    async def _spawn(self, child: Child) -> None:
        child.log.parent.mkdir(parents=True, exist_ok=True)
        child.starts += 1
        first = child.starts == 1
        with child.log.open("wb" if first else "ab") as handle:
            if not first:
                handle.write(f"\n--- hubctl up: restart {child.starts - 1} at {time.strftime('%H:%M:%S')}, "
                             f"after it exited with {describe_exit(child.last_exit or 0)} ---\n".encode())
                handle.flush()
            argv = child.argv + (child.first_start_args if first else [])
            child.process = await asyncio.create_subprocess_exec(
                *argv, stdout=handle, stderr=asyncio.subprocess.STDOUT, start_new_session=True)

    async def _supervise(self, child: Child) -> None:
        while True:
            assert child.process is not None
            child.last_exit = await child.process.wait()
            if self._stopping:
                return
            restart = self.restarts[child.name] + 1
            delay = self.policy.delay(restart)
            self._line(f"EXITED  {child.name}: {describe_exit(child.last_exit)}; restart {restart} in {delay:.1f} s")
            await asyncio.sleep(delay)
            if self._stopping:
                return
            if not self._windows[child.name].allow(self.clock()):
                assert self.policy.start_limit is not None
                self.gave_up = GaveUp(child.name, child.last_exit, self._windows[child.name].count,
                                     self.policy.start_limit, child.log)
                self.failed.set()
                return
            self.restarts[child.name] = restart
            await self._spawn(child)
            self._line(f"restarted  {child.name} (pid {child.process.pid})")

    def pid(self, name: str) -> int | None:
        """The pid of the child while it runs; None while it waits for its restart."""
        process = self.children[name].process
        return process.pid if process is not None and process.returncode is None else None

    def kill(self, name: str, sig: signal.Signals = signal.SIGKILL) -> int | None:
        """Send `sig` to the child's process (only that process, not its session); its pid, None if not running."""
        process = self.children[name].process
        if process is None or process.returncode is not None:
            return None
        try:
            process.send_signal(sig)
        except ProcessLookupError:
            return None
        return process.pid

    def restart_counts(self) -> str:
        """'pi-tool 1, controller 2', or 'none'."""
        counted = [f"{name} {n}" for name, n in self.restarts.items() if n]
        return ", ".join(counted) if counted else "none"

    async def stop(self) -> None:
        """No more restarts; SIGTERM to every running child, SIGKILL to any still running after the grace."""
        self._stopping = True
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        running = [c.process for c in self.children.values() if c.process is not None and c.process.returncode is None]
        for process in running:
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        for process in running:
            try:
                async with asyncio.timeout(max(0.1, deadline - time.monotonic())):
                    await process.wait()
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
