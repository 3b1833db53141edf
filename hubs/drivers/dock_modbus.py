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
from typing import Any

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.modbus_io import ModbusLink
from hubs.drivers.params import require
from hubs.drivers.reconnect import Backoff, LinkedDriver

SLOTS = ("nutrunner_home_m", "lift_tool_home_m", "filter_tool_home_m")


class DockModbus(LinkedDriver[ModbusLink]):
    def __init__(
        self,
        resource: str = "dock",
        *,
        host: str,
        port: int = 502,
        device_id: int = 1,
        di_base: int = 8,
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

    def safe_state(self) -> Mapping[str, Value]:
        return {}

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


def from_params(resource: str, params: Mapping[str, Any]) -> DockModbus:
    return DockModbus(
        resource,
        host=str(require(params, "host")),
        port=int(params.get("port", 502)),
        device_id=int(params.get("device_id", 1)),
        di_base=int(params.get("di_base", 8)),
        timeout=float(params.get("timeout", 1.0)),
        backoff=Backoff.from_params(params),
    )
