"""RSP tool changer on a Modbus TCP remote-I/O coupler (coils out, discrete inputs in).

I/O map (addresses are offsets from ``coil_base`` / ``di_base``, defaults 0; unit id 1):

=========  ====  ===================================  ==================================
table      addr  signal                               variable
=========  ====  ===================================  ==================================
coil       +0    lock valve solenoid                  ``lock_c`` = true → 1
coil       +1    unlock valve solenoid                ``lock_c`` = false → 1
discrete   +0    piston in locked position            ``locked_m``
discrete   +1    piston in unlocked position          (plausibility: never both)
discrete   +2    air pressure OK                      ``pressure_ok_m``
discrete   +3    tool present on the tool plate       ``tool_m`` (none when 0)
discrete   +4-5  tool code bit 0, bit 1               ``tool_m``: 1 nutrunner, 2 lift_tool,
                                                      3 filter_tool, 0 none
=========  ====  ===================================  ==================================

Protocol: ``read`` is one FC2 request (6 inputs).  ``write`` is one FC15 request
(both solenoids, exactly one on) followed by an FC1 read-back of both coils; a mismatch
raises ``DeviceUnavailable``.  On (re)connect the driver drives the last commanded
``lock_c`` again, or, with no command yet, leaves the coils as they are: it never
unlocks on its own.

Safe state: none. ``lock_c`` keeps its value (a tool changer never drops its tool), so
``enter_safe_state()`` changes nothing and returns ``{}``: the valves hold position and
nothing else moves, and a hub (re)start never unlocks a held tool.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.modbus_io import Address, ModbusLink, ModbusParams
from hubs.drivers.reconnect import Backoff, LinkedDriver
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.coupler import (
    CHANGER_INPUTS,
    DEVICE_ID,
    DI_CODE0,
    DI_CODE1,
    DI_LOCKED,
    DI_PRESENT,
    DI_PRESSURE,
    DI_UNLOCKED,
    TOOLS,
)

TOOL_CODES = {0: "none", **{code: tool for code, tool in enumerate(TOOLS, start=1)}}


class RspModbus(LinkedDriver[ModbusLink]):
    def __init__(
        self,
        resource: str = "rsp",
        *,
        host: str,
        port: int = 502,
        device_id: int = DEVICE_ID,
        coil_base: int = 0,
        di_base: int = 0,
        timeout: float = 1.0,
        backoff: Backoff | None = None,
    ) -> None:
        self.resource = resource
        self.coil_base = coil_base
        self.di_base = di_base
        self._desired_lock: bool | None = None
        # Writes and the self-test's read-back take turns: interleaved, the self-test reads a
        # command's coils as its own failure, or writes its own over them.
        self._command_lock = asyncio.Lock()
        self._link = ModbusLink(
            resource, host, port, device_id=device_id, timeout=timeout, backoff=backoff, probe=self._on_connect
        )

    async def read(self) -> Mapping[str, Value]:
        inputs = await self.link.read_discrete_inputs(self.di_base, CHANGER_INPUTS)
        if inputs[DI_LOCKED] and inputs[DI_UNLOCKED]:
            raise DeviceUnavailable(f"{self.resource}: locked and unlocked sensors both on (sensor fault)")
        return self._decode(inputs)

    async def write(self, commands: Mapping[str, Value]) -> None:
        if "lock_c" not in commands:
            return
        lock = bool(commands["lock_c"])
        async with self._command_lock:
            self._desired_lock = lock
            await self._drive(lock)

    async def enter_safe_state(self) -> Mapping[str, Value]:
        return {}  # the valves hold: a tool changer never drops its tool

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self.link.reconnect.wait_attempt():
            report.add("device answers", False, f"no coupler at {self.link.where}: {self.link.reconnect.last_error}")
            report.add("inputs read", False, "not checked: device absent")
            report.add("outputs read back", False, "not checked: device absent")
            return report
        report.add("device answers", True, f"coupler at {self.link.where}")
        try:
            values = await self.read()
            report.add("inputs read", True, ", ".join(f"{k}={v}" for k, v in values.items()))
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
        try:
            async with self._command_lock:
                report.add("outputs read back", *await self._outputs_read_back())
        except DeviceUnavailable as exc:
            report.add("outputs read back", False, str(exc))
        return report

    async def _outputs_read_back(self) -> tuple[bool, str]:
        """Write what is commanded (or what is there) and read it back: never a change of lock state."""
        coils = await self.link.read_coils(self.coil_base, 2)
        if coils[0] and coils[1]:
            return False, "lock and unlock solenoids both on"
        lock = self._desired_lock if self._desired_lock is not None else (coils[0] if any(coils) else None)
        if lock is None:
            await self.link.write_coils(self.coil_base, coils)
            back = await self.link.read_coils(self.coil_base, 2)
            return back == coils, f"solenoids lock={int(back[0])} unlock={int(back[1])}"
        await self._drive(lock)
        return True, f"{'lock' if lock else 'unlock'} solenoid on, read back"

    # -- protocol ---------------------------------------------------------------------

    @staticmethod
    def _decode(inputs: list[bool]) -> dict[str, Value]:
        code = int(inputs[DI_CODE0]) | int(inputs[DI_CODE1]) << 1
        return {
            "locked_m": inputs[DI_LOCKED],
            "tool_m": TOOL_CODES[code] if inputs[DI_PRESENT] else "none",
            "pressure_ok_m": inputs[DI_PRESSURE],
        }

    async def _drive(self, lock: bool, *, connecting: bool = False) -> None:
        values = [lock, not lock]
        await self.link.write_coils(self.coil_base, values, connecting=connecting)
        back = await self.link.read_coils(self.coil_base, 2, connecting=connecting)
        if back != values:
            raise DeviceUnavailable(
                f"{self.resource}: solenoids not read back: wrote lock={int(values[0])} unlock={int(values[1])}, "
                f"read lock={int(back[0])} unlock={int(back[1])}"
            )

    async def _on_connect(self, link: ModbusLink) -> None:
        await link.read_discrete_inputs(self.di_base, CHANGER_INPUTS, connecting=True)
        if self._desired_lock is not None:
            # The coupler answers; a read-back problem shows on the next write and in the selftest.
            with contextlib.suppress(DeviceUnavailable):
                await self._drive(self._desired_lock, connecting=True)


class RspParams(ModbusParams, frozen=True, kw_only=True):
    coil_base: Address = 0
    di_base: Address = 0


def build(resource: str, params: RspParams) -> RspModbus:
    return RspModbus(resource, host=params.host, port=params.port, device_id=params.device_id,
                     coil_base=params.coil_base, di_base=params.di_base, timeout=params.timeout,
                     backoff=params.backoff())


PLUGIN = DriverPlugin(RspParams, build)
