"""Which driver serves a device type: the built-in drivers, then installed plugins.

A driver plugin is a `DriverPlugin`: the driver's parameter type (a msgspec Struct
that rejects unknown keys: the device's table in hubs.toml, less `type` and `mode`)
and a function that builds the driver from the resource name and those parameters.
A package ships one for its own device type as an entry point::

    [project.entry-points."statehub.drivers"]
    gripper = "my_cell.gripper:PLUGIN"

Built-in types are looked up first, so a plugin cannot replace a built-in driver.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgspec

from hubs.plugins import PluginTable

from .base import Driver
from .params import require_strict

ENTRY_POINT_GROUP = "statehub.drivers"


@dataclass(frozen=True)
class DriverPlugin:
    params: type[msgspec.Struct]  # the driver's parameters (forbid_unknown_fields=True)
    build: Callable[[str, Any], Driver]  # (resource name, params instance) -> Driver

    def __post_init__(self) -> None:
        require_strict(self.params)


_TABLE: PluginTable[DriverPlugin] = PluginTable(ENTRY_POINT_GROUP, DriverPlugin, {
    "nutrunner": "hubs.drivers.nutrunner_mcp23017:PLUGIN",
    "rsp": "hubs.drivers.rsp_modbus:PLUGIN",
    "dock": "hubs.drivers.dock_modbus:PLUGIN",
    "lift": "hubs.drivers.lift_can:PLUGIN",
    "rfid": "hubs.drivers.rfid_serial:PLUGIN",
    "mir": "hubs.drivers.mir_rest:PLUGIN",
    "camera": "hubs.drivers.camera_tracker:PLUGIN",
    "ur": "hubs.drivers.ur_rtde:PLUGIN",
    "operator": "hubs.drivers.operator_page:PLUGIN",
})


def find_driver(device_type: str) -> DriverPlugin | None:
    """The driver of `device_type`: built-in first, then entry points; None when there is none.
    Raises hubs.plugins.PluginError for an installed plugin that cannot be loaded."""
    return _TABLE.find(device_type)


def driver_types() -> list[str]:
    """The device types with a driver: built-in and installed plugins."""
    return _TABLE.names()


def builtin_driver_types() -> list[str]:
    return sorted(_TABLE.builtin)
