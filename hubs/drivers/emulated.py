"""Emulate mode: the resource's own effect transitions stand in for the device.

The emulator behind a `Driver` like any other: `write` sets the command variables,
`read` returns the measured ones, and effects fire after their delays in a background
task. Effects may depend on other resources (the tool changer sees where the robot is):
it declares `Inputs` naming those variables, and `Observes` them: the hub feeds their
values from the states the other hubs publish.

Such an effect waits, after a command, for news of those resources published after the
command came. The controller commanded on a state at least that new, but another hub's
news can reach this hub after the command does (another path, a busy machine); fired on
older news the effect takes a branch the controller never saw. Seen under load: the tool
changer, told to unlock at the dock while it still had the robot on its way there, kept
the tool on the plate, a dead end for the station. The other hubs publish at their rate
(50 Hz by default), so the wait is short; a silent one holds it at most `input_wait`,
and one never heard of (its hub not running) not at all.

The emulated device outlives its hub, as a real one does: given a file (`hubctl up` gives each a file in its
run directory), the driver keeps the device's values there (what it measures and the commands it holds) and a
restarted hub finds its device as the killed one left it. Without that, a robot whose hub was killed standing
at a filter woke up at `home` and moved back onto the filter at the controller's next command: the work done
twice that no real cell would do.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path

import msgspec

from common.model import Duration, Model, Value

from ..emulator import EffectEmulator
from .base import Driver, Inputs, Observes, SelftestReport

SAFE_STATES: dict[str, dict[str, Value]] = {
    "nutrunner": {"run_c": False},
    "mir": {"goto_c": "none"},
    "agv": {"goto_c": "none"},
    "operator": {"instr_c": "none"},
}


log = logging.getLogger("statehub.hub.emulated")

# The longest an effect that reads other resources waits for their news after a command.
INPUT_WAIT_S = 1.0


class EmulatedDriver(Driver, Inputs, Observes):
    def __init__(self, model: Model, resource: str, *, speed: float = 1.0, seed: int = 0,
                 failure_probability: float = 0.0, delay: Duration | float | None = None,
                 input_wait: float = INPUT_WAIT_S, keep_in: Path | None = None) -> None:
        """`keep_in`: the file the device's values are kept in across restarts of its hub (None: not kept)."""
        self.resource = resource
        self.model = model
        spec = model.resource_by_name[resource]
        self.emulator = EffectEmulator(
            model, [resource], speed=speed, seed=seed,
            failure={resource: failure_probability}, delays={resource: delay} if delay is not None else None,
        )
        self.values: dict[str, Value] = {v.path: v.initial for v in spec.variables}
        self.measured = tuple(v.path for v in spec.measured)
        self.commands = tuple(v.path for v in spec.commands)
        own = set(self.values)
        self._inputs = frozenset(p for p in self.emulator.paths if p not in own)
        for path in self._inputs:
            self.values[path] = model.var(path).initial
        self._reads_inputs = {t.name: t.guard.paths() & self._inputs for t in self.emulator.effects
                              if t.guard.paths() & self._inputs}
        self._published: dict[str, float] = {}  # input path -> when its latest value was published
        self._commanded_at: float | None = None  # when a command value last changed here
        self._input_wait = input_wait
        self._task: asyncio.Task[None] | None = None
        self._wake = asyncio.Event()
        self._prefix = f"{resource}."
        self._keep_in = keep_in
        self._kept: dict[str, Value] = {}
        if keep_in is not None:
            self._restore(keep_in)

    def _own(self) -> dict[str, Value]:
        return {p: self.values[p] for p in (*self.measured, *self.commands)}

    def _restore(self, path: Path) -> None:
        """The values the device had when its last hub stopped, if it ran before in this run."""
        try:
            saved = msgspec.json.decode(path.read_bytes())
        except FileNotFoundError:
            return
        except (OSError, msgspec.DecodeError) as exc:
            log.warning("%s: the emulated device's kept values in %s are unreadable (%s): it starts afresh",
                        self.resource, path, exc)
            return
        own = self._own()
        if not isinstance(saved, dict):
            log.warning("%s: %s holds no values: the emulated device starts afresh", self.resource, path)
            return
        bad = sorted(p for p, v in saved.items() if p not in own or v not in self.model.var(p).domain)
        if bad:
            log.warning("%s: %s names unknown variables or values (%s): the emulated device starts afresh",
                        self.resource, path, ", ".join(bad))
            return
        self.values.update(saved)
        self._kept = self._own()
        log.info("%s: the emulated device is as its last hub left it (%s)", self.resource,
                 ", ".join(f"{p}={v}" for p, v in sorted(saved.items())))

    def _keep(self) -> None:
        """Write the device's values if they changed: a file replaced whole, never half written."""
        if self._keep_in is None:
            return
        own = self._own()
        if own == self._kept:
            return
        partial = self._keep_in.with_name(self._keep_in.name + ".partial")
        partial.write_bytes(msgspec.json.encode(own))
        os.replace(partial, self._keep_in)
        self._kept = own

    @property
    def connected(self) -> bool:
        return self._task is not None and not self._task.done()

    async def connect(self) -> None:
        if self._task is None:
            self._task = asyncio.create_task(self._run(), name=f"emulate {self.resource}")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    async def _run(self) -> None:
        # Effects change values only when one falls due, or when a command or an input changes
        # what is enabled (`write`/`observe` set `_wake`): the task sleeps until then, never polls.
        loop = asyncio.get_running_loop()
        while True:
            self._wake.clear()
            hold, release_in = self._held()
            changes = self.emulator.step(self.values, time.monotonic(), hold)
            if changes:
                # What just fired may enable another effect: step again to schedule it, after
                # letting the rest of the hub run.
                self.values.update(changes)
                self._keep()
                await asyncio.sleep(0)
                continue
            due = self.emulator.next_due(hold)
            wait = min(max(0.0, due - time.monotonic()) if due is not None else math.inf, release_in)
            timer = None if wait == math.inf else loop.call_later(wait, self._wake.set)
            try:
                await self._wake.wait()
            finally:
                if timer is not None:
                    timer.cancel()

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(sorted(self._inputs))

    def _held(self) -> tuple[frozenset[str], float]:
        """The effects that wait for news of their inputs, and in how many seconds they stop waiting
        (inf: none waits)."""
        since = self._commanded_at
        if since is None or not self._reads_inputs:
            return frozenset(), math.inf
        left = since + self._input_wait - time.time()
        if left <= 0:
            return frozenset(), math.inf
        # An input never heard of has no publisher to wait for (its hub is not running: the
        # device tested alone, `hubctl test`): its initial value is all there will be.
        held = frozenset(name for name, paths in self._reads_inputs.items()
                         if any(self._published.get(p, math.inf) < since for p in paths))
        return held, (left if held else math.inf)

    def observe(self, values: Mapping[str, Value], published_at: float | None = None) -> None:
        """Values of other resources' variables that this device's effects depend on."""
        at = time.time() if published_at is None else published_at
        wake = False
        for path, value in values.items():
            if path not in self._inputs:
                continue
            before = self._published.get(path, -math.inf)
            if at < before:
                continue  # older than what is known: overtaken on the way
            self._published[path] = at
            since = self._commanded_at
            if self.values.get(path) != value or (since is not None and before < since <= at):
                self.values[path] = value
                wake = True  # a changed value, or the first news since the command
        if wake:
            self._wake.set()

    async def read(self) -> dict[str, Value]:
        return {p[len(self._prefix):]: self.values[p] for p in self.measured}

    async def write(self, commands: Mapping[str, Value]) -> None:
        for name, value in commands.items():
            path = self._prefix + name
            if self.values.get(path) != value:
                self.values[path] = value
                self._commanded_at = time.time()
        self._keep()
        self._wake.set()

    async def enter_safe_state(self) -> dict[str, Value]:
        safe = self.safe_values()
        await self.write(safe)
        return safe

    def safe_values(self) -> dict[str, Value]:
        """The command values of the safe state."""
        # As docs/resource-contract.md says for the real devices; the rest keep their value
        # (a robot holds its pose, a tool changer never drops its tool). A device type of the
        # station's own names its safe state in its model (`parameters["safe_state"]`, by
        # command name): statehub cannot guess that a conveyor stops but a gripper holds.
        spec = self.model.resource_by_name[self.resource]
        if spec.device_type in SAFE_STATES:
            return dict(SAFE_STATES[spec.device_type])
        own = spec.parameters.get("safe_state", {})
        return dict(own) if isinstance(own, Mapping) else {}

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        report.add("device answers", self.connected, "emulated")
        measured = await self.read()
        report.add("inputs read", len(measured) == len(self.measured), ", ".join(sorted(measured)))
        report.add("outputs read back", all(self.values[c] is not None for c in self.commands), "emulated")
        return report
