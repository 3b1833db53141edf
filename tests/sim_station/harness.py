"""Sim-mode hubs without a controller: the test commands the devices itself and watches what they measure.

    async with SimCell(config_path, tmp_path, speed=3) as cell:   # sim world + every hub, --mode sim
        cell.command("ur", ref_pos_c="dock_lift_tool")             # re-sent at 10 Hz, like the controller
        await cell.wait("ur.pos_m", "dock_lift_tool")
        assert cell.trace("ur.pos_m") == ["home", "unknown", "dock_lift_tool"]

The test's bus listens where the controller would (`--loopback-port`); every hub runs as
`python -m hubs NAME --mode sim --params-file ...`, as `hubctl up --mode sim`
starts them, and the simulated world (`deploy.local.simworld`) couples the simulators through
the same bus. Every measured value the hubs publish is recorded in order (no
coalescing), so a test can compare a variable's trace with the model's effects.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_station
from common.model import Value
from common.plumbing.lifecycle import free_port
from common.plumbing.tasks import cancel_and_wait
from common.wire.holder_token import declare_holder
from common.wire.messages import Codec, MessageError
from deploy.local.simworld import TASKS_END_S, SimWorld
from hubs.protocols.ur import COMMAND_PORT
from hubs.sim.cell import RobotLink

ROOT = Path(__file__).resolve().parents[2]
COMMAND_PERIOD_S = 0.1
SIM_TEST = "sim-test"  # the controller id this harness commands the hubs as


class SimCell:
    def __init__(self, config_path: str | Path, run_dir: Path, *, speed: float = 1.0) -> None:
        self.config, self.model = load_station(config_path)
        self.config_path = str(config_path)
        self.run_dir = run_dir
        self.speed = speed
        self.port = free_port()
        self.keys = self.config.keys
        self.codecs = {r.name: Codec(r) for r in self.model.resources}
        self.commands: dict[str, dict[str, Value]] = {
            r.name: {v.name: v.initial for v in r.commands} for r in self.model.resources}
        self.values: dict[str, Value | None] = {}
        self.history: dict[str, list[Value | None]] = {}
        self.world: SimWorld | None = None
        self.hubs: dict[str, asyncio.subprocess.Process] = {}
        self._bus: ZenohBus | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._seq = 0
        self._changed = asyncio.Event()
        self.longest_command_gap = 0.0  # s between two rounds of commands, the longest so far

    async def __aenter__(self) -> SimCell:
        self._bus = ZenohBus(zenoh_config("peer", listen=[f"tcp/127.0.0.1:{self.port}"],
                                          lease_ms=self.config.network.lease_ms))
        await self._bus.open()
        declare_holder(self._bus, self.keys, SIM_TEST)  # the hubs apply the holder's commands only
        self._tasks = [asyncio.create_task(self._record()), asyncio.create_task(self._send_commands())]
        self.world = SimWorld(self.config, self.model, self.run_dir / "sim", speed=self.speed,
                              loopback_port=self.port, say=lambda _line: None)
        await self.world.start()
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        for hub in self.config.hubs:
            argv = [sys.executable, "-m", "hubs", hub, "--config", self.config_path, "--mode", "sim",
                    "--speed", str(self.speed), "--loopback-port", str(self.port), *self.world.hub_args(hub)]
            with (self.run_dir / f"{hub}.log").open("wb") as log:
                self.hubs[hub] = await asyncio.create_subprocess_exec(
                    *argv, stdout=log, stderr=asyncio.subprocess.STDOUT, cwd=ROOT, env=env, start_new_session=True)
        await self.wait_all_measured()
        return self

    async def wait_all_measured(self, timeout: float = 60.0) -> None:
        """Until every device of every hub answers (every measured variable known)."""
        paths = [v.path for r in self.model.resources for v in r.measured]
        deadline = time.monotonic() + timeout
        while any(self.values.get(p) is None for p in paths):
            if time.monotonic() > deadline:
                unknown = [p for p in paths if self.values.get(p) is None]
                raise AssertionError(f"devices do not answer within {timeout} s: {unknown} unknown; "
                                     f"hubs exited: {self.dead_hubs()}; logs in {self.run_dir}")
            await asyncio.sleep(0.1)

    async def __aexit__(self, *_exc: object) -> None:
        for process in self.hubs.values():
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGTERM)
        for process in self.hubs.values():
            try:
                await asyncio.wait_for(process.wait(), 5)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        await cancel_and_wait(self._tasks, TASKS_END_S)
        if self.world is not None:
            await self.world.stop()
        if self._bus is not None:
            await self._bus.close()

    # --- commanding and watching ------------------------------------------------------------
    def command(self, resource: str, **values: Value) -> None:
        """Set command variables of `resource`; the whole command is re-sent every 0.1 s."""
        self.commands[resource].update(values)
        self._publish(resource)

    def _publish(self, resource: str) -> None:
        assert self._bus is not None
        self._seq += 1
        codec = self.codecs[resource]
        message = codec.command(self.commands[resource], seq=self._seq, controller=SIM_TEST)
        self._bus.publish(self.keys.cmd(resource), codec.encode_command(message))

    async def _send_commands(self) -> None:
        last = time.monotonic()
        while True:
            for resource, values in self.commands.items():
                if values:
                    self._publish(resource)
            # Kept for failure messages: beyond the hubs' command timeout (1 s), a hub in its safe state
            # is right, the test process (the controller here) having been starved.
            now = time.monotonic()
            self.longest_command_gap = max(self.longest_command_gap, now - last)
            last = now
            await asyncio.sleep(COMMAND_PERIOD_S)

    async def _record(self) -> None:
        assert self._bus is not None
        async for sample in self._bus.subscribe(self.keys.all_state, coalesce=False):
            resource = self.keys.resource_of(sample.key)
            codec = self.codecs.get(resource or "")
            if codec is None:
                continue
            try:
                state = codec.decode_state(sample.payload)
            except MessageError:
                continue
            for path, value in codec.values(state, paths=True).items():
                if self.values.get(path, "never") != value:
                    self.values[path] = value
                    self.history.setdefault(path, []).append(value)
                    self._changed.set()

    def trace(self, path: str, since: int = 0) -> list[Value]:
        """The values `path` took (from the `since`-th change on), repeats and unknowns (None) left out."""
        out: list[Value] = []
        for value in self.history.get(path, [])[since:]:
            if value is not None and (not out or out[-1] != value):
                out.append(value)
        return out

    def mark(self, path: str) -> int:
        """Where `path`'s history stands now: pass it to `trace(path, since=...)`."""
        return max(0, len(self.history.get(path, [])) - 1)

    async def wait(self, path: str, value: Value, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while self.values.get(path) != value:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"{path} did not become {value!r} within {timeout} s; it is "
                                     f"{self.values.get(path)!r}, trace {self.trace(path)}; now: {self.snapshot()}; "
                                     f"longest gap between commands {self.longest_command_gap:.2f} s")
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), min(remaining, 0.5))

    async def robot_stands_at(self, resource: str, pose: str) -> bool:
        """Whether the simulated robot `resource` stands at `pose` now: every joint within the driver's
        tolerance of the pose's target, asked of the fake controller itself (its command port, as the
        world's flange coupling asks), not of the hub."""
        assert self.world is not None
        # A probe of the test's, not the world's 10 ms poll: on a loaded machine the fake may take a while.
        link = RobotLink(self.world.server_of[resource].address, COMMAND_PORT, timeout=10.0)
        try:
            q = await link.joints()
        finally:
            link.close()
        assert q is not None, f"the fake controller of {resource} does not answer on its command port"
        target = self.world.overrides[resource]["poses"][pose]["q"]
        tolerance = float(self.world.devices[resource].params.get("joint_tolerance", 0.01))
        return max(abs(a - b) for a, b in zip(q, target, strict=True)) <= tolerance

    def snapshot(self) -> dict[str, Any]:
        return {p: v for p, v in sorted(self.values.items()) if not p.startswith(("agv.", "human."))}

    def dead_hubs(self) -> list[str]:
        return [hub for hub, p in self.hubs.items() if p.returncode is not None]
