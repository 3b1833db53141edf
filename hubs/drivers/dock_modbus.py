"""Tool dock on a Modbus TCP remote-I/O coupler: one occupancy sensor per slot, inputs only.

I/O map (offsets from ``di_base``, default 8, so the dock shares the tool changer's
coupler; unit id 1):

=========  ====  ====================================  =========================
table      addr  signal                                variable
=========  ====  ====================================  =========================
discrete   +0    slot 1 occupied                       ``nutrunner_home_m``
discrete   +1    slot 2 occupied                       ``lift_tool_home_m``
discrete   +2    slot 3 occupied                       ``filter_tool_home_m``
=========  ====  ====================================  =========================

Protocol: ``read`` is one FC2 request of three inputs.  There are no outputs, so the
self-test checks that the coupler answers and the inputs read; "outputs read back" is
reported as not applicable (ok).  Safe state: none (nothing to command).
"""

from __future__ import annotations

from collections.abc import Mapping

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.modbus_io import Address, ModbusLink, ModbusParams
from hubs.drivers.reconnect import Backoff, LinkedDriver
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.coupler import DEVICE_ID, DI_DOCK, TOOLS

SLOTS = tuple(f"{tool}_home_m" for tool in TOOLS)  # slot n+1 is the home of the n-th tool


class DockModbus(LinkedDriver[ModbusLink]):
    def __init__(
        self,
        resource: str = "dock",
        *,
        host: str,
        port: int = 502,
        device_id: int = DEVICE_ID,
        di_base: int = DI_DOCK,
        timeout: float = 1.0,
        backoff: Backoff | None = None,
    ) -> None:
        self.resource = resource
        self.di_base = di_base
        self._link = ModbusLink(
            resource, host, port, device_id=device_id, timeout=timeout, backoff=backoff, probe=self._probe
        )

    async def read(self) -> Mapping[str, Value]:
        inputs = await self.link.read_discrete_inputs(self.di_base, len(SLOTS))
        return dict(zip(SLOTS, inputs, strict=True))

    async def write(self, commands: Mapping[str, Value]) -> None:
        return None  # the dock has no command variables

    async def enter_safe_state(self) -> Mapping[str, Value]:
        return {}  # nothing to command

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self.link.reconnect.wait_attempt():
            report.add("device answers", False, f"no coupler at {self.link.where}: {self.link.reconnect.last_error}")
            report.add("inputs read", False, "not checked: device absent")
            return report
        report.add("device answers", True, f"coupler at {self.link.where}")
        try:
            values = await self.read()
            report.add("inputs read", True, ", ".join(f"{k}={v}" for k, v in values.items()))
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
        report.add("outputs read back", True, "not applicable: the dock has no outputs")
        return report

    async def _probe(self, link: ModbusLink) -> None:
        await link.read_discrete_inputs(self.di_base, len(SLOTS), connecting=True)


class DockParams(ModbusParams, frozen=True, kw_only=True):
    di_base: Address = DI_DOCK  # after the tool changer's inputs on a shared coupler


def build(resource: str, params: DockParams) -> DockModbus:
    return DockModbus(resource, host=params.host, port=params.port, device_id=params.device_id,
                      di_base=params.di_base, timeout=params.timeout, backoff=params.backoff())


PLUGIN = DriverPlugin(DockParams, build)
