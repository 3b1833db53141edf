"""MiR100 mobile platform via its REST API v2.0.0 (httpx, async).

Requests (base ``http://{host}:{port}/api/v2.0.0``; headers ``Authorization: Basic
base64(username:sha256hex(password))`` as the robot expects, ``Accept-Language: en_US``):

==========================  ===========================================================
request                     use
==========================  ===========================================================
``GET /status``             polled every ``poll_interval`` (0.2 s): ``state_id``,
                            ``state_text``, ``position`` {x, y}, ``mission_text``
``GET /mission_queue``      on (re)connect: adopt a queued/running mission of ours
``GET /missions``           self-test: the configured mission GUIDs exist on the robot
``POST /mission_queue``     ``{"mission_id": GUID}`` of the target (``missions`` param)
``PUT /status``             ``{"state_id": 3}`` Ready (go / continue),
                            ``{"state_id": 4}`` Pause (stop where it is)
``DELETE /mission_queue``   abort the running and queued missions
==========================  ===========================================================

Mapping:

* ``pos_m`` = ``at_kitting`` / ``at_station`` when the robot is not executing a mission
  and stands within ``tolerance`` m of that target's ``positions`` entry; otherwise
  ``moving`` (driving, paused on the way, or anywhere else: the domain has no "unknown").
* ``goto_c`` = kitting/station: on a new target, abort the queue, post the target's
  mission and set Ready; repeated writes of the same target do nothing while the
  mission runs, set Ready again if the robot is paused, and post again if the robot
  is idle away from the target (its queue was lost, e.g. after a reboot).
  ``goto_c = none``: abort the queue and Pause (the robot stops).

Device lost: a failed or timed-out request: ``read`` raises ``DeviceUnavailable``; the
shared ReconnectLogic reconnects with backoff.  A status older than ``stale_after`` is
asked for again by ``read`` and ``write`` before they use it (the poll loop may simply
not have run), so only a robot that does not answer is lost.  ``GET /status`` requests
go one at a time, so a stored status never goes back in time.  A 401 is reported as a
connect failure ("authentication rejected").

Safe state: ``goto_c = none`` (the queue is aborted and the robot pauses where it is).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import ssl
import time
from collections.abc import Mapping
from typing import Any

import httpx

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.params import DriverParams, Port, Positive, invalid
from hubs.drivers.reconnect import Backoff, LinkedDriver, ReconnectLogic, describe
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.mir_rest import API, EXECUTING, PAUSE, READY, auth_header

log = logging.getLogger(__name__)

TARGETS = ("kitting", "station")


class MirRest(LinkedDriver[ReconnectLogic]):
    def __init__(
        self,
        resource: str = "mir",
        *,
        host: str,
        port: int = 80,
        username: str = "admin",
        password: str = "admin",
        missions: Mapping[str, str],
        positions: Mapping[str, tuple[float, float]],
        tolerance: float = 0.3,
        poll_interval: float = 0.2,
        timeout: float = 1.0,
        backoff: Backoff | None = None,
    ) -> None:
        missing = [t for t in TARGETS if t not in missions or t not in positions]
        if missing:
            raise ValueError(f"missions and positions needed for {', '.join(missing)}")
        self.resource = resource
        self.base_url = f"http://{host}:{port}{API}"
        self.missions = dict(missions)
        self.positions = {k: (float(v[0]), float(v[1])) for k, v in positions.items()}
        self.tolerance = tolerance
        self.poll_interval = poll_interval
        self.timeout = timeout
        self.stale_after = max(3 * poll_interval, poll_interval + timeout) + 0.2
        self._headers = {"Authorization": auth_header(username, password), "Accept-Language": "en_US"}
        self._client: httpx.AsyncClient | None = None
        # Made once: building it loads the CA bundle (~40 ms of CPU, far more on a loaded machine), which
        # every reconnect's new client would otherwise do on the event loop.
        self._ssl = ssl.create_default_context()
        self._poller: asyncio.Task[None] | None = None
        self._status: dict[str, Any] | None = None
        self._status_time = 0.0
        self._desired: str | None = None  # last commanded goto_c
        self._active: str | None = None  # target whose mission we have queued
        self._active_entry: int | None = None  # its mission queue id
        self._last_queue_check = 0.0
        self._lock = asyncio.Lock()
        self._status_lock = asyncio.Lock()  # one GET /status at a time (see _poll_once)
        self._link = ReconnectLogic(
            f"{resource}@{host}:{port}", self._open, self._release, backoff=backoff, connect_timeout=3 * timeout + 1
        )

    # -- Driver API -------------------------------------------------------------------

    async def read(self) -> Mapping[str, Value]:
        status = await self._current_status()
        return {"pos_m": self._position_name(status)}

    async def write(self, commands: Mapping[str, Value]) -> None:
        if "goto_c" not in commands:
            return
        goto = str(commands["goto_c"])
        if goto != "none" and goto not in TARGETS:
            raise ValueError(f"{self.resource}: goto_c must be none, kitting or station, got {goto!r}")
        self._desired = goto
        await self._current_status()
        async with self._lock:
            await self._apply(goto, await self._current_status())

    async def enter_safe_state(self) -> Mapping[str, Value]:
        safe: dict[str, Value] = {"goto_c": "none"}
        await self.write(safe)  # abort the queue and pause; remembered for a reconnect
        return safe

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self._link.wait_attempt():
            report.add("device answers", False, f"no MiR REST API at {self.base_url}: {self._link.last_error}")
            report.add("inputs read", False, "not checked: device absent")
            report.add("outputs read back", False, "not checked: device absent")
            return report
        try:
            status = await self._current_status()
            known = {m.get("guid") for m in await self._request("GET", "/missions")}
            unknown = [f"{t}={g}" for t, g in self.missions.items() if g not in known]
            detail = f"{status.get('robot_name', 'MiR')} at {self.base_url}, state {status.get('state_text')}"
            if unknown:
                report.add("device answers", False, f"{detail}; missions not on the robot: {', '.join(unknown)}")
            else:
                report.add("device answers", True, detail)
            values = await self.read()
            pos = status.get("position", {})
            report.add("inputs read", True, f"pos_m={values['pos_m']} (x={pos.get('x')}, y={pos.get('y')})")
        except DeviceUnavailable as exc:
            report.add("device answers", False, str(exc))
            return report
        try:
            report.add("outputs read back", *await self._state_read_back())
        except DeviceUnavailable as exc:
            report.add("outputs read back", False, str(exc))
        return report

    async def _state_read_back(self) -> tuple[bool, str]:
        """Write the robot state and read it back, never changing what the robot does.

        Idle and Ready: Pause, read back, Ready again, read back.  Paused: write Pause again.
        Executing or any other state: not checked (writing would change what the robot does).
        The hub runs its self-test while commands arrive: under the command lock and on a status
        asked for inside it, so that a mission a command posts meanwhile is never paused by a
        check that had seen the robot idle (seen: at_kitting, moving, at_kitting, moving)."""
        async with self._lock:
            await self._poll_once()
            status = self._status or {}
            state = int(status.get("state_id", 0))
            idle = status.get("mission_queue_id") is None
            if state == READY and idle:
                sequence = [PAUSE, READY]
            elif state == PAUSE:
                sequence = [PAUSE]
            else:
                return True, f"not checked: robot {status.get('state_text')} ({state})"
            for wanted in sequence:
                await self._request("PUT", "/status", json={"state_id": wanted})
                await self._poll_once()
                got = int((self._status or {}).get("state_id", -1))
                if got != wanted:
                    return False, f"state_id {wanted} written, {got} read back"
            return True, f"state_id {' then '.join(map(str, sequence))} written and read back"

    # -- mapping ----------------------------------------------------------------------

    def _position_name(self, status: Mapping[str, Any]) -> str:
        if int(status.get("state_id", 0)) == EXECUTING:
            return "moving"
        pos = status.get("position") or {}
        x, y = float(pos.get("x", math.nan)), float(pos.get("y", math.nan))
        for target, (tx, ty) in self.positions.items():
            if math.hypot(x - tx, y - ty) <= self.tolerance:
                return f"at_{target}"
        return "moving"

    async def _apply(self, goto: str, status: Mapping[str, Any], *, connecting: bool = False) -> None:
        state = int(status.get("state_id", 0))
        if goto == "none":
            if self._active is not None or state == EXECUTING:
                await self._request("DELETE", "/mission_queue", connecting=connecting)
                await self._request("PUT", "/status", json={"state_id": PAUSE}, connecting=connecting)
                self._active, self._active_entry = None, None
            return
        if self._active == goto:
            if state == PAUSE:
                await self._request("PUT", "/status", json={"state_id": READY}, connecting=connecting)
            elif state == READY and self._position_name(status) != f"at_{goto}" and await self._mission_gone():
                log.info("%s: robot idle away from %s and the mission is gone: posted again", self.resource, goto)
                await self._post(goto, connecting=connecting)
            return
        if self._active is not None or state == EXECUTING:
            await self._request("DELETE", "/mission_queue", connecting=connecting)
        await self._post(goto, connecting=connecting)

    async def _mission_gone(self) -> bool:
        """Our queued mission is no longer pending or running (checked at most once a second)."""
        now = time.monotonic()
        if now - self._last_queue_check < 1.0:
            return False
        self._last_queue_check = now
        if self._active_entry is None:
            return True
        entry = await self._request("GET", f"/mission_queue/{self._active_entry}")
        return not isinstance(entry, dict) or entry.get("state") not in ("Pending", "Executing")

    async def _post(self, goto: str, *, connecting: bool = False) -> None:
        entry = await self._request(
            "POST", "/mission_queue", json={"mission_id": self.missions[goto]}, connecting=connecting
        )
        await self._request("PUT", "/status", json={"state_id": READY}, connecting=connecting)
        self._active = goto
        self._active_entry = entry.get("id") if isinstance(entry, dict) else None
        self._last_queue_check = time.monotonic()
        await self._poll_once(connecting=connecting)

    # -- HTTP -------------------------------------------------------------------------

    async def _request(self, method: str, path: str, *, json: Any = None, connecting: bool = False) -> Any:
        client = self._client
        if client is None:
            raise DeviceUnavailable(f"{self.resource}: not connected ({self._link.last_error})")
        try:
            response = await client.request(method, path, json=json)
        except httpx.HTTPError as exc:
            reason = f"{method} {path}: {describe(exc)}"
            if connecting:
                raise ConnectionError(reason) from exc
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}") from exc
        if response.status_code == 401:
            reason = "authentication rejected (401): check username and password"
            if connecting:
                raise ConnectionError(reason)
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}")
        if response.status_code >= 400:
            raise DeviceUnavailable(
                f"{self.resource}: {method} {path} answered {response.status_code}: {response.text}"
            )
        return response.json() if response.content else None

    async def _poll_once(self, *, connecting: bool = False) -> None:
        # The poll loop, a command's refresh and a late read all ask for the status. One request at a
        # time: the answers then come in the order asked, and an older one never replaces a newer one.
        async with self._status_lock:
            status = await self._request("GET", "/status", connecting=connecting)
            if not isinstance(status, dict) or "state_id" not in status:
                raise DeviceUnavailable(f"{self.resource}: status without state_id")
            self._status, self._status_time = status, time.monotonic()

    async def _current_status(self) -> dict[str, Any]:
        """The last status, asked again when it is older than `stale_after`.

        An old status means only that nobody asked: the poll loop did not run (this hub starved of
        CPU, or its loop blocked). Only a robot that does not answer now is lost (`_request`)."""
        if not self.connected or self._status is None:
            raise DeviceUnavailable(f"{self.resource}: MiR not connected ({self._link.last_error})")
        age = time.monotonic() - self._status_time
        if age > self.stale_after:
            if self._poller is None or self._poller.done():
                reason = f"no status for {age:.1f} s: the status poll stopped"
                self._link.connection_lost(reason)  # reconnecting starts a new poll loop
                raise DeviceUnavailable(f"{self.resource}: {reason}")
            await self._poll_once()
        if self._status is None:  # lost while asking
            raise DeviceUnavailable(f"{self.resource}: MiR not connected ({self._link.last_error})")
        return self._status

    async def _poll_loop(self) -> None:
        while True:
            await asyncio.sleep(self.poll_interval)
            if not self.connected:
                continue
            with contextlib.suppress(DeviceUnavailable):
                await self._poll_once()

    async def _open(self) -> None:
        self._status = None
        self._active, self._active_entry = None, None
        self._client = httpx.AsyncClient(base_url=self.base_url, headers=self._headers, timeout=self.timeout,
                                         verify=self._ssl)
        await self._poll_once(connecting=True)
        # Adopt a mission of ours that is still queued or running (hub restart, network blip).
        queue = await self._request("GET", "/mission_queue", connecting=True) or []
        for entry in reversed(queue):
            if entry.get("state") not in ("Pending", "Executing"):
                continue
            detail = await self._request("GET", f"/mission_queue/{entry['id']}", connecting=True)
            target = next((t for t, g in self.missions.items() if g == detail.get("mission_id")), None)
            if target is not None:
                self._active, self._active_entry = target, int(entry["id"])
                break
        if self._desired is not None and self._status is not None:
            async with self._lock:
                try:
                    await self._apply(self._desired, self._status, connecting=True)  # drive the reference again
                except DeviceUnavailable as exc:
                    raise ConnectionError(str(exc)) from exc
        self._poller = asyncio.create_task(self._poll_loop(), name=f"poll:{self.resource}")

    async def _release(self) -> None:
        task, self._poller = self._poller, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(Exception):
                await client.aclose()
        self._status = None


class MirParams(DriverParams, frozen=True, kw_only=True):
    host: str
    port: Port = 80
    username: str = "admin"
    password: str = "admin"
    missions: dict[str, str]  # target -> mission GUID on the robot
    positions: dict[str, tuple[float, float]]  # target -> [x, y] on the robot's map
    tolerance: Positive = 0.3
    poll_interval: Positive = 0.2
    timeout: Positive = 1.0

    def __post_init__(self) -> None:
        for key, table in (("missions", self.missions), ("positions", self.positions)):
            missing = [t for t in TARGETS if t not in table]
            if missing:
                raise invalid(key, f"needs an entry for {', '.join(missing)} (targets: {', '.join(TARGETS)})")


def build(resource: str, params: MirParams) -> MirRest:
    return MirRest(resource, **params.options())


PLUGIN = DriverPlugin(MirParams, build)
