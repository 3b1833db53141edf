"""UR10 robot via RTDE (ur-rtde) and the dashboard server, in a worker process.

ur-rtde runs only in the worker (``hubs.drivers.ur_rtde_worker``, spawned with
``multiprocessing``): its calls hold the GIL while blocked and it may abort at exit.
The driver talks to the worker over a pipe and restarts it (shared ReconnectLogic,
backoff) when it dies, hangs or loses the robot.

Ports (fixed by the robot): RTDE 30004 (ur-rtde ``RTDEReceiveInterface``: timestamp,
actual_q, actual_qd, target_q, actual_TCP_pose, robot_mode, safety_mode,
safety_status_bits, robot_status_bits, runtime_state), dashboard 29999 (text lines:
``stop``, ``close safety popup``, ``unlock protective stop``, ``is in remote control``,
``robotmode``, ``safetystatus``, ``PolyscopeVersion``), and for motion either
ur-rtde's ``RTDEControlInterface`` (``motion_backend = "real"``: uploads its URScript
to port 30003 and drives it through RTDE registers; ``moveJ``/``moveL`` with
``asynchronous=True``, ``stopJ``) or, in simulation, the fake controller's command
port (``motion_backend = "sim"``, default 30099).

Poses: a table of named targets, each joint angles (rad) or a TCP pose
(x, y, z in m, rotation vector in rad)::

    poses = { home = { q = [0, -1.57, 1.57, -1.57, -1.57, 0] },
              at_bolt1 = { tcp = [0.5, -0.2, 0.3, 0, 3.14, 0] } }

``ref_pos_c = P`` moves to P (joint targets with moveJ, TCP targets with moveL); the
same command repeated does nothing while the robot moves or stands at P, and moves
again when the robot stands still elsewhere for ``reissue_after`` s (after a stop or a
released protective stop).  ``pos_m`` is the pose the robot stands at: every joint
within ``joint_tolerance`` (rad) of a joint target, or the TCP within ``tcp_tolerance``
(m) and ``rot_tolerance`` (rad) of a TCP target; ``unknown`` otherwise.
``prot_stop_m`` is ur-rtde's ``isProtectiveStopped()``.

Device lost (``read`` raises ``DeviceUnavailable``, ur-rtde's stale getters never
reach the controller): the worker exits or fails to start, sends no state for
``stale_after`` s, or the RTDE ``timestamp`` stops advancing for ``stale_after`` s
(default 0.25; the robot stopped talking).  The worker is then killed and started
again with backoff.

Safe state: ``enter_safe_state()`` stops the robot at once (motion backend stop, then
dashboard ``stop``) and holds it until the next command; ``ref_pos_c`` keeps its value
(it returns ``{}``).  A robot is therefore never set in motion by a hub (re)start; the
next command moves on.

``unlock_protective_stop()`` is offered for the operator console (dashboard
``close safety popup`` + ``unlock protective stop``).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import multiprocessing
import time
from collections.abc import Mapping
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any, Literal

import msgspec

from common.model import Value
from hubs.drivers import ur_rtde_worker as worker
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.params import DriverParams, Port, Positive, invalid
from hubs.drivers.reconnect import Backoff, LinkedDriver, ReconnectLogic
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.ur import COMMAND_PORT, RUNNING, Pose, rotation_between

log = logging.getLogger(__name__)


class UrRtde(LinkedDriver[ReconnectLogic]):
    def __init__(
        self,
        resource: str = "ur",
        *,
        host: str,
        poses: Mapping[str, Pose],
        motion_backend: str = "real",
        command_port: int = COMMAND_PORT,
        joint_tolerance: float = 0.01,
        tcp_tolerance: float = 0.005,
        rot_tolerance: float = 0.02,
        stale_after: float = 0.25,
        start_timeout: float = 10.0,
        reissue_after: float = 1.0,
        request_timeout: float = 5.0,
        joint_speed: float = 1.05,
        tcp_speed: float = 0.25,
        backoff: Backoff | None = None,
    ) -> None:
        if not poses:
            raise ValueError("at least one pose needed")
        if "unknown" in poses:
            raise ValueError("'unknown' is reserved: the robot is between named poses")
        self.resource = resource
        self.host = host
        self.poses = dict(poses)
        self.joint_tolerance = joint_tolerance
        self.tcp_tolerance = tcp_tolerance
        self.rot_tolerance = rot_tolerance
        self.stale_after = stale_after
        self.start_timeout = start_timeout
        self.reissue_after = reissue_after
        self.request_timeout = request_timeout
        self.config = worker.WorkerConfig(
            host, backend=motion_backend, command_port=command_port, joint_speed=joint_speed, tcp_speed=tcp_speed
        )
        self.info: dict[str, Any] = {}
        self._proc: BaseProcess | None = None
        self._conn: Connection | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready: asyncio.Future[dict[str, Any]] | None = None
        self._pending: dict[int, asyncio.Future[tuple[bool, str]]] = {}
        self._ids = itertools.count(1)
        self._state: dict[str, Any] | None = None
        self._state_time = 0.0
        self._ts_change_time = 0.0
        self._watchdog: asyncio.Task[None] | None = None
        self._desired: str | None = None
        self._held = False
        self._issued: str | None = None
        self._issued_at = 0.0
        self._drive_lock = asyncio.Lock()
        self._link = ReconnectLogic(
            f"{resource}@{host}", self._spawn, self._kill, backoff=backoff, connect_timeout=start_timeout + 2
        )

    # -- Driver API -------------------------------------------------------------------

    @property
    def worker_pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    async def read(self) -> Mapping[str, Value]:
        state = self._fresh_state()
        return {"pos_m": self.pose_name(state), "prot_stop_m": bool(state["protective_stop"])}

    async def write(self, commands: Mapping[str, Value]) -> None:
        if "ref_pos_c" not in commands:
            return
        target = str(commands["ref_pos_c"])
        if target not in self.poses:
            raise ValueError(f"{self.resource}: unknown pose {target!r}; poses are {', '.join(self.poses)}")
        self._desired, self._held = target, False
        await self._drive(self._fresh_state())

    async def enter_safe_state(self) -> Mapping[str, Value]:
        self._held = True  # stands still until the next command
        self._issued = None
        if self.connected:
            self._send_nowait("stop")
        return {}

    async def unlock_protective_stop(self) -> str:
        """Dashboard: close the safety popup and unlock the protective stop (the operator's decision)."""
        self._fresh_state()
        ok, detail = await self._request("unlock")
        if not ok:
            raise DeviceUnavailable(f"{self.resource}: unlock refused: {detail}")
        return detail

    async def dashboard(self, text: str) -> str:
        """One dashboard command (e.g. ``robotmode``); the reply line."""
        self._fresh_state()
        ok, detail = await self._request("dashboard", text)
        if not ok:
            raise DeviceUnavailable(f"{self.resource}: dashboard {text!r}: {detail}")
        return detail

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self._link.wait_attempt():
            report.add("device answers", False, f"no UR controller at {self.host}: {self._link.last_error}")
            report.add("inputs read", False, "not checked: device absent")
            report.add("outputs read back", False, "not checked: device absent")
            return report
        try:
            mode = await self.dashboard("robotmode")
            report.add("device answers", True, f"{self.info.get('polyscope', '?')} at {self.host}, {mode}")
        except DeviceUnavailable as exc:
            report.add("device answers", False, str(exc))
            return report
        try:
            values = await self.read()
            state = self._fresh_state()
            report.add(
                "inputs read",
                True,
                f"pos_m={values['pos_m']} prot_stop_m={values['prot_stop_m']} robot_mode={state['robot_mode']} "
                f"safety_mode={state['safety_mode']}",
            )
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
            return report
        try:
            report.add("outputs read back", *await self._output_check())
        except DeviceUnavailable as exc:
            report.add("outputs read back", False, str(exc))
        return report

    # -- poses and motion -------------------------------------------------------------

    def pose_name(self, state: Mapping[str, Any]) -> str:
        best, best_err = "unknown", math.inf
        for name, pose in self.poses.items():
            if pose.kind == "joint":
                err = max(abs(a - b) for a, b in zip(state["q"], pose.values, strict=True))
                ok = err <= self.joint_tolerance
                score = err / self.joint_tolerance
            else:
                tcp = state["tcp"]
                dist = math.dist(tcp[:3], pose.values[:3])
                angle = rotation_between(tcp[3:], pose.values[3:])
                ok = dist <= self.tcp_tolerance and angle <= self.rot_tolerance
                score = max(dist / self.tcp_tolerance, angle / self.rot_tolerance)
            if ok and score < best_err:
                best, best_err = name, score
        return best

    @staticmethod
    def _moving(state: Mapping[str, Any]) -> bool:
        return max(abs(v) for v in state["qd"]) > 1e-3

    async def _drive(self, state: Mapping[str, Any]) -> None:
        async with self._drive_lock:
            await self._drive_locked(state)

    async def _drive_locked(self, state: Mapping[str, Any]) -> None:
        target = self._desired
        if target is None or self._held:
            return
        if self.pose_name(state) == target:
            self._issued = target
            return
        now = time.monotonic()
        if self._issued == target and (
            self._moving(state) or state["protective_stop"] or now - self._issued_at < self.reissue_after
        ):
            return
        if state["protective_stop"]:
            return  # moves are refused until the protective stop is unlocked
        pose = self.poses[target]
        ok, detail = await self._request("move", pose.kind, list(pose.values))
        self._issued_at = time.monotonic()
        if not ok:
            self._issued = None
            raise DeviceUnavailable(f"{self.resource}: move to {target} refused: {detail}")
        self._issued = target

    async def _output_check(self) -> tuple[bool, str]:
        remote = await self.dashboard("is in remote control")
        if remote.strip().lower() != "true":
            return False, f"robot in local control (dashboard: {remote!r}): motion commands are refused"
        # The hub runs its self-test while commands arrive: under the lock moves are issued with, on a
        # state taken inside it, so that a zero-length move never cancels a commanded one (a robot sent
        # back to where it stood when the check began).
        async with self._drive_lock:
            state = self._fresh_state()
            wanted = None if self._held else self._desired
            if wanted is not None and self.pose_name(state) != wanted:
                return True, f"in remote control; zero-length move not tried (a move to {wanted} is commanded)"
            if state["protective_stop"] or state["robot_mode"] != RUNNING or self._moving(state):
                return True, (
                    f"in remote control; zero-length move not tried (robot_mode {state['robot_mode']}, "
                    f"protective stop {state['protective_stop']}, moving {self._moving(state)})"
                )
            q = list(state["q"])
            ok, detail = await self._request("move", "joint", q)
            if not ok:
                return False, f"zero-length move refused: {detail}"
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                back = self._fresh_state()["target_q"]
                if max(abs(a - b) for a, b in zip(back, q, strict=True)) <= self.joint_tolerance:
                    return True, "in remote control; zero-length move accepted, target_q read back"
                await asyncio.sleep(0.02)
            return False, "zero-length move accepted but target_q does not read back"

    # -- worker -----------------------------------------------------------------------

    def _fresh_state(self) -> dict[str, Any]:
        # Take what the worker has sent first: after the hub's own process was starved of CPU, its states
        # wait in the pipe behind this call, and judging by the last one read would blame the worker.
        self._on_readable()
        if not self.connected or self._state is None:
            raise DeviceUnavailable(f"{self.resource}: UR not connected ({self._link.last_error})")
        reason = self._staleness(time.monotonic())
        if reason:
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}")
        return self._state

    def _staleness(self, now: float) -> str | None:
        proc = self._proc
        if proc is None or not proc.is_alive():
            code = proc.exitcode if proc is not None else None
            return f"worker process exited (code {code})"
        if now - self._state_time > self.stale_after:
            return f"worker silent for {now - self._state_time:.2f} s"
        if now - self._ts_change_time > self.stale_after:
            return f"RTDE timestamp not advancing for {now - self._ts_change_time:.2f} s (robot silent)"
        if self._state is not None and not self._state.get("rtde_connected", True):
            return "RTDE connection closed"
        return None

    def _on_readable(self) -> None:
        conn = self._conn
        if conn is None:
            return
        try:
            while conn.poll():
                self._on_message(conn.recv())
        except (EOFError, OSError) as exc:
            self._detach_reader()
            self._fail_pending(f"worker pipe closed ({exc.__class__.__name__})")
            if self._ready is not None and not self._ready.done():
                self._ready.set_exception(ConnectionError("worker exited during start-up"))
            self._link.connection_lost("worker process exited")

    def _on_message(self, msg: tuple[Any, ...]) -> None:
        kind = msg[0]
        now = time.monotonic()
        if kind == "state":
            state = msg[1]
            if self._state is None or state["timestamp"] != self._state["timestamp"]:
                self._ts_change_time = now
            self._state, self._state_time = state, now
        elif kind == "reply":
            future = self._pending.pop(msg[1], None)
            if future is not None and not future.done():
                future.set_result((bool(msg[2]), str(msg[3])))
        elif kind == "ready":
            if self._ready is not None and not self._ready.done():
                self._ready.set_result(msg[1])
        elif kind == "error" and self._ready is not None and not self._ready.done():
            self._ready.set_exception(ConnectionError(msg[1]))

    def _send_nowait(self, kind: str, *args: Any) -> int:
        conn = self._conn
        if conn is None:
            raise DeviceUnavailable(f"{self.resource}: worker not running")
        req_id = next(self._ids)
        try:
            conn.send((kind, req_id, *args))
        except (OSError, ValueError) as exc:
            self._link.connection_lost(f"worker pipe: {exc}")
            raise DeviceUnavailable(f"{self.resource}: worker pipe: {exc}") from exc
        return req_id

    async def _request(self, kind: str, *args: Any) -> tuple[bool, str]:
        assert self._loop is not None
        future: asyncio.Future[tuple[bool, str]] = self._loop.create_future()
        req_id = self._send_nowait(kind, *args)
        self._pending[req_id] = future
        try:
            async with asyncio.timeout(self.request_timeout):
                return await future
        except TimeoutError:
            self._pending.pop(req_id, None)
            self._link.connection_lost(f"worker did not answer {kind!r} within {self.request_timeout} s")
            raise DeviceUnavailable(f"{self.resource}: worker did not answer {kind!r}") from None

    def _fail_pending(self, reason: str) -> None:
        pending, self._pending = self._pending, {}
        for future in pending.values():
            if not future.done():
                future.set_exception(DeviceUnavailable(f"{self.resource}: {reason}"))

    async def _watch(self) -> None:
        while True:
            await asyncio.sleep(self.stale_after / 2)
            self._on_readable()  # as in _fresh_state: a late wake-up first takes what waits in the pipe
            if self.connected:
                reason = self._staleness(time.monotonic())
                if reason:
                    self._link.connection_lost(reason)
                    continue
                if self._state is not None and not self._drive_lock.locked():
                    # re-drive the reference (after a reconnect or an unlock); never wait for a write
                    with contextlib.suppress(DeviceUnavailable):
                        await self._drive(self._state)

    async def _spawn(self) -> None:
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._state = None
        ctx = multiprocessing.get_context("spawn")
        parent, child = ctx.Pipe(duplex=True)
        proc = ctx.Process(target=worker.run, args=(child, self.config), name=f"ur-worker-{self.resource}", daemon=True)
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent
        self._ready = loop.create_future()
        loop.add_reader(parent.fileno(), self._on_readable)
        try:
            async with asyncio.timeout(self.start_timeout):
                self.info = await self._ready
        except TimeoutError:
            raise ConnectionError(f"worker did not connect within {self.start_timeout} s") from None
        deadline = time.monotonic() + max(1.0, 4 * self.stale_after)
        while self._state is None and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        if self._state is None:
            raise ConnectionError("worker ready but no robot state arrived")
        self._ts_change_time = time.monotonic()
        self._issued = None  # a new worker: motion is commanded afresh
        self._watchdog = loop.create_task(self._watch(), name=f"watch:{self.resource}")

    def _detach_reader(self) -> None:
        conn, loop = self._conn, self._loop
        if conn is not None and loop is not None and not conn.closed:
            with contextlib.suppress(ValueError, OSError):
                loop.remove_reader(conn.fileno())

    async def _kill(self) -> None:
        task, self._watchdog = self._watchdog, None
        if task is not None and task is not asyncio.current_task():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._detach_reader()
        conn, self._conn = self._conn, None
        proc, self._proc = self._proc, None
        if conn is not None:
            with contextlib.suppress(OSError, ValueError):
                conn.send(("quit",))
        if proc is not None:
            await asyncio.to_thread(proc.join, 0.5)
            if proc.is_alive():
                proc.kill()
                await asyncio.to_thread(proc.join, 2.0)
        if conn is not None:
            conn.close()
        self._fail_pending("worker stopped")
        self._state = None


