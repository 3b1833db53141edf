"""A Modbus TCP remote-I/O coupler link shared by the tool-changer and dock drivers.

One ``AsyncModbusTcpClient`` (pymodbus 3.16: ``device_id=``, not ``slave=``) with its own
reconnection switched off (``reconnect_delay=0``, ``retries=0``): the shared
``ReconnectLogic`` owns reconnection.  The connection counts as up only after a probe
request was answered.  A dropped TCP connection (pymodbus' ``trace_connect`` callback), a
timeout or a transport error reports the device lost at once; an exception *response*
(the coupler answered but refused, e.g. code 4 device failure) raises
``DeviceUnavailable`` without dropping the connection.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Annotated, Any

import msgspec
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.params import DriverParams, Port, Positive
from hubs.drivers.reconnect import Backoff, ReconnectLogic, describe

log = logging.getLogger(__name__)

Address = Annotated[int, msgspec.Meta(ge=0, le=65535)]


class ModbusParams(DriverParams, frozen=True, kw_only=True):
    """The coupler's address, shared by the drivers of the devices wired to it."""

    host: str
    port: Port = 502
    device_id: Annotated[int, msgspec.Meta(ge=0, le=247)] = 1
    timeout: Positive = 1.0


class ModbusLink:
    def __init__(
        self,
        name: str,
        host: str,
        port: int = 502,
        *,
        device_id: int = 1,
        timeout: float = 1.0,
        backoff: Backoff | None = None,
        probe: Callable[[ModbusLink], Awaitable[None]] | None = None,
    ) -> None:
        self.name = name
        self.host = host
        self.port = port
        self.device_id = device_id
        self.timeout = timeout
        self._probe = probe
        self._client: AsyncModbusTcpClient | None = None
        self._lock = asyncio.Lock()
        self.reconnect = ReconnectLogic(
            f"{name}@modbus:{host}:{port}/{device_id}",
            self._open,
            self._close,
            backoff=backoff,
            connect_timeout=max(2.0, 3 * timeout),
        )

    @property
    def connected(self) -> bool:
        return self.reconnect.connected

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port} unit {self.device_id}"

    async def start(self) -> None:
        await self.reconnect.start()

    async def stop(self) -> None:
        await self.reconnect.stop()

    # -- requests ---------------------------------------------------------------------

    async def read_coils(self, address: int, count: int, *, connecting: bool = False) -> list[bool]:
        response = await self._request(
            "read coils", lambda c: c.read_coils(address, count=count, device_id=self.device_id), connecting
        )
        return [bool(b) for b in response.bits[:count]]

    async def read_discrete_inputs(self, address: int, count: int, *, connecting: bool = False) -> list[bool]:
        response = await self._request(
            "read discrete inputs",
            lambda c: c.read_discrete_inputs(address, count=count, device_id=self.device_id),
            connecting,
        )
        return [bool(b) for b in response.bits[:count]]

    async def write_coils(self, address: int, values: list[bool], *, connecting: bool = False) -> None:
        await self._request(
            "write coils", lambda c: c.write_coils(address, values, device_id=self.device_id), connecting
        )

    async def _request(
        self, what: str, call: Callable[[AsyncModbusTcpClient], Awaitable[Any]], connecting: bool
    ) -> Any:
        client = self._client
        if client is None or not (connecting or self.connected):
            raise DeviceUnavailable(f"{self.name}: coupler {self.where} not connected ({self.reconnect.last_error})")
        async with self._lock:
            try:
                async with asyncio.timeout(self.timeout + 0.5):
                    response = await call(client)
            except (ModbusException, OSError, TimeoutError) as exc:
                reason = f"{what}: {describe(exc)}"
                if connecting:
                    raise ConnectionError(reason) from exc
                self.reconnect.connection_lost(reason)
                raise DeviceUnavailable(f"{self.name}: coupler {self.where}: {reason}") from exc
        if response.isError():
            code = getattr(response, "exception_code", "?")
            raise DeviceUnavailable(f"{self.name}: coupler {self.where} refused {what} (Modbus exception {code})")
        return response

    # -- connection -------------------------------------------------------------------

    def _trace_connect(self, connected: bool) -> None:
        if not connected and self.connected:
            self.reconnect.connection_lost("TCP connection closed by the coupler")

    async def _open(self) -> None:
        client = AsyncModbusTcpClient(
            self.host,
            port=self.port,
            timeout=self.timeout,
            retries=0,
            reconnect_delay=0,
            name=self.name,
            trace_connect=self._trace_connect,
        )
        self._client = client
        if not await client.connect():
            raise ConnectionError(f"no Modbus TCP coupler at {self.host}:{self.port}")
        if self._probe is not None:
            await self._probe(self)

    async def _close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            try:
                client.close()
            except Exception as exc:
                log.debug("%s: close failed: %s", self.name, describe(exc))
