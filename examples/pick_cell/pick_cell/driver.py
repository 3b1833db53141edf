"""The vacuum ejector's driver: Modbus TCP to the ejector's gateway (I/O map in `pick_cell.sim`).

Variables (resource `vacuum_ejector` of `pick_cell.model`):

* command `suction_c` (bool): coil 0, the suction valve. Closing it (true -> false) also
  pulses the blow-off valve (coil 1), which the ejector closes by itself.
* measured `vacuum_m` (bool): discrete input 0, the ejector's switch point 1.

Safe state: none. Without commands the suction stays as it is, so a held box is never
dropped. The self-test checks that the gateway answers, that the supply pressure is
there (discrete input 1) and that the suction valve reads back as last commanded.

Registered as the `vacuum_ejector` entry point of group `statehub.drivers` (pyproject.toml);
its `hubs.toml` parameters are `EjectorParams`.
"""

from __future__ import annotations

from collections.abc import Mapping

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.modbus_io import ModbusLink, ModbusParams
from hubs.drivers.reconnect import LinkedDriver
from hubs.drivers.registry import DriverPlugin

from .sim import COIL_SUCTION, DI_SUPPLY_OK, DI_VACUUM_OK

INPUTS = 2  # discrete inputs 0..1


class EjectorParams(ModbusParams, frozen=True, kw_only=True):
    """The device's table in hubs.toml (besides `type` and `mode`): the gateway's `host`, `port`,
    `device_id`, `timeout` (s per request) and the reconnect backoff (`reconnect_min`, ...)."""


class VacuumEjector(LinkedDriver[ModbusLink]):
    def __init__(self, resource: str, params: EjectorParams) -> None:
        self.resource = resource
        self._link = ModbusLink(resource, params.host, params.port, device_id=params.device_id,
                                timeout=params.timeout, backoff=params.backoff(), probe=self._probe)
        self._suction: bool | None = None  # as last written; None: not written since connecting

    async def read(self) -> Mapping[str, Value]:
        inputs = await self.link.read_discrete_inputs(0, INPUTS)
        return {"vacuum_m": inputs[DI_VACUUM_OK]}

    async def write(self, commands: Mapping[str, Value]) -> None:
        if "suction_c" not in commands:
            return
        suction = bool(commands["suction_c"])
        if suction == self._suction:
            return  # the controller repeats its command: a repeated release must not blow off again
        releasing = self._suction is True and not suction
        await self.link.write_coils(COIL_SUCTION, [suction, releasing])
        self._suction = suction

    async def enter_safe_state(self) -> Mapping[str, Value]:
        return {}  # keep the suction as it is: a held box stays held

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self.link.reconnect.wait_attempt():
            report.add("device answers", False, f"no gateway at {self.link.where}: {self.link.reconnect.last_error}")
            return report
        report.add("device answers", True, f"gateway at {self.link.where}")
        try:
            inputs = await self.link.read_discrete_inputs(0, INPUTS)
            supply = inputs[DI_SUPPLY_OK]
            report.add("inputs read", supply, f"vacuum_m={inputs[DI_VACUUM_OK]}, supply pressure "
                                              f"{'OK' if supply else 'MISSING: check the compressed air'}")
            valve = (await self.link.read_coils(COIL_SUCTION, 1))[0]
            expected = bool(self._suction)
            report.add("outputs read back", valve == expected,
                       f"suction valve {'open' if valve else 'closed'}, commanded {'open' if expected else 'closed'}")
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
        return report

    async def _probe(self, link: ModbusLink) -> None:
        await link.read_discrete_inputs(0, INPUTS, connecting=True)
        self._suction = None  # the valve may have changed while we were away: the next command is written


PLUGIN = DriverPlugin(params=EjectorParams, build=VacuumEjector)