class PoseSpec(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    q: list[float] | None = None  # joint angles, rad
    tcp: list[float] | None = None  # x, y, z (m), rotation vector (rad)


class UrParams(DriverParams, frozen=True, kw_only=True):
    host: str
    poses: dict[str, PoseSpec]
    motion_backend: Literal["real", "sim"] = "real"
    command_port: Port = COMMAND_PORT  # the fake controller's side channel (motion_backend "sim")
    joint_tolerance: Positive = 0.01
    tcp_tolerance: Positive = 0.005
    rot_tolerance: Positive = 0.02
    stale_after: Positive = 0.25
    start_timeout: Positive = 10.0
    reissue_after: Positive = 1.0
    joint_speed: Positive = 1.05
    tcp_speed: Positive = 0.25

    def __post_init__(self) -> None:
        if not self.poses:
            raise invalid("poses", "at least one pose needed")
        for name in self.poses:
            try:
                self.pose(name)
            except ValueError as exc:
                raise invalid(f"poses.{name}", str(exc)) from None

    def pose(self, name: str) -> Pose:
        spec = self.poses[name]
        return Pose.parse(name, {k: v for k, v in (("q", spec.q), ("tcp", spec.tcp)) if v is not None})


def build(resource: str, params: UrParams) -> UrRtde:
    return UrRtde(resource, poses={name: params.pose(name) for name in params.poses},
                  **params.options(leave_out=("poses",)))


PLUGIN = DriverPlugin(UrParams, build)
