"""Device drivers: one module per device protocol, and the factory the hub uses.

``make_driver(resource, device_type, mode, params)`` builds the driver of one resource
from its ``hubs.toml`` entry.  Modes:

* ``real``: the driver talks to the device at the address in ``params``.
* ``sim``: the same driver class against a simulator speaking the same protocol.  For
  I2C and CAN the factory starts the in-process simulator (there is no I2C bus and the
  CAN bus is python-can's ``virtual`` interface); for Modbus TCP, RTDE, REST, serial and
  the tracker feed the simulator runs on its own and ``params`` give its address.
* ``emulate``: built from the resource model (``hubs.factory``), not here.

Driver modules are imported on demand, so a hub only loads the libraries its devices use.
The parameters per device type are listed in docs/drivers.md.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from hubs.drivers.base import Driver

MODES = ("sim", "real")


def _nutrunner(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import nutrunner_mcp23017 as mod

    if mode == "sim":
        from hubs.sim import mcp23017 as sim

        bus, address = int(params.get("bus", 1)), int(params.get("address", 0x20))
        timing = {k[4:]: float(v) for k, v in params.items() if k in ("sim_spinup", "sim_tighten", "sim_reset")}
        sim.ensure_nutrunner(
            bus,
            address,
            fail_probability=float(params.get("sim_fail_probability", 0.0)),
            seed=int(params.get("sim_seed", 0)),
            timing=sim.NutrunnerTiming(**timing),
        )
        return mod.from_params(resource, params, bus_factory=sim.sim_bus(bus).open)
    return mod.from_params(resource, params)


def _sim_defaults(mode: str, params: Mapping[str, Any], **defaults: Any) -> dict[str, Any]:
    """In sim mode the simulator runs on this machine: fill in its default address."""
    out = dict(params)
    if mode == "sim":
        for key, value in defaults.items():
            out.setdefault(key, value)
    return out


def _rsp(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import rsp_modbus

    return rsp_modbus.from_params(resource, _sim_defaults(mode, params, host="127.0.0.1", port=5020))


def _dock(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import dock_modbus

    return dock_modbus.from_params(resource, _sim_defaults(mode, params, host="127.0.0.1", port=5020))


def _lift(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import lift_can

    if mode == "sim":
        from hubs.sim.lift_can import ensure_lift

        params = _sim_defaults(mode, params, channel="statehub-lift")
        sim_options = {k[4:]: float(v) for k, v in params.items() if k in ("sim_speed", "sim_travel")}
        ensure_lift(str(params["channel"]), int(params.get("node_id", 0x10)), **sim_options)
        return lift_can.from_params(resource, params, interface="virtual")
    return lift_can.from_params(resource, params)


def _rfid(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import rfid_serial

    return rfid_serial.from_params(resource, params)  # sim: serial_port is the simulator's pty link


def _mir(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import mir_rest

    if mode == "sim":
        from hubs.sim import mir_rest as sim

        params = _sim_defaults(
            mode,
            params,
            host="127.0.0.1",
            port=8080,
            missions={"kitting": sim.KITTING_MISSION, "station": sim.STATION_MISSION},
            positions={"kitting": sim.KITTING_POSITION, "station": sim.STATION_POSITION},
        )
    return mir_rest.from_params(resource, params)


SIM_CAMERA_ZONES = {"shared": [[0.0, 0.0, 2.0, 2.0]], "robot": [[2.0, 0.0, 4.0, 2.0]]}


def _camera(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import camera_tracker

    params = _sim_defaults(mode, params, host="127.0.0.1", port=7001, zones=SIM_CAMERA_ZONES)
    return camera_tracker.from_params(resource, params)


def _ur(resource: str, mode: str, params: Mapping[str, Any]) -> Driver:
    from hubs.drivers import ur_rtde

    # sim: a fake controller (hubs.sim.ur_rtde_fake) runs at `host`; motion through its command port
    params = _sim_defaults(mode, params, host="127.0.0.2", motion_backend="sim", command_port=30099)
    return ur_rtde.from_params(resource, params)


_BUILDERS: dict[str, Callable[[str, str, Mapping[str, Any]], Driver]] = {
    "nutrunner": _nutrunner,
    "rsp": _rsp,
    "dock": _dock,
    "lift": _lift,
    "rfid": _rfid,
    "mir": _mir,
    "camera": _camera,
    "ur": _ur,
}


def device_types() -> list[str]:
    return sorted(_BUILDERS)


def make_driver(resource_name: str, device_type: str, mode: str, params: Mapping[str, Any] | None = None) -> Driver:
    """The driver for one resource. Raises ValueError naming what is wrong (type, mode, parameter)."""
    params = dict(params or {})
    if mode == "emulate":
        raise ValueError(
            f"resource {resource_name!r}: mode 'emulate' is built from the resource model "
            "(hubs.factory, hubs.drivers.emulated), not by hubs.drivers.make_driver"
        )
    if mode not in MODES:
        raise ValueError(f"resource {resource_name!r}: unknown mode {mode!r}; expected one of sim, real, emulate")
    builder = _BUILDERS.get(device_type)
    if builder is None:
        raise ValueError(
            f"resource {resource_name!r}: no driver for device type {device_type!r}; "
            f"known types: {', '.join(device_types())}"
        )
    try:
        return builder(resource_name, mode, params)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"resource {resource_name!r} ({device_type}, {mode}): bad parameters: {exc}") from exc
